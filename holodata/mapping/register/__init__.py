"""``holodata register``: the depth camera's one-time extrinsic in the map, and per-frame human
points and closed human surfaces in the map frame. Why each step is done as it is, and what was
measured on the way: ``docs/design/register.md``.

Inputs (a dataset scene): ``camera/points`` (ragged, camera frame; for depth images the optical
frame, with the intrinsics in ``sensors.camera.intrinsics``), the LiDAR map (``map/points`` of
``holodata slam``, or ``lidar/points`` + ``pose/T_world_lidar``), ``camera/timestamp_ns`` and
``time/timestamp_ns``.

1. **Static camera cloud** (:func:`static_depth`): the camera does not move, so per pixel the
   depth over up to ``median_frames`` frames, averaged over its background samples (a moving person
   is only ever in front of the static scene), is a denoised picture of the static scene.
2. **Map** (:func:`scene_map`): slam's static point map when it was built from the scene's poses;
   else every scan in the world frame minus the LiDAR foreground and the segmented people
   (:func:`map_cloud`).
3. **Extrinsic** ``T_world_camera`` (:func:`register_extrinsic`): point-to-plane Gauss-Newton ICP
   with a Tukey loss, coarse to fine (``icp_distances``), of the static camera cloud onto the map
   (denoised onto local planes, :func:`holodata.geometry.local_plane_projection`) and slam's mesh
   near the camera (:func:`mesh_surface_samples`), from ``--init`` or the TF pose. Directions the overlap does not
   pin down are held at the guess (or where the SLAM map's own turn puts it, :func:`anchored_guess`)
   instead of sliding. Accepted only when overlap, fitness, RMSE and the pose's standard deviation
   along the directions the data measured (:func:`pose_uncertainty`) pass; a held direction is
   accepted at the guess's stated precision (``guess_std_m``, ``--guess-std``; reported as its
   uncertainty: the data can neither confirm nor improve the guess there, :func:`~.extrinsic.check_held`).
   Else FPFH + RANSAC then the same ICP and check; else the camera is not registered: the scene is
   finished without a person (mesh, poses and ``lidar/instance`` kept; scene attrs
   ``register_failed`` with every attempt's numbers) and :class:`RegistrationError` says why in one line.
4. **Human points per frame** (:func:`frame_candidates`, :func:`pick_human`): returns in front of
   the static depth (a moving person) or on no large plane of the static cloud (a person standing
   still), not explained by the map; the largest person-like cluster near the track, outliers
   removed; picks that jump are picked again near the track's prediction (:func:`track_jumps`).
5. **Closed surface per radar frame** (:func:`body_columns`, :func:`closed_surface`): each
   horizontal run of human pixels is an elliptic cross-section of the body behind the visible front
   (deeper behind a person walking along the view, whose far leg is hidden); the columns are
   voxelised and the boundary of the half-filled voxels is a closed, outward-oriented surface; it
   is shifted by the human's velocity from the camera stamp to the radar frame's stamp.

Outputs (scene): ``human/vertices`` + ``human/faces`` ragged per frame (world frame, float32 /
int32; what ``holodata raytrace-gt`` reads), ``human/points`` ragged (world frame),
``calib/T_world_camera`` (4,4), ``lidar/instance`` (the segmentation, :mod:`.segment`) and the
report in the scene attrs ``register``. :func:`camera_points_world` gives any frame's camera cloud
in the map frame; ``write_camera_world`` (``--camera-world``) also stores that copy
(``camera/points_world``, as large as ``camera/points``).

Modules: :mod:`.config` (settings and results), :mod:`.extrinsic` (step 3), :mod:`.camera` (step 1,
the camera's frames and candidate returns), :mod:`.humans` (steps 4–5 and the track checks),
:mod:`.steps` (the named steps :func:`register_scene` runs), :mod:`.scene_inputs` (slam's map, mesh
and anchor, the camera's TF guess, the scene with a camera, ``--init``), :mod:`.lidar_side` (the
LiDAR half and its map), :mod:`.pipeline` (:func:`register_scene`, fingerprints, the report); the
ICP solver, voxel means and plane fits are :mod:`holodata.geometry`'s. This module only re-exports.

**Processes** (``processes``, default two on a two-CPU machine; :mod:`holodata.parallel`): the LiDAR
half (background model, map unless slam's is used, segmentation of every scan) runs in a forked
process beside the camera half; after the extrinsic, the human candidates of the later half of the
frames and every other frame's surface are made in another one. The results are the same as in
one process (test).
"""
from __future__ import annotations

