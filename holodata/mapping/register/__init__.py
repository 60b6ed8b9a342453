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
:mod:`.steps` (the named steps :func:`register_scene` runs); the ICP solver, voxel means and plane
fits are :mod:`holodata.geometry`'s. This module holds the pipeline (:func:`register_scene`, the
LiDAR half and its map, fingerprints, the report).

**Processes** (``processes``, default two on a two-CPU machine; :mod:`holodata.parallel`): the LiDAR
half (background model, map unless slam's is used, segmentation of every scan) runs in a forked
process beside the camera half; after the extrinsic, the human candidates of the later half of the
frames and every other frame's surface are made in another one. The results are the same as in
one process (test).
"""
from __future__ import annotations

import time

import numpy as np

from ...dataset.layout import (CALIB_T_WORLD_CAMERA, CAMERA_POINTS, CAMERA_POINTS_WORLD, CAMERA_TIMESTAMP_NS, HUMAN_FACES,
                               HUMAN_POINTS, HUMAN_VERTICES, LIDAR_INSTANCE, MAP_POINTS, MESH_FACES, MESH_VERTICES,
                               POSE_T_WORLD_LIDAR, TIME_TIMESTAMP_NS)
from ...errors import InputError
from ...parallel import cpus, fork_call, release_free_memory
from .config import RegisterConfig, Registration, RegistrationError
from ...geometry.voxels import voxel_average
from .extrinsic import (anchored_guess, fpfh_ransac, held_directions, icp, map_normals, mesh_surface_samples,
                        pose_uncertainty, register_extrinsic)
from .camera import (_camera_points_through, camera_points_world, camera_seen_through, camera_swept, CameraFrames,
                     depth_noise_model, noise_coefficient, static_depth, static_depth_of)
from .steps import (all_surfaces, body_columns_of, clear_outputs, frame_cuts, human_candidates, human_shift,
                    initial_guess, pick_track, registration_failure, static_camera, track_smoothing, write_outputs)
from .humans import body_columns, closed_surface, cluster_points, pick_human, pixel_runs, static_residual, voxel_boundary
from .tracks import radial_speed, track_jumps, track_prediction, track_velocity, velocity_shift


# ------------------------------------------------------------------------------------ pipeline
def _parse_init(init) -> np.ndarray | None:
    if init is None:
        return None
    a = np.asarray(init, float)
    if a.shape == (4, 4):
        return a
    if a.shape == (6,):
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", np.deg2rad(a[3:])).as_matrix()
        T[:3, 3] = a[:3]
        return T
    raise InputError(f"--init needs x,y,z,roll,pitch,yaw (m, degrees), got {init!r}")


def map_cloud(scans, bg, traj, voxel: float, deskew: bool = True, instances=None, margin_m: float = 0.25,
              max_scans: int = 0, world_points: dict | None = None) -> np.ndarray:
    """World-frame static map: every scan's returns inside the background model and farther than
    ``margin_m`` from the scan's segmented instances ``instances`` (lazy (T,H,W) array or None),
    voxel-thinned; at most ``max_scans`` scans (0: all): motion keyframes plus scans spread in time,
    as for slam's mesh (a 400-cycle corner has 400 scans, most taken at rest). The instance margin
    removes the parts of people that fall into static voxels (a hand near a wall, feet on the
    floor), which would otherwise bias the registration. ``world_points``: {frame: world points of
    the valid returns (N,3)} already de-skewed with ``traj`` (the segmentation's background pass);
    scans in it without instances are taken from it instead of being read and de-skewed again."""
    from scipy.spatial import cKDTree

    from ..segment import in_background

    pts = []
    ks = list(range(len(scans.stamps)))
    if max_scans and len(ks) > max_scans:  # long recordings: motion keyframes + scans evenly spread in time
        from ..slam import mesh_scan_subset

        ks = [k for k in ks if scans.usable(k)]
        ks = [ks[i] for i in mesh_scan_subset(np.asarray(scans.poses)[ks], max_scans)]
    for k in ks:
        inst = np.asarray(instances[k]) > 0 if instances is not None else None
        if world_points is not None and k in world_points and (inst is None or not inst.any()):
            p = np.asarray(world_points[k], np.float64)
        else:
            valid, _, Pw = scans.scan(k, traj, deskew)
            if inst is not None and (inst & valid).any():
                d, _ = cKDTree(Pw[inst & valid]).query(Pw[valid], k=1, distance_upper_bound=margin_m, workers=-1)
                keep = np.zeros_like(valid)
                keep[valid] = ~np.isfinite(d)
                valid = keep
            p = Pw[valid]
        if bg is not None and len(p):
            p = p[in_background(bg, p, 0)]
        if len(p):
            pts.append(voxel_average(p, voxel))
    if not pts:
        return np.zeros((0, 3))
    return voxel_average(np.concatenate(pts), voxel)


def lidar_map(scene, cfg: RegisterConfig, segment: bool, quiet: bool = True, build_map: bool = True,
              segment_cfg=None, early=None) -> tuple[np.ndarray | None, dict | None, dict]:
    """The LiDAR half of :func:`register_scene` (step 2 and the segmentation) of ``scene`` (a read
    handle; run in a forked process, which opens its own writers): background model,
    the static map (when ``build_map``) and, when ``segment``, ``lidar/instance``. The map is built
    first, with the instance masks of the few map scans that have foreground computed on the spot,
    and handed to ``early`` (a callback, or None) before the segmentation of every scan starts.
    Returns (map points (M,3) float64 world or None, segmentation summary or None, timings
    {background_s, map_s, segment_s})."""
    from ..segment import InstanceMasks, LidarScans, SegmentConfig, background_and_segment, write_instances

    t0 = time.perf_counter()
    scans = LidarScans.open(scene, scene.ds.url)
    traj = scans.trajectory()
    scfg = segment_cfg or SegmentConfig()
    bg, _, world_points = background_and_segment(scene, scfg, quiet, segment=False, scans=scans, traj=traj)
    t1 = time.perf_counter()
    if segment:
        inst = InstanceMasks(scans, bg, scfg, traj, world_points)
    else:
        inst = scene[LIDAR_INSTANCE] if LIDAR_INSTANCE in set(scene.arrays()) else None
    M = map_cloud(scans, bg, traj, cfg.map_voxel, instances=inst, max_scans=cfg.map_max_scans,
                  world_points=world_points) if build_map else None
    t2 = time.perf_counter()
    if early is not None:
        early(M)
    seg_summary = (write_instances(scene, scfg, quiet, background=bg, world_points=world_points, masks=inst,
                                   scans=scans, traj=traj)
                   if segment else None)         # the masks the map asked for are not computed again
    return M, seg_summary, {"background_s": t1 - t0, "map_s": t2 - t1, "segment_s": time.perf_counter() - t2}


def camera_world(scene, T: np.ndarray) -> None:
    """Write ``camera/points_world`` of ``scene`` (a read handle; the array made by the caller): every
    camera point in the map frame through ``T`` (4,4) T_world_camera, float32, shard by shard (the
    recording's clouds never sit in memory together)."""
    from ...dataset import open_dataset

    arr = open_dataset(scene.ds.url, "r+").scene(scene.id).ragged_array(CAMERA_POINTS_WORLD)
    for s in range(arr.n_shards):
        sl = arr.frames(s)
        arr.write_shard(s, [_camera_points_through(scene, T, k) for k in range(sl.start, sl.stop)])


def register_processes(cfg: RegisterConfig) -> int:
    """Processes :func:`register_scene` uses: ``cfg.processes``, or with 0 two when the machine has two
    CPUs for it (one otherwise)."""
    if cfg.processes:
        return max(1, int(cfg.processes))
    return 2 if cpus() >= 2 else 1


def _built_from_the_poses(scene, names: tuple) -> bool:
    """True when the scene holds the arrays ``names`` and each one's ``source`` attribute equals
    ``pose/T_world_lidar``'s (``holodata slam`` writes "slam" on its poses, mesh and map; poses
    replaced afterwards, e.g. by the true ones, leave products that no longer match them)."""
    nodes = scene.nodes()
    names = names + (POSE_T_WORLD_LIDAR,)
    if not all(n in nodes for n in names):
        return False
    src = [(nodes[n][1].get("attributes") or {}).get("source") for n in names]
    return src[0] is not None and len(set(src)) == 1


def slam_anchor(scene) -> np.ndarray | None:
    """(3,) m: the LiDAR position at the first scan when the scene's poses are ``holodata slam``'s,
    anchored at the TF pose of that scan (their world is the TF world, off by the odometry's error
    there); None otherwise."""
    nodes = scene.nodes()
    if POSE_T_WORLD_LIDAR not in nodes:
        return None
    if (nodes[POSE_T_WORLD_LIDAR][1].get("attributes") or {}).get("source") != "slam":
        return None
    anchor = (scene.attrs.get("slam") or {}).get("anchor") or {}
    T0 = anchor.get("T_world_lidar0")
    if anchor.get("kind") != "tf" or T0 is None:
        return None
    return np.asarray(T0, np.float64)[:3, 3]


def scene_mesh(scene) -> tuple[np.ndarray, np.ndarray] | None:
    """The scene's static mesh (``mesh/vertices`` (V,3), ``mesh/faces`` (F,3)) when it was built from
    the poses the scene holds now (:func:`_built_from_the_poses`); None otherwise."""
    if not _built_from_the_poses(scene, (MESH_VERTICES, MESH_FACES)):
        return None
    return np.asarray(scene[MESH_VERTICES][...], np.float64), np.asarray(scene[MESH_FACES][...], np.int64)


def scene_map(scene) -> np.ndarray | None:
    """slam's static map ``map/points`` (M,3) float64 world when it was built from the poses the scene
    holds now (:func:`_built_from_the_poses`); None otherwise."""
    if not _built_from_the_poses(scene, (MAP_POINTS,)):
        return None
    return np.asarray(scene[MAP_POINTS][...], np.float64)


def camera_tf_guess(scene) -> tuple[str | None, list | None]:
    """(world frame, T_world_camera 4x4 nested list) of the camera's static TF pose that ingest stored
    (``sensors.camera.T_<world>_sensor``); (None, None) without one."""
    cam = (scene.attrs.get("sensors") or {}).get("camera") or {}
    for k, v in cam.items():
        if k.startswith("T_") and k.endswith("_sensor") and v is not None:
            return k[2:-len("_sensor")], v
    return None, None


def map_frame_problem(scene, world: str) -> str | None:
    """Why the scene's LiDAR poses (``pose/T_world_lidar``, hence its map) are not in the TF frame
    ``world``, or None when they are: slam found no TF pose of the LiDAR (its world is then the
    first scan's frame: ``anchor`` base or lidar), or its poses name another world frame."""
    nodes = scene.nodes()
    if POSE_T_WORLD_LIDAR not in nodes:
        return None
    a = nodes[POSE_T_WORLD_LIDAR][1].get("attributes") or {}
    if a.get("source") == "slam" and a.get("anchor") not in (None, "tf"):
        return (f"the LiDAR map is in the {a.get('world_frame') or 'first scan frame'} (slam found no TF pose of "
                f"the LiDAR: TF does not connect its frame to {world!r})")
    wf = a.get("world_frame")
    if wf and (a.get("source") != "slam" or a.get("anchor") == "tf") and str(wf).lstrip("/") != world.lstrip("/"):
        return f"the LiDAR map is in {wf!r}"
    return None


REGISTER_OUTPUTS = (CALIB_T_WORLD_CAMERA, HUMAN_VERTICES, HUMAN_FACES, HUMAN_POINTS)
# scene attribute of a camera that could not be registered: register's report, ``registered`` False
# (the scene finished without a person, :func:`unregistered`); cleared by a registration that passes
REGISTER_FAILED = "register_failed"
# Switches deleted (issue 25: off by default, never used) after datasets were registered with them:
# their only value stays in the fingerprint, so a scene registered before still reads as done.
RETIRED_PARAMS = {"noise_weights": False, "max_std_m": 0.0, "search_m": 0.0, "mesh_keep_map_m": 0.0}
RETIRED_SEGMENT_PARAMS = {"grow_pixels": 0}


def register_fingerprint(scene, cfg: RegisterConfig, init, segment_cfg=None) -> str:
    """What register's outputs depend on, hashed: the settings (less ``processes``, which changes no
    result; with :data:`RETIRED_PARAMS`), ``--init``, the camera's TF pose and intrinsics
    (``sensors.camera``), ingest's fingerprint (the camera and LiDAR arrays) and the bytes of slam's
    poses, map points and mesh."""
    import hashlib
    import json

    h = hashlib.sha256()
    params = {**RETIRED_PARAMS, **{k: v for k, v in cfg.to_attrs().items() if k != "processes"}}
    head = {"params": params, "init": None if init is None else np.asarray(_parse_init(init), float).tolist(),
            "camera": (scene.attrs.get("sensors") or {}).get("camera"),
            "ingest": (scene.attrs.get("ingest") or {}).get("fingerprint")}
    if segment_cfg is not None:                      # a segmentation other than the default's
        head["segment"] = {**RETIRED_SEGMENT_PARAMS, **segment_cfg.to_attrs()}
    h.update(json.dumps(head, sort_keys=True, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)).encode())
    names = set(scene.arrays())
    for name in (POSE_T_WORLD_LIDAR, MAP_POINTS, MESH_VERTICES, MESH_FACES):
        if name in names:
            h.update(name.encode())
            h.update(np.ascontiguousarray(scene[name][...]).tobytes())
    return h.hexdigest()[:16]


def camera_scenes(ds) -> list[str]:
    """The scenes of dataset ``ds`` (a read handle) that have a camera (``camera/points``): the ones
    register can register. A mapping pass (LiDAR + odometry only, ``role: mapping``) has none."""
    return [sid for sid in ds.scenes if CAMERA_POINTS in set(ds.scene(sid).arrays())]


def only_camera_scene(ds, url: str) -> str:
    """The one scene of ``ds`` with a camera (:func:`camera_scenes`); InputError (one line) with none or
    several."""
    cams = camera_scenes(ds)
    if len(cams) == 1:
        return cams[0]
    if not cams:
        raise InputError(f"{url}: no scene has a camera (camera/points) to register; scenes: {', '.join(ds.scenes) or 'none'}")
    raise InputError(f"{url}: {len(cams)} scenes have a camera ({', '.join(cams)}); pick one with --scene")


def register_scene(url: str, scene_id: str | None = None, init=None, cfg: RegisterConfig | None = None,
                   quiet: bool = True, force: bool = False, segment_cfg=None) -> dict:
    """``holodata register``: extrinsic + human points/surfaces for one scene (see the module
    docstring); ``segment_cfg``: the LiDAR segmentation's :class:`~holodata.mapping.segment.SegmentConfig`
    (None: its defaults). Returns a summary dict; raises :class:`RegistrationError` (one line; its
    ``report`` the summary) if no registration passes, after finishing the scene without a person
    (:func:`unregistered`): a camera that cannot be registered costs the scene its person, not the
    scene. ``scene_id`` None: the one scene with a camera (:func:`camera_scenes`).
    A scene registered before from the same inputs and settings (:func:`register_fingerprint`, every
    output present) is not registered again unless ``force``: the stored report comes back with
    ``skipped`` set, as slam does. The steps are :mod:`.steps`'."""
    from ...dataset import open_dataset
    from ..segment import LidarScans, _scene_id

    cfg = cfg or RegisterConfig()
    t0 = time.perf_counter()
    timings: dict = {}
    ds = open_dataset(url)
    scene = ds.scene(_scene_id(ds, url, scene_id) if scene_id is not None else only_camera_scene(ds, url))
    where = f"{url}: scene {scene.id!r}"
    scene.require_complete("register")
    fingerprint = register_fingerprint(scene, cfg, init, segment_cfg)
    resuming = "register" in scene.unfinished    # an interrupted run: its outputs are not to be trusted
    skipped = None if force or resuming else stored_report(scene, cfg, fingerprint)
    if skipped is not None:
        return skipped
    release_free_memory()      # (before the forks below)
    cam = CameraFrames.open(scene, url)
    LidarScans.open(scene, url)   # checks the LiDAR arrays and poses before any work starts
    T_init, init_source = initial_guess(scene, url, _parse_init(init))
    processes = register_processes(cfg)
    # marked unfinished before the first write (lidar/instance, by the LiDAR half), finished with the
    # ``register`` report after the last
    sw = open_dataset(url, "r+").scene(scene.id)
    sw.begin("register", rerun=f"rerun holodata register DATASET --scene {scene.id} to finish it")
    outputs_touched = False
    # 1.-2. the LiDAR half (segmentation, map) and the camera half (depth images, static depth) are
    # independent until the extrinsic: side by side in two processes (the LiDAR one quiet)
    stored_map, lidar = lidar_half(scene, cfg, segment_cfg, processes, quiet, where)
    try:
        t1 = time.perf_counter()
        static = static_camera(cam, cfg, quiet)
        if static is None:
            if stored_map is None:
                lidar.early()
            raise InputError(f"{where}: camera/points is empty in every frame")
        timings["camera_s"], t1 = time.perf_counter() - t1, time.perf_counter()
        M = stored_map if stored_map is not None else lidar.early()   # (the LiDAR process goes on segmenting)
        timings["map_wait_s"], t1 = time.perf_counter() - t1, time.perf_counter()
        if len(M) < 100:
            raise InputError(f"{where}: the LiDAR map is empty (no usable scans/poses)")
        # 3. extrinsic (onto slam's mesh near the camera where it was built from these poses)
        reg = register_extrinsic(static.points, M, T_init, cfg, sigma=static.sigma,
                                 mesh=scene_mesh(scene) if cfg.mesh_target else None,
                                 anchor=slam_anchor(scene) if init_source == "tf" else None)
        timings["extrinsic_s"], t2 = time.perf_counter() - t1, time.perf_counter()
        if not reg.accepted:
            # the scene stays usable (mesh, poses, lidar/instance) and finished, without a person
            outputs_touched = True
            line = registration_failure(where, reg, cfg, init_source)
            report, seg_summary = unregistered(sw, reg, lidar, line, init_source, T_init, stored_map is not None, cfg,
                                               scene.n_frames, time.perf_counter() - t0, timings, fingerprint)
            out = {"scene": scene.id, **{k: v for k, v in report.items() if k not in ("params", "T_init")}}
            if seg_summary:
                out["segment"] = seg_summary
            raise RegistrationError(line, report=out)
        T, eye, f_px = reg.T, reg.T[:3, 3], float(cam.K[0, 0])
        # 4. humans (camera/points_world written by a second process meanwhile)
        outputs_touched = True
        clear_outputs(sw, cfg)
        cam_world = fork_call(camera_world, scene, T, label=f"{where}: camera/points_world",
                              enabled=processes > 1) if cfg.write_camera_world else None
        cand = human_candidates(cam, static, M, T, cfg, processes, quiet, where)
        del static.images
        timings["candidates_s"] = time.perf_counter() - t2
        ts = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64)
        cts = np.asarray(scene[CAMERA_TIMESTAMP_NS][...], np.int64) if CAMERA_TIMESTAMP_NS in scene.arrays() else ts
        sigma_a = noise_coefficient(static.med, static.mad)
        picks = pick_track(cand.frames, M, eye, f_px, np.where(cts != 0, cts, ts), cfg, sigma_a)
        shift = human_shift(picks.points, cts, ts, cfg)
        columns = body_columns_of(picks, eye, f_px, cts, cfg)
        cuts = frame_cuts(picks, static.med, cfg, sigma_a)
        shift = shift + track_smoothing(picks.points, columns, shift, eye, ts, cfg, cuts)
        picks.pixels = []
        timings["picks_s"] = time.perf_counter() - t2 - timings["candidates_s"]
        if cam_world is not None:
            cam_world()
        # 5. closed surfaces, then the writes
        surfaces = all_surfaces(picks.points, columns, shift, eye, cfg, processes, where)
        timings["humans_s"] = time.perf_counter() - t2
        write_outputs(sw, surfaces, picks.points, T)
        t1 = time.perf_counter()
        seg_summary = None
        if lidar is not None:
            _, seg_summary, lidar_timings = lidar()   # the segmentation of every scan (lidar/instance)
            timings.update(lidar_timings)
        timings["segment_wait_s"] = time.perf_counter() - t1
        report = register_report(reg, init_source, T_init, stored_map is not None, surfaces, cand.carved,
                                 picks.repicked, cfg, shift, time.perf_counter() - t0, timings, fingerprint, cuts)
        sw.finish("register", {"register": report, REGISTER_FAILED: None})
    except BaseException as err:
        if lidar is not None:
            lidar.join()   # it must not write on after register has failed
        if isinstance(err, Exception) and not outputs_touched and not resuming:
            # refused (or failed on an error of its own) before its outputs were touched (lidar/instance,
            # if written, is whole: its shards committed, the LiDAR process joined): the scene is as
            # consistent as before, so the failure leaves no mark; an interrupt (Ctrl-C) does
            sw.finish("register")
        raise
    out = {"scene": scene.id, **{k: v for k, v in report.items() if k not in ("params", "T_init")}}
    if seg_summary:
        out["segment"] = seg_summary
    return out


def unregistered(sw, reg: Registration, lidar, line: str, init_source: str, T_init: np.ndarray, slam_map: bool,
                 cfg: RegisterConfig, n_frames: int, seconds: float, timings: dict,
                 fingerprint: str) -> tuple[dict, dict | None]:
    """A camera that cannot be registered (``reg`` not accepted; ``line`` the one-line reason,
    :func:`registration_failure`) costs the scene its person, not the scene: a previous run's person
    and extrinsic (made from other inputs or settings) are removed, the LiDAR half (``lidar``, or
    None) finishes the segmentation, and the scene is finished through scene writer ``sw`` with the
    report in the scene attribute :data:`REGISTER_FAILED` (``registered`` False, ``warning``: ``line``,
    every attempt's numbers) and no ``register`` attribute (it declares register's outputs). Its mesh
    and poses stay: raytrace-gt traces it without a person, validate accepts it. Returns (the report,
    the segmentation summary or None)."""
    clear_outputs(sw, cfg, calib=True)
    seg_summary = None
    if lidar is not None:
        _, seg_summary, lidar_timings = lidar()
        timings.update(lidar_timings)
    report = {"registered": False, "warning": line, "extrinsic": reg.to_attrs(), "init": init_source,
              "T_init": np.asarray(T_init).tolist(), "map": "slam (map/points)" if slam_map else "built from the LiDAR scans",
              "frames_with_human": 0, "frames": int(n_frames), "params": cfg.to_attrs(), "seconds": seconds,
              "timings": timings, "fingerprint": fingerprint}
    # (not under ``register``: that attribute declares register's outputs, which validate then requires)
    sw.finish("register", {"register": None, REGISTER_FAILED: report})
    return report, seg_summary


def lidar_half(scene, cfg: RegisterConfig, segment_cfg, processes: int, quiet: bool, where: str):
    """(slam's static map of ``scene`` or None, the forked :func:`lidar_map` or None): the LiDAR half
    runs when the scene needs ``lidar/instance`` (made with other poses: made again; left unfinished:
    resumed) or has no map of slam's to register against; with ``processes`` > 1 in a second process."""
    from ..segment import instance_state

    segment = cfg.segment_lidar and instance_state(scene) != "current"
    stored_map = scene_map(scene) if cfg.slam_map else None
    if not segment and stored_map is not None:
        return stored_map, None
    return stored_map, fork_call(lidar_map, scene, cfg, segment, quiet or processes > 1, stored_map is None, segment_cfg,
                                 label=f"{where}: LiDAR map", enabled=processes > 1, early=stored_map is None)


def stored_report(scene, cfg: RegisterConfig, fingerprint: str) -> dict | None:
    """The report of a scene registered before from the same inputs and settings (``fingerprint``),
    every output present (and ``lidar/instance`` current when segmenting), with ``skipped`` set; else
    None."""
    from ..segment import instance_state

    done = scene.attrs.get("register") or {}
    if (done.get("fingerprint") == fingerprint and set(REGISTER_OUTPUTS) <= set(scene.arrays())
            and (not cfg.segment_lidar or instance_state(scene) == "current")):
        return {"scene": scene.id, **{k: v for k, v in done.items() if k not in ("params", "T_init")},
                "skipped": "already done with the same inputs and settings (use --force to recompute)"}
    return None


def register_report(reg: Registration, init_source: str, T_init: np.ndarray, slam_map: bool, surfaces: list,
                    carved: np.ndarray, repicked: int, cfg: RegisterConfig, shift: np.ndarray, seconds: float,
                    timings: dict, fingerprint: str, cuts: np.ndarray) -> dict:
    """The scene attribute ``register``: the extrinsic's report, where the guess and the map came
    from, frames with a person (and those partly hidden, placed from the track: ``frames_cut``, with
    each frame's cut share ``cut_share``), the settings, timings and the fingerprint."""
    n = len(surfaces)
    cuts = np.asarray(cuts, float)
    return {"registered": True, "extrinsic": reg.to_attrs(), "init": init_source, "T_init": np.asarray(T_init).tolist(),
            "map": "slam (map/points)" if slam_map else "built from the LiDAR scans",
            "frames_with_human": int(sum(len(s[1]) > 0 for s in surfaces)), "frames": n,
            "frames_cut": np.flatnonzero(cuts >= cfg.cut_share).tolist(), "cut_share": np.round(cuts, 3).tolist(),
            "map_points_seen_through": int(carved.sum()), "frames_repicked": repicked, "params": cfg.to_attrs(),
            "surface": "voxel boundary (half-filled voxels) of elliptic per-run columns behind the "
                       "visible front (closed)",
            "velocity_shift_m_max": float(np.nanmax(np.linalg.norm(shift, axis=1))) if n else 0.0,
            "seconds": seconds, "timings": timings, "fingerprint": fingerprint}


__all__ = ["RegisterConfig", "Registration", "RegistrationError", "register_extrinsic", "icp", "fpfh_ransac",
           "closed_surface", "voxel_boundary", "cluster_points", "pick_human", "static_depth", "camera_points_world",
           "CameraFrames", "register_scene", "velocity_shift", "map_cloud", "static_residual",
           "body_columns", "pixel_runs",
           "depth_noise_model", "map_normals", "pose_uncertainty", "track_prediction",
           "track_jumps", "track_velocity", "radial_speed", "mesh_surface_samples",
           "scene_mesh", "held_directions", "anchored_guess", "static_depth_of",
           "register_fingerprint", "scene_map", "slam_anchor", "camera_seen_through", "camera_swept",
           "camera_scenes", "only_camera_scene", "REGISTER_FAILED"]
