"""evaluate stage: un-mirroring (stage two without learning), the non-learned baseline, metric
tables with breakdowns, metrics.json and report.html; and every other evaluation against truth:
the mapping stages' accuracy (:mod:`.slam_accuracy`: poses and mesh; :mod:`.register_accuracy`:
segmentation AP, camera extrinsic, human centroids).

``Evaluation(dataset_url, checkpoint, out_dir, split="test", ...).run() -> dict`` is the entry
point; it imports torch only to run the model.
"""
from __future__ import annotations

from holodata.geometry.unmirror import los_mask, normals_from_range, unmirror

from .baseline import strongest_peaks
from .pipeline import Evaluation
from .report import format_tables

__all__ = ["Evaluation", "format_tables", "strongest_peaks", "los_mask", "normals_from_range", "unmirror"]
