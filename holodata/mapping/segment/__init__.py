"""Automatic human (moving-object) instance segmentation on the LiDAR's native range-image grid.

The method of the Ouster OS0 instance-segmentation note, on the organised scan ``lidar/range``
(T, Hl, Wl) of a scene whose scans have poses ``pose/T_world_lidar``:

1. **Background model**: every scan's returns in the world frame go into a 15 cm voxel model of the
   static scene (:class:`holodata.mapping.background.VoxelBackground`: voxels occupied in at least
   ``min_fraction`` of the scans that observed them, free-space test from the scan origins; people
   occupy a voxel only briefly), plus the **floor plane** (:func:`floor_plane`): returns within
   ``floor_margin_m`` of it are background too.
2. **Foreground**: the returns of a scan outside the background (grid mask, (Hl, Wl)).
3. **Seeds by shrinking**: binary erosion of the foreground mask (columns wrap around), which
   removes isolated pixels and the fringe of mixed/edge returns; 3×3, or 1×3 when the rows are
   more than twice as far apart in angle as the columns (:func:`shrink_structure`).
4. **Flood fill** from the seeds over grid neighbours (right, down, both diagonals, and the
   second neighbour along rows and columns to bridge single dropouts; columns wrap) that are
   foreground and within a Euclidean distance ``dist_m + dist_per_m · r + spacing_factor · s · r``
   of each other (3-D points, metres; r the nearer range, s the beam pattern's angular step between
   the two pixels — :func:`neighbour_spacing`, from the row elevations measured in the scan,
   :func:`beam_elevations`). Implemented as connected components of that neighbour graph
   (``scipy.sparse.csgraph``) keeping the components that hold a seed. Clusters standing on the
   same plan-view spot with overlapping heights are joined (:func:`merge_stacked`: a limb split
   off by a depth jump).
5. **Keep the largest cluster(s)**: components with at least ``min_points`` returns whose extent is
   person-like (vertical extent >= ``min_height_m``, horizontal extent <= ``max_width_m``, top at
   most ``max_height_m`` above the floor, not flat), largest first, at most ``max_instances``.

Beam geometry: the link threshold, the shrink structure and the smallest height follow the beam
spacing measured in the scan, so that a coarse wide-FOV LiDAR (an OS0-like 90°, 32 beams) is
segmented as well as a fine narrow one (an OS1-like 33°, 64 beams): on a coarse grid the rows of a
far person lie farther apart than a fixed link threshold, a fixed 3×3 shrink removes whole rows, and
the far floor seen by one coarse ring stays out of the voxel background. What failed and the
accuracy per LiDAR: ``docs/design/segment.md``.

Output per scan: an instance image (Hl, Wl) uint16, 0 = background / no return, 1 = the largest
instance, 2 = the next ... Stored as ``lidar/instance`` (T, Hl, Wl) uint16 with
``dims = [frame, beam, column]`` and the parameters in its attributes (written shard by shard with
the dataset writer: atomic shards, a rerun resumes), with ``poses_sha256``, the fingerprint of the
``pose/T_world_lidar`` it was made with (:func:`instance_state`: masks made with other poses are
made again, not resumed or reused).

Points: ``lidar/points`` holds the valid pixels of ``lidar/range`` in row-major order (see
:mod:`holodata.ingest`), in the sensor frame at each point's own time; with ``lidar/point_time_ns``
(time relative to the scan stamp) the points are de-skewed with poses interpolated between scans
(:meth:`LidarScans.deskew_points`: one transform for a scan taken at rest, one pose per column).

What keeps the background model + segmentation fast (measured with ``benchmarks/pipeline.py``, numbers
in ``benchmarks/results/pipeline.md``): a dense voxel grid for the occupancy count and lookups
(:mod:`.background`), ``lidar/range`` read a shard at a time, the de-skew shortcuts
(:meth:`LidarScans.scan_world` for the background pass; :mod:`.scans`), and :func:`background_and_segment`, which
reuses the background pass's world points so that scans without foreground are not read twice.

Modules: :mod:`.config` (settings), :mod:`.core` (one scan's segmentation, arrays in and out),
:mod:`.scans` (the scene's scans as the segmentation reads them), :mod:`.background_model` (the
background model and what it says of a scan's returns), :mod:`.instances` (the dataset passes:
:func:`segment_scene`, :func:`background_and_segment`, the instance masks); this module only
re-exports.
"""
from __future__ import annotations

from .background_model import _background_pass as _background_pass
from .background_model import background_from_points as background_from_points
from .background_model import background_masks, build_background, in_background, surely_without_foreground

# ``name as name``: importable from the package since its code lived here, kept so; not in __all__
from .config import INSTANCE_ARRAY, SegmentConfig
from .core import above_floor as above_floor
from .core import (
                   beam_elevations,
                   destagger,
                   erode,
                   flood_fill,
                   floor_plane,
                   merge_stacked,
                   neighbour_spacing,
                   row_shifts,
                   segment_scan,
                   shrink_structure,
)
from .instances import (
                   InstanceMasks,
                   background_and_segment,
                   grid_geometry,
                   instance_state,
                   pose_fingerprint,
                   segment_scene,
                   write_instances,
)
from .instances import _scene_id as _scene_id
from .instances import _segment_stage as _segment_stage
from .scans import LidarScans

__all__ = ["SegmentConfig", "segment_scan", "flood_fill", "erode", "LidarScans", "build_background", "segment_scene",
           "write_instances", "InstanceMasks",
           "background_and_segment", "surely_without_foreground", "INSTANCE_ARRAY", "instance_state",
           "pose_fingerprint", "destagger", "row_shifts", "merge_stacked", "neighbour_spacing", "shrink_structure",
           "beam_elevations", "floor_plane", "grid_geometry", "background_masks", "in_background"]
