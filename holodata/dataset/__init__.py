"""Dataset format v1 (docs/format.md §3): sharded Zarr v3, one frame per chunk, whole-shard atomic writes
with a sha256 commit record per shard, resume, ragged arrays, lazy reader, validate, info.

Layout: ``<root>/zarr.json`` (attrs ``holodata``: format_version, created_by, grid, range_bins,
splits, provenance, shard_frames) / ``scenes/<id>/`` (attrs: n_frames, corner_type, ...) /
``<array>`` with ``attrs`` dims, units, holodata {kind: frame|array|ragged, ...}. Frame arrays keep
``manifest/<k>.json`` commit records next to their ``c/`` shard objects (see :mod:`.writer`).
Ragged arrays are groups with ``values`` (N, width) and ``offsets`` (T+1,) int64.
"""
from __future__ import annotations

from .reader import Dataset, Ragged, Scene
from .reader import open_dataset as _open_read
from .writer import DEFAULT_SHARD_FRAMES, DatasetWriter, FrameArrayWriter, FrameStorage, RaggedWriter, SceneWriter, create_dataset


def open_dataset(path_or_url, mode: str = "r", created_by: str = "holodata", **writer_options):
    """``mode="r"``: the dataset read-only and lazily (:class:`Dataset`). ``mode="r+"``: a
    :class:`DatasetWriter` on an existing dataset, with its own grid and range bins, for a stage
    that adds or replaces arrays of its scenes (``created_by`` and ``writer_options`` as
    :func:`create_dataset`'s)."""
    if mode == "r":
        return _open_read(path_or_url)
    if mode == "r+":
        ds = _open_read(path_or_url)
        return create_dataset(path_or_url, grid=ds.grid, range_bins=ds.range_bins, created_by=created_by,
                              **writer_options)
    raise ValueError(f"open_dataset: mode must be 'r' or 'r+', got {mode!r}")


def dataset_info(path_or_url) -> dict:
    from .info import dataset_info as _f

    return _f(path_or_url)


def format_info(summary: dict) -> str:
    from .info import format_info as _f

    return _f(summary)


def validate_dataset(path_or_url, **kwargs) -> dict:
    from .validate import validate_dataset as _f

    return _f(path_or_url, **kwargs)


__all__ = ["create_dataset", "open_dataset", "Dataset", "Scene", "Ragged", "DatasetWriter", "SceneWriter",
           "FrameArrayWriter", "FrameStorage", "RaggedWriter", "DEFAULT_SHARD_FRAMES", "dataset_info", "format_info",
           "validate_dataset"]
