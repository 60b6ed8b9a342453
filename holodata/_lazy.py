"""The package's lazy face (PEP 562): ``holodata.<subpackage>`` imported on first attribute access, and
:func:`open_dataset` without importing the dataset stack, so that ``import holodata`` stays fast and
``holodata.torch`` needs the ``train`` extra only when it is touched. :mod:`holodata` re-exports these."""
from __future__ import annotations

import importlib
import sys

# reachable as attributes of the package without importing them first
SUBMODULES = ("beams", "conventions", "dataset", "evaluate", "groundtruth", "ingest", "mapping", "metrics",
              "raytrace", "readers", "synth", "torch", "trajectory")


def open_dataset(path_or_url: str, **kwargs):
    """Open a holodata dataset read-only and lazily (local path or fsspec URL)."""
    from .dataset import open_dataset as _open

    return _open(path_or_url, **kwargs)


def __getattr__(name: str):
    if name in SUBMODULES:
        return importlib.import_module(f"holodata.{name}")
    raise AttributeError(f"module 'holodata' has no attribute {name!r}")


def __dir__():
    return sorted(set(vars(sys.modules["holodata"])) | set(SUBMODULES))
