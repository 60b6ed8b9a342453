"""holodata: multi-bounce radar ground truth datasets.

Public API (DESIGN.md §6): :func:`open_dataset`, :mod:`holodata.metrics`,
:func:`holodata.raytrace.trace`, :mod:`holodata.torch`.
"""
from __future__ import annotations

__version__ = "0.1.0"


def open_dataset(path_or_url: str, **kwargs):
    """Open a holodata dataset read-only and lazily (local path or fsspec URL)."""
    from .dataset import open_dataset as _open

    return _open(path_or_url, **kwargs)


__all__ = ["open_dataset", "__version__"]
