"""holodata: multi-bounce radar ground truth datasets.

Public API (docs/format.md §6): :func:`open_dataset`, :mod:`holodata.metrics`,
:func:`holodata.raytrace.trace`, :mod:`holodata.torch`. Subpackages are imported on first use
(``holodata.raytrace`` works after a plain ``import holodata``), so ``import holodata`` stays fast and
``holodata.torch`` needs the ``train`` extra only when it is touched.
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

# reachable as attributes of the package without importing them first (PEP 562)
SUBMODULES = ("beams", "conventions", "dataset", "evaluate", "groundtruth", "ingest", "mapping", "metrics",
              "raytrace", "readers", "synth", "torch", "trajectory")


def open_dataset(path_or_url: str, **kwargs):
    """Open a holodata dataset read-only and lazily (local path or fsspec URL)."""
    from .dataset import open_dataset as _open

    return _open(path_or_url, **kwargs)


def __getattr__(name: str):
    if name in SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(SUBMODULES))


__all__ = ["open_dataset", "__version__"]
