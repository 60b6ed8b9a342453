"""``holodata ingest``: recordings -> dataset scenes (docs/format.md §3), streaming and resumable.

Per recording (one scene each):

1. **Topic mapping** (:func:`map_topics`): radar = ``*/RadarHeatmap`` messages; LiDAR = a
   ``PointCloud2`` whose topic/frame does not look like a camera, Ouster pcap scans, or
   ``ouster_ros/PacketMsg`` packets + the driver's metadata ``String``; camera = a depth ``Image``
   (16UC1 mm / 32FC1 m) + its ``CameraInfo``, else a camera-looking ``PointCloud2``; TF =
   ``/tf`` and ``/tf_static``. A YAML file (``--topics``, see ``examples/topics.yaml``) overrides
   any role (``null`` switches a role off) and the options ``time``, ``world_frame``,
   ``base_frame``, ``camera_stride``.
2. **Index pass**: every message of the mapped topics is read undecoded; stamps come from the
   header bytes (``time: header``, default; 0 stamps fall back to the log time) or the log time
   (``time: log``). Messages of the sensor that defines the frames are decoded and checked here,
   so a frame exists only for a message that decodes.
3. **Sync**: frames are radar rotation cycles (radar header stamp), or LiDAR scans when there is
   no radar (``frame_sensor`` says which). Each frame takes the LiDAR scan and camera frame
   nearest in time within a tolerance (``--tolerance MS``; default per sensor: half its median period,
   at least 50 ms, so a sensor that kept publishing fills every frame); frames with none get an empty cloud and
   ``<sensor>/timestamp_ns`` = 0. Unmatched and failed messages are counted and reported.
4. **Write pass**: only the matched messages are decoded; shards are written as soon as all their
   frames have arrived (memory is a few shards, flat in recording size). Rerunning the same command
   resumes: finished shards are skipped (their messages are not decoded), a finished scene is
   skipped entirely.

Arrays: ``time/timestamp_ns``; ``radar/heatmap`` (T, R, H, W) as recorded (float16|float32 linear
amplitude), ``radar/cycle_ns`` (T, 2) [start, end]; ``lidar/points`` ragged (sensor frame; for
organised clouds the valid pixels of ``lidar/range`` in row-major order), ``lidar/point_time_ns``
ragged (per-point time relative to the scan stamp, when the cloud has a time field), ``lidar/range``
(T, Hl, Wl) float32 m, NaN = no return (organised clouds as published; Ouster scans destaggered),
``lidar/timestamp_ns``; ``camera/points`` ragged (sensor frame: optical frame for depth images),
``camera/timestamp_ns``; ``pose/T_world_radar`` when TF connects the radar frame to the world frame
at every frame time; ``tf/T_world_lidar`` when TF connects the LiDAR frame to a world frame (NaN
where TF does not cover a frame's scan: slam anchors its map to it). Scene attributes: ``frame_sensor``, ``source`` {recording,
files, bytes, blake3 (BLAKE3 of each file, written with ``ingest.complete``; scenes ingested
before it carry sha256 instead), reader, truncated, problems}, ``extrinsics`` (T_base_sensor from static TF),
``sensors`` (topics,
frames, intrinsics, Ouster metadata), ``ingest`` (mapping, tolerance, counts, drops, warnings).

Modules: :mod:`.roles` (topic mapping), :mod:`.streams` (one decoder per kind of sensor message),
:mod:`.plan` (index and sync passes), :mod:`.write` (the write pass), :mod:`.listing`
(``ingest --list``), :mod:`.run` (orchestrates them: :func:`ingest`, locally or one Dask task per
recording); this module only re-exports. Each recording is opened once (:func:`open_for_ingest`)
and the opened :class:`~holodata.readers.base.Recording` is passed down to the grid pre-pass
(:func:`radar_grid`), the plan and the write pass; whoever opened it closes it.

Truncated recordings (recorder crash, file cut short): the readable prefix is ingested and the
scene is marked ``source.truncated = true`` with the reason; ``ingest`` warns. Recordings with no
radar, point cloud, depth or Ouster topic (camera-only, IMU-only, strings, non-ROS MCAP) are
rejected with a one-line reason.
"""

from __future__ import annotations

from .listing import format_listing, list_recording
from .plan import Plan, plan_recording
from .plan import _grid_of as _grid_of
from .plan import _limit_malloc_arenas as _limit_malloc_arenas
from .plan import _scene_id as _scene_id
from .radar_streams import radar_stream as radar_stream

# ``name as name``: importable from the package since its code lived here, kept so; not in __all__
from .roles import RADAR_SUFFIX as RADAR_SUFFIX
from .roles import TopicMap, load_topics_file, map_topics
from .run import IngestOptions, check_grid, ingest, ingest_dask, ingest_one, open_for_ingest, radar_grid
from .run import _create as _create
from .run import _error_line as _error_line
from .run import _failures as _failures
from .run import _ingest_task as _ingest_task
from .run import _passes as _passes
from .write import write_plan

__all__ = ["ingest", "ingest_one", "open_for_ingest", "IngestOptions", "ingest_dask",
           "plan_recording", "write_plan", "check_grid", "radar_grid", "list_recording",
           "format_listing", "map_topics", "load_topics_file", "Plan", "TopicMap"]
