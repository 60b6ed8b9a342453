"""Dataset format v1 (docs/format.md §3): sharded Zarr v3, one frame per chunk, whole-shard atomic writes
with a sha256 commit record per shard, resume, ragged arrays, lazy reader, validate, info.

Layout: ``<root>/zarr.json`` (attrs ``holodata``: format_version, created_by, grid, range_bins,
splits, provenance, shard_frames) / ``scenes/<id>/`` (attrs: n_frames, corner_type, ...) /
``<array>`` with ``attrs`` dims, units, holodata {kind: frame|array|ragged, ...}. Frame arrays keep
``manifest/<k>.json`` commit records next to their ``c/`` shard objects (see :mod:`.writer`).
Ragged arrays are groups with ``values`` (N, width) and ``offsets`` (T+1,) int64.
"""
from __future__ import annotations

from .access import open_dataset
from .info import dataset_info, format_info
from .reader import Dataset, Ragged, Scene
from .validate import validate_dataset
from .writer import DEFAULT_SHARD_FRAMES, DatasetWriter, FrameArrayWriter, FrameStorage, RaggedWriter, SceneWriter, create_dataset

__all__ = ["create_dataset", "open_dataset", "Dataset", "Scene", "Ragged", "DatasetWriter", "SceneWriter",
           "FrameArrayWriter", "FrameStorage", "RaggedWriter", "DEFAULT_SHARD_FRAMES", "dataset_info", "format_info",
           "validate_dataset"]
