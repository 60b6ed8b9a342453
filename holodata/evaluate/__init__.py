"""evaluate stage: un-mirroring (stage two without learning), the non-learned baseline, metric
tables with breakdowns, metrics.json and report.html.

``evaluate(dataset_url, checkpoint, out_dir, split="test", ...) -> dict`` is the entry point;
it imports torch only to run the model.
"""
from __future__ import annotations

from .baseline import strongest_peaks
from .report import format_tables
from holodata.geometry.unmirror import los_mask, normals_from_range, unmirror


def evaluate(dataset_url, checkpoint, out_dir, split: str = "test", **kwargs) -> dict:
    """See :func:`holodata.evaluate.pipeline.evaluate`."""
    from .pipeline import evaluate as _evaluate

    return _evaluate(dataset_url, checkpoint, out_dir, split=split, **kwargs)


__all__ = ["evaluate", "format_tables", "strongest_peaks", "los_mask", "normals_from_range", "unmirror"]
