"""``holodata slam``: LiDAR poses per scan, radar poses through the extrinsic, and the static mesh.

Pipeline (all poses ``T_world_sensor``, 4×4 float64, REP-103):

1. **Scans** (:func:`load_scans`): ``lidar/points`` (sensor frame) per frame, the per-point time
   ``lidar/point_time_ns`` (relative to the scan stamp) when present, the scan stamp
   ``lidar/timestamp_ns`` (``time/timestamp_ns`` for LiDAR-framed scenes). Frames without a scan
   and frames repeating the previous scan are skipped (their poses are interpolated). ``holodata
   slam`` reads them in a thread while the refinement (3.) already works on the first ones
   (:func:`stream_scans`).
2. **Odometry** (:func:`kiss_odometry`): kiss-icp 1.3's Python API configured for indoor
   corridors: voxel ``SlamConfig.voxel`` (0.1–0.2 m), max range from the data (99.5th percentile
   of the ranges of the first scans, +10 %), min range ``min_range``, deskew with the per-point
   time. kiss-icp reports the pose at the *last* point time of a scan (its deskew reference).
3. **Refinement** (:func:`refine`): scan-to-map point-to-plane ICP in open3d (Tukey kernel,
   coarse-to-fine correspondence distances), initial guesses from kiss-icp's relative motion,
   own deskew (constant twist over the scan from the neighbouring refined poses; each scan is
   registered at the middle of its sweep, where a wrong twist biases the pose least, and moved to
   the scan stamp through the twist, so ``pose/T_world_lidar[k]`` is the pose at
   ``lidar/timestamp_ns[k]``: ``docs/design/slam.md``, yaw drift on a sparse 10 Hz LiDAR), and
   optionally (``global_pass``) a second pass against the whole map with moving points removed by
   the voxel background model. Where TF's LiDAR poses are a ground robot's on a level floor
   (:func:`level_tf_poses`) or the seeds are (``seed_poses="tf"``), height, roll and pitch are
   theirs and the ICP sets the other three. kiss-icp and the refinement run in one pass (:class:`KissStream`):
   a scan taken at rest (one point-to-plane Gauss-Newton step from the last refined pose against
   the map below ``still_check_m`` / ``still_check_deg``) holds that pose and is fed to neither
   kiss-icp nor ICP, so a robot that stands for most of a long recording costs little; on organised
   scans the check reuses the map correspondences of the last scan that passed it, pixel by pixel
   (:class:`_SameBeam`: no downsampling, no nearest-neighbour search).
   (Bare kiss-icp lags while the robot accelerates from rest; the refinement is what makes the
   poses centimetre-accurate: ``docs/design/slam.md``.)
4. **World frame**: when TF connects the LiDAR to a world frame (ingest's ``tf/T_world_lidar``;
   else its TF radar poses ``pose/T_world_radar`` with ``source: tf`` through the extrinsics; slam
   reads the dataset only, never the source recording), the first scan TF covers is anchored at its TF pose, so the map lives in
   TF's world frame (where static camera TF and odometry live; TF may start after the LiDAR);
   else the world is the base frame at the first scan (``extrinsics.lidar`` = T_base_lidar), else
   the first LiDAR pose is the identity. ``pose/T_world_lidar`` says which (``world_frame``,
   ``anchor``).
5. **Radar poses**: ``T_world_radar(t) = T_world_lidar(t) · T_base_lidar⁻¹ · T_base_radar`` with
   ``T_world_lidar(t)`` interpolated (SLERP) at each frame time ``time/timestamp_ns``.

Modules: :mod:`.config` (settings and results), :mod:`.scans` (reading the scans), :mod:`.points`
(normal helpers; voxels and ICP are :mod:`holodata.geometry`'s), :mod:`.odometry` (kiss-icp,
deskewing), :mod:`.refine` (scan-to-map ICP), :mod:`.world` (world frame, per-frame poses, the
static mesh), :mod:`.localise` (localisation against a mapping pass, :func:`localise_scene`),
:mod:`.store` (the writes and a finished scene read back), :mod:`.pipeline` (slam's steps on one
scene, :func:`~.pipeline.run_slam`), :mod:`.entry` (the entry points :func:`slam_scene` and
:func:`slam_dataset`); this module only re-exports.

Outputs (written with the dataset writer, whole arrays, atomically): ``pose/T_world_lidar``
(T,4,4), ``pose/T_world_radar`` (T,4,4) when there is a radar or a radar extrinsic (replacing the
odometry poses ingest took from TF), ``mesh/vertices`` + ``mesh/faces`` (:func:`static_mesh`, :mod:`.mesh`;
the background model of its scans is built in a forked process beside the point accumulation) and
``map/points``, the static point map the mesh was reconstructed from (``holodata register``'s
target), scene
attribute ``slam`` (config, counts, timings, health figures). A TUM trajectory and a PLY are
optional exports.
"""
from __future__ import annotations

# ``name as name``: importable from the package since its code lived here, kept so; not in __all__
from .config import Scans, SlamConfig, SlamOutputs, SlamResult
from .entry import own_mapping_pass as own_mapping_pass
from .entry import slam_dataset, slam_scene
from .localise import MAPPING_ROLE, check_map_scene, localise_scene
from .odometry import KissStream as KissStream
from .odometry import _Fixed as _Fixed
from .odometry import deskew, kiss_odometry, twist
from .pipeline import _export as _export
from .pipeline import _odometry as _odometry
from .pipeline import _only_scene as _only_scene
from .pipeline import _scans_and_poses as _scans_and_poses
from .refine import RefineOptions, global_refine, mesh_scan_subset, refine
from .scans import _import_in_background as _import_in_background
from .scans import _StreamBroken as _StreamBroken
from .scans import data_max_range, load_scans, stream_scans
from .store import _fingerprint as _fingerprint
from .store import _stored_result as _stored_result
from .store import _write as _write
from .store import write_static_map
from .world import StaticMap, anchor_pose, frame_poses, guess_poses, static_mesh, tf_lidar_poses
from .world import level_tf_poses as level_tf_poses
from .world import tf_agreement as tf_agreement

__all__ = ["SlamConfig", "SlamOutputs", "SlamResult", "StaticMap", "write_static_map", "Scans", "load_scans",
           "kiss_odometry", "refine", "RefineOptions", "global_refine",
           "static_mesh", "slam_scene", "slam_dataset", "deskew", "twist", "anchor_pose", "tf_lidar_poses", "frame_poses",
           "localise_scene", "check_map_scene", "guess_poses", "MAPPING_ROLE", "stream_scans",
           "data_max_range", "mesh_scan_subset"]
