"""Settings of the LiDAR segmentation (:class:`SegmentConfig`) and the instance array's name."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ...dataset.layout import LIDAR_INSTANCE

INSTANCE_ARRAY = LIDAR_INSTANCE       # segment's output (the layout's name; kept for its importers)
# neighbour offsets (row, col): right, down, down-right, down-left, 2 right, 2 down
NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0))


@dataclass(frozen=True)
class SegmentConfig:
    """Parameters of :func:`segment_scan` (metres). ``voxel`` / ``min_fraction`` / ``min_hits``:
    background model (:meth:`VoxelBackground.build`; 0.6 as slam's: 0.25 kept walkers' trails in
    short recordings); ``floor_margin_m``: returns this close to the floor plane are background (0: no
    floor model); ``tolerance_voxels`` 0: a return is background when its own voxel is, 1: when any
    voxel of its 3×3×3 neighbourhood is (the model's ``contains``);
    ``erosion``: iterations of the shrink that makes the seeds (:func:`shrink_structure`);
    ``dist_m`` + ``dist_per_m``·r + ``spacing_factor``·(beam step)·r: flood-fill distance threshold
    between grid neighbours (:func:`link_threshold`); ``merge_xy_m``: join clusters this close in plan
    view with overlapping heights (:func:`merge_stacked`; 0: off); ``max_height_m``: highest top of a
    person above the floor (and tallest merge); ``min_points``: smallest kept cluster;
    ``min_height_m`` / ``max_width_m``: person-like extent (0 / inf switch the check off);
    ``min_depth_m`` / ``min_depth_sigmas`` / ``surface_sigmas`` / ``max_surface_share``: the flat
    surface check, which rejects patches of wall that the background missed (e.g. behind a lane
    people walk often) and keeps flat movers (a box-shaped robot, a board carried face-on): a
    cluster is *thin* when its robust extent along its least principal axis (:func:`_thickness`)
    is under ``min_depth_m``, or, when that is None, under ``min_depth_sigmas`` × the scan's range
    noise measured from its background returns (:func:`range_noise`; a face-on plane measures
    about 3 σ from the noise alone, 3.6 σ at the 95th percentile); a thin cluster is dropped when more
    than ``max_surface_share`` of its border continues the surrounding surface within
    ``surface_sigmas``·√6·σ (:func:`surface_share`), i.e. it is a piece of that surface, not
    something standing in front of it (``min_depth_m`` 0: off; docs/design/segment.md);
    ``max_instances``: keep at most this many clusters per scan (largest first; 0 = no limit)."""

    voxel: float = 0.15
    min_fraction: float = 0.6
    min_hits: int = 2
    floor_margin_m: float = 0.07
    merge_xy_m: float = 0.15
    max_height_m: float = 2.3
    tolerance_voxels: int = 0
    erosion: int = 1
    dist_m: float = 0.10
    dist_per_m: float = 0.02
    spacing_factor: float = 2.0
    min_points: int = 15
    min_height_m: float = 0.25
    max_width_m: float = 1.5
    min_depth_m: float | None = None
    min_depth_sigmas: float = 5.0
    surface_sigmas: float = 3.0
    max_surface_share: float = 0.8
    max_instances: int = 0
    deskew: bool = True
    free_space: bool = True

    def to_attrs(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}
