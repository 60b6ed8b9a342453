"""One way in: :func:`open_dataset` opens a dataset to read (:class:`~holodata.dataset.reader.Dataset`)
or to add to (:class:`~holodata.dataset.writer.DatasetWriter`, with the dataset's own grid and range bins)."""
from __future__ import annotations

from .reader import open_dataset as _open_read
from .writer import create_dataset


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