from .camera import (
                        CameraFrames,
                        camera_points_world,
                        camera_seen_through,
                        camera_swept,
                        depth_noise_model,
                        static_depth,
                        static_depth_of,
)
from .camera import _camera_points_through as _camera_points_through
from .camera import noise_coefficient as noise_coefficient

# ``name as name``: importable from the package since its code lived here, kept so; not in __all__
from .config import RegisterConfig, Registration, RegistrationError
from .extrinsic import (
                        anchored_guess,
                        fpfh_ransac,
                        held_directions,
                        icp,
                        map_normals,
                        mesh_surface_samples,
                        pose_uncertainty,
                        register_extrinsic,
)
from .humans import (
                        ColumnShape,
                        body_columns,
                        closed_surface,
                        cluster_points,
                        pick_human,
                        pixel_runs,
                        static_residual,
                        voxel_boundary,
)
from .lidar_side import MapInputs, map_cloud
from .lidar_side import lidar_half as lidar_half
from .lidar_side import lidar_map as lidar_map
from .pipeline import REGISTER_FAILED, register_fingerprint, register_scene
from .pipeline import REGISTER_OUTPUTS as REGISTER_OUTPUTS
from .pipeline import RETIRED_PARAMS as RETIRED_PARAMS
from .pipeline import RETIRED_SEGMENT_PARAMS as RETIRED_SEGMENT_PARAMS
from .pipeline import camera_world as camera_world
from .pipeline import register_processes as register_processes
from .pipeline import register_report as register_report
from .pipeline import stored_report as stored_report
from .pipeline import unregistered as unregistered
from .scene_inputs import _built_from_the_poses as _built_from_the_poses
from .scene_inputs import _parse_init as _parse_init
from .scene_inputs import camera_scenes, only_camera_scene, scene_map, scene_mesh, slam_anchor
from .scene_inputs import camera_tf_guess as camera_tf_guess
from .scene_inputs import map_frame_problem as map_frame_problem
from .steps import all_surfaces as all_surfaces
from .steps import body_columns_of as body_columns_of
from .steps import clear_outputs as clear_outputs
from .steps import frame_cuts as frame_cuts
from .steps import human_candidates as human_candidates
from .steps import human_shift as human_shift
from .steps import initial_guess as initial_guess
from .steps import pick_track as pick_track
from .steps import registration_failure as registration_failure
from .steps import static_camera as static_camera
from .steps import track_smoothing as track_smoothing
from .steps import write_outputs as write_outputs
from .tracks import radial_speed, track_jumps, track_prediction, track_velocity, velocity_shift

__all__ = ["RegisterConfig", "Registration", "RegistrationError", "register_extrinsic", "icp", "fpfh_ransac",
           "closed_surface", "voxel_boundary", "cluster_points", "pick_human", "static_depth", "camera_points_world",
           "CameraFrames", "register_scene", "velocity_shift", "map_cloud", "MapInputs", "static_residual",
           "body_columns", "ColumnShape", "pixel_runs",
           "depth_noise_model", "map_normals", "pose_uncertainty", "track_prediction",
           "track_jumps", "track_velocity", "radial_speed", "mesh_surface_samples",
           "scene_mesh", "held_directions", "anchored_guess", "static_depth_of",
           "register_fingerprint", "scene_map", "slam_anchor", "camera_seen_through", "camera_swept",
           "camera_scenes", "only_camera_scene", "REGISTER_FAILED"]
