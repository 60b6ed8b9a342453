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
   own deskew (constant twist over the scan from the neighbouring refined poses, reference time
   = the scan stamp, so ``pose/T_world_lidar[k]`` is the pose at ``lidar/timestamp_ns[k]``), and
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
   else its TF radar poses ``pose/T_world_radar`` with ``source: tf`` through the extrinsics, or the
   source recording's TF), the first scan TF covers is anchored at its TF pose, so the map lives in
   TF's world frame (where static camera TF and odometry live; TF may start after the LiDAR);
   else the world is the base frame at the first scan (``extrinsics.lidar`` = T_base_lidar), else
   the first LiDAR pose is the identity. ``pose/T_world_lidar`` says which (``world_frame``,
   ``anchor``).
5. **Radar poses**: ``T_world_radar(t) = T_world_lidar(t) · T_base_lidar⁻¹ · T_base_radar`` with
   ``T_world_lidar(t)`` interpolated (SLERP) at each frame time ``time/timestamp_ns``.

Modules: :mod:`.config` (settings and results), :mod:`.scans` (reading the scans), :mod:`.points`
(voxel and normal helpers), :mod:`.odometry` (kiss-icp, deskewing), :mod:`.refine` (scan-to-map
ICP), :mod:`.world` (world frame, per-frame poses, the static mesh); this module holds the entry
points (:func:`slam_scene`, :func:`localise_scene`, :func:`slam_dataset`) and the writes.

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

import threading
import time
from pathlib import Path

import numpy as np

from ...conventions import rotation_angle_deg
from ...errors import DatasetError, InputError
from ...trajectory import Trajectory, write_tum
from .config import Scans, SlamConfig, SlamResult
from .scans import _StreamBroken, data_max_range, load_scans, stream_scans
from ...geometry.voxels import first_per_voxel
from .points import _o3d_cloud
from .odometry import KissStream, _Fixed, deskew, kiss_odometry, twist
from .refine import VoxelMap, _TargetCache, global_refine, icp, mesh_scan_subset, refine
from .world import (StaticMap, _attr_T, anchor_pose, frame_poses, level_tf_poses, recording_tf_poses, static_mesh,
                    tf_agreement, tf_lidar_poses)


def _import_in_background(modules) -> threading.Thread:
    """Start importing ``modules`` in a daemon thread and return it (join it before use). kiss-icp and
    open3d take ~1 s CPU to import (open3d's visualization module pulls in dash and plotly), mostly
    Python; it runs while the scans are read, whose zarr decoding leaves the GIL free at times. An
    import error is left for the real import to raise."""
    import importlib

    def run():
        for m in modules:
            try:
                importlib.import_module(m)
            except Exception:  # noqa: BLE001 - raised again, with context, by the import that needs it
                return

    th = threading.Thread(target=run, name="holodata-slam-imports", daemon=True)
    th.start()
    return th


def _fingerprint(scene, cfg: SlamConfig, mesh_cfg) -> str:
    import hashlib
    import json

    h = hashlib.sha256(json.dumps({"slam": cfg.to_attrs(), "mesh": mesh_cfg.to_attrs() if mesh_cfg else None},
                                  sort_keys=True).encode())
    for name in ("lidar/points", "lidar/timestamp_ns", "time/timestamp_ns"):
        if name in scene:
            node = scene.nodes()[name][1]
            h.update(json.dumps(node.get("attributes", {}).get("holodata", {}).get("shards"), sort_keys=True).encode())
    return h.hexdigest()[:16]


def _odometry(scene, scans: Scans, config: SlamConfig, health: dict, timings: dict, feed, quiet: bool):
    """Poses of ``scans`` (module doc, 2.-4.): (max range, T0 the first scan's world pose, anchor info,
    refined poses (S,4,4), kiss-icp poses (S,4,4) in the world frame, their reference stamps (S,),
    the global pass' background model or None). Fills ``health`` and ``timings``; ``feed``: the
    :class:`_ScanFeed` of streamed scans (None: all read)."""
    ready = feed.wait if feed is not None else None
    if ready is not None:
        ready(min(len(scans), 10) - 1)   # data_max_range
    max_range = float(config.max_range or data_max_range(scans))
    T_a, j_a, anchor = anchor_pose(scene, scans.stamp_ns)
    T0 = T_a     # scan 0 seeded at the anchor scan's pose; the trajectory is moved onto it below
    background = None
    guess = None
    if config.refine and len(scans) > 1 and config.seed_poses == "tf":
        if ready is not None:
            ready(len(scans) - 1)
        guess, health["seed_poses"] = guess_poses(scene, scans)
    vertical = level_tf_poses(scene, scans.stamp_ns) if config.refine and guess is None else None
    if config.refine and len(scans) > 1:
        # kiss-icp and the refinement in one pass: kiss-icp is fed only the scans where the robot moves
        t0 = time.perf_counter()
        ks = KissStream(scans, config, max_range) if guess is None else _Fixed(guess, seed=True)
        poses, h1 = refine(scans, ks, config, max_range, quiet=quiet, T0=T0, ready=ready, vertical=vertical)
        K, kref = ks.poses, (ks.ref if guess is None else scans.stamp_ns.copy())
        timings["kiss_icp_s"] = h1["kiss_s"]
        timings["refine_s"] = time.perf_counter() - t0 - h1["kiss_s"]
        health["sequential"] = {"fitness_min": float(h1["fitness"][1:].min()), "fitness_mean": float(h1["fitness"][1:].mean()),
                                "rmse_max_m": float(h1["rmse"][1:].max()), "kiss_fallbacks": h1["kiss_fallbacks"],
                                "still_scans": h1["still_scans"], "still_same_beam": h1["still_same_beam"],
                                "kiss_scans": h1["kiss_scans"], "vertical_from": h1["vertical_from"],
                                "map_keyframes": h1["map_keyframes"]}
        K = (T0 @ np.linalg.inv(K[0])) @ K  # kiss-icp's poses in the world frame (module doc, 4.)
        if config.global_pass:
            t0 = time.perf_counter()
            poses, h2 = global_refine(scans, poses, config, max_range, quiet=quiet)
            timings["global_refine_s"] = time.perf_counter() - t0
            background = h2["background"]
            poses = (T0 @ np.linalg.inv(poses[0])) @ poses  # keep the world frame (the anchor) exact
            health["global"] = {"fitness_min": float(h2["fitness"].min()), "fitness_mean": float(h2["fitness"].mean()),
                                "rmse_max_m": float(h2["rmse"].max()), "rmse_mean_m": float(h2["rmse"].mean()),
                                "map_points": h2["map_points"]}
    else:
        if ready is not None:
            ready(len(scans) - 1)
        t0 = time.perf_counter()
        K, kref = kiss_odometry(scans, config, max_range, quiet=quiet)
        timings["kiss_icp_s"] = time.perf_counter() - t0
        K = (T0 @ np.linalg.inv(K[0])) @ K  # the world frame (module doc, 4.)
        poses = Trajectory(kref, K).interpolate(scans.stamp_ns) if len(scans) > 1 else K.copy()
    if j_a:   # anchored at a later scan (the first TF covers): that scan sits at its TF pose
        A = T_a @ np.linalg.inv(poses[j_a])
        poses, K = A @ poses, A @ K
    T0 = poses[0].copy()
    anchor["T_world_lidar0"] = T0.tolist()
    return max_range, T0, anchor, poses, K, kref, background


def slam_scene(dataset_url, scene_id: str | None = None, *, config: SlamConfig = SlamConfig(), mesh_config=None,
               quiet: bool = False, write: bool = True, tum: str | Path | None = None, ply: str | Path | None = None,
               force: bool = False, map_scene: str | None = None) -> SlamResult:
    """Run SLAM on one scene of the dataset at ``dataset_url`` (``scene_id`` None: its only scene).

    Writes ``pose/T_world_lidar``, ``pose/T_world_radar`` (with a radar extrinsic), ``mesh/*`` and
    the scene attribute ``slam`` when ``write``; exports the LiDAR trajectory as TUM (``tum``) and
    the mesh as PLY (``ply``). A scene already done with the same inputs and settings is not
    recomputed for writing (``force`` recomputes) — the poses are still returned.

    ``map_scene``: localisation mode (:func:`localise_scene`): the scene's scans are localised
    against the map that slam builds from that scene (a mapping pass of the same corner), whose mesh
    and map the scene then gets."""
    from ...dataset import open_dataset
    from ..mesh import MeshConfig

    from ...parallel import release_free_memory

    if map_scene is not None:
        return localise_scene(dataset_url, scene_id, map_scene, config=config, mesh_config=mesh_config, quiet=quiet,
                              write=write, tum=tum, ply=ply, force=force)
    t_all = time.perf_counter()
    release_free_memory()      # (slam forks the mesh's background model)
    mesh_config = mesh_config or MeshConfig()
    ds = open_dataset(dataset_url)
    if scene_id is None:
        if len(ds.scenes) != 1:
            raise InputError(f"{dataset_url}: {len(ds.scenes)} scenes ({', '.join(ds.scenes) or 'none'}); give --scene")
        scene_id = ds.scenes[0]
    scene = ds.scene(scene_id)
    scene.require_complete("slam")
    fp = _fingerprint(scene, config, mesh_config if config.mesh else None)
    done = scene.attrs.get("slam") or {}
    if (write and not force and done.get("complete") and done.get("fingerprint") == fp
            and "pose/T_world_lidar" in scene and (not config.mesh or ("mesh/faces" in scene and "map/points" in scene))):
        res = _stored_result(scene, done)
        if tum is not None:
            write_tum(tum, res.trajectory())
        if ply is not None and res.mesh is not None:
            from ...meshio import Mesh, write_ply

            write_ply(ply, Mesh(res.mesh[0], res.mesh[1]))
        return res
    timings: dict = {}
    health: dict = {}
    t0 = time.perf_counter()
    imports = _import_in_background(("kiss_icp.kiss_icp", "open3d"))
    streamed = stream_scans(scene) if config.refine else None
    if streamed is None:
        scans, feed = load_scans(scene, quiet=quiet), None
        timings["read_s"] = time.perf_counter() - t0
    else:
        # read while the refinement works on the first scans (the reading thread's zarr decoding and
        # open3d's ICP leave the GIL free for the other)
        scans, feed = streamed
    try:
        try:
            imports.join()
            odo = _odometry(scene, scans, config, health, timings, feed, quiet)
            if feed is not None:
                feed.wait(len(scans) - 1)   # every scan read (the mesh uses them), or the reader's error
        except _StreamBroken:
            feed.close()
            t0 = time.perf_counter()
            scans, feed = load_scans(scene, quiet=quiet), None
            timings["read_s"] = time.perf_counter() - t0
            odo = _odometry(scene, scans, config, health, timings, None, quiet)
    finally:
        if feed is not None:
            feed.close()
    if feed is not None:
        timings["read_s"], timings["read_wait_s"] = feed.read_s, feed.wait_s   # reading beside the refinement
    max_range, T0, anchor, poses, K, kref, background = odo
    Kw = K
    Tl, Tr, finfo = frame_poses(scene, scans, poses)
    mesh = map_points = minfo = None
    if config.mesh:
        t0 = time.perf_counter()
        sm = static_mesh(scans, poses, config, max_range, mesh_config, background, quiet=quiet)
        timings["mesh_s"] = time.perf_counter() - t0
        mesh, map_points, minfo = (sm.vertices, sm.faces), sm.points, sm.info
    timings = {k: round(v, 3) for k, v in timings.items()}
    summary = {"scene": scene_id, "scans": len(scans), "frames": scene.n_frames, "max_range_m": round(max_range, 3),
               "anchor": {k: v for k, v in anchor.items() if k != "T_world_lidar0"}, "health": health,
               "frames_info": {k: v for k, v in finfo.items() if k != "T_lidar_radar"}, "mesh": minfo,
               "timings": timings, "fingerprint": fp}
    agree = tf_agreement(scene, scans.stamp_ns, poses)
    if agree is not None:
        summary["tf_agreement"] = agree
    res = SlamResult(scene_id, scans.stamp_ns.copy(), poses, Kw, kref, Tl, Tr, mesh, summary, map_points)
    if write:
        _write(dataset_url, ds, scene_id, res, config, mesh_config, anchor, finfo, fp)
    if tum is not None:
        write_tum(tum, res.trajectory())
    if ply is not None and mesh is not None:
        from ...meshio import Mesh, write_ply

        write_ply(ply, Mesh(mesh[0], mesh[1]))
    summary["timings"]["total_s"] = round(time.perf_counter() - t_all, 3)
    return res


# ----------------------------------------------------------------------------------------------
# localisation against a mapping pass

MAPPING_ROLE = "mapping"   # scene attribute ``role`` of a mapping-pass scene (no train/test split, no raytrace-gt)


def check_map_scene(ds, scene_id: str, map_scene: str) -> None:
    """InputError (one line) unless ``map_scene`` is another scene of ``ds`` with LiDAR scans."""
    if map_scene not in ds.scenes:
        raise InputError(f"{ds.url}: no map scene {map_scene!r} (have: {', '.join(ds.scenes) or 'none'})")
    if map_scene == scene_id:
        raise InputError(f"{ds.url}: scene {scene_id!r} cannot be its own map scene")
    if "lidar/points" not in ds.scene(map_scene):
        raise InputError(f"{ds.url}: map scene {map_scene!r} has no lidar/points (a mapping pass needs LiDAR scans)")


def map_target(points: np.ndarray, cfg: SlamConfig) -> VoxelMap:
    """The refinement's point-to-plane map (:class:`VoxelMap`, ``cfg.map_voxel``) of a static point map
    ``points`` (M,3) world frame (normals from open3d, 0.25 m / 30 neighbours)."""
    import open3d as o3d

    pc = _o3d_cloud(points)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.25, max_nn=30))
    vm = VoxelMap(cfg.map_voxel)
    vm.add(np.asarray(pc.points), np.asarray(pc.normals))
    return vm


def guess_poses(scene, scans: Scans) -> tuple[np.ndarray | None, str]:
    """Odometry/TF-based guesses T_world_lidar (S,4,4) at the scan stamps: ingest's TF radar poses
    (``pose/T_world_radar``, source tf) through the extrinsics, else the source recording's TF
    (:func:`recording_tf_poses`); (None, "none") without either."""
    names = set(scene.arrays())
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    if "pose/T_world_radar" in names and T_br is not None and dict(scene["pose/T_world_radar"].attrs).get("source") == "tf":
        P = np.asarray(scene["pose/T_world_radar"][...], np.float64)
        t = np.asarray(scene["time/timestamp_ns"][...], np.int64)
        ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
        if ok.sum() >= 2:
            T_rl = np.linalg.inv(T_br) @ (T_bl if T_bl is not None else np.eye(4))
            return Trajectory(t[ok], P[ok]).interpolate(scans.stamp_ns) @ T_rl, "tf (pose/T_world_radar)"
    for src, poses in (("tf (tf/T_world_lidar)", tf_lidar_poses),
                       ("tf (source recording)", recording_tf_poses)):   # (the recording is read only if needed)
        rt = poses(scene, scans.stamp_ns)
        if rt is not None and rt[1].all():
            return rt[0], src
    return None, "none"


def localise_first(points: np.ndarray, vmap: VoxelMap, guess: np.ndarray, cfg: SlamConfig, max_range: float,
                   distances=(1.0, 0.5, 0.3, 0.1, 0.05)) -> tuple[np.ndarray, float, float]:
    """Scan-to-map ICP of one scan (sensor frame, (N,3)) from ``guess`` (4,4) with wide-to-fine
    correspondence distances (``distances`` m; the guess may be off by the odometry's drift and the
    two recordings' world frames); returns (T_world_lidar, fitness, inlier RMSE m)."""
    p = np.asarray(points, np.float64)
    r2 = np.einsum("ij,ij->i", p, p)
    p = p[(r2 >= cfg.min_range ** 2) & (r2 <= max_range ** 2)]
    src = p[first_per_voxel(p, cfg.source_voxel)]
    tgt = _TargetCache(max_range + 1.5).cloud(vmap, guess[:3, 3])
    return icp(src, tgt, guess, replace_cfg(cfg, icp_iterations=30), distances)


def replace_cfg(cfg: SlamConfig, **kw) -> SlamConfig:
    from dataclasses import replace

    return replace(cfg, **kw)


def localise_scene(dataset_url, scene_id: str | None, map_scene: str, *, config: SlamConfig = SlamConfig(),
                   mesh_config=None, quiet: bool = False, write: bool = True, tum=None, ply=None,
                   force: bool = False) -> SlamResult:
    """Localisation mode of ``holodata slam`` (``--map-scene``): the map first, then the data.

    1. ``map_scene`` (a mapping pass of the same corner, no person: its own LiDAR-only scene) gets
       the ordinary :func:`slam_scene` (poses, ``mesh/*``, ``map/points``; resumed when done; seeded
       by its odometry/TF, ``seed_poses="tf"``, where it has them) and the
       scene attribute ``role: "mapping"`` (``mapping_for``: the scenes localised against it), which
       excludes it from train/test splits and raytrace-gt.
    2. The scene's scans are localised against that map (its ``map/points`` as a fixed point-to-plane
       target, never grown): the first scan by ICP from the odometry/TF-based guess
       (:func:`guess_poses`; else the map scene's anchor) with wide-to-fine distances
       (:func:`localise_first`), every later one by :func:`refine` from the previous pose moved by the
       guesses' relative motion (kiss-icp's without TF), at-rest scans held as in slam.
    3. The scene gets ``pose/T_world_lidar``, ``pose/T_world_radar``, the map's ``mesh/*`` and
       ``map/points`` (copied, source "slam"), all in the map scene's world frame, and the attribute
       ``slam`` with ``mode: "localisation"``, ``map_scene``, the map's anchor and the localisation's
       health (fitness per scan, the first scan's correction from its guess).
    Raises InputError for an unknown map scene or one without LiDAR, DatasetError when the first scan
    does not localise (fitness below ``config.min_fitness``)."""
    from ...dataset import open_dataset
    from ...parallel import release_free_memory
    from ..mesh import MeshConfig

    t_all = time.perf_counter()
    mesh_config = mesh_config or MeshConfig()
    ds = open_dataset(dataset_url)
    if scene_id is None:
        others = [s for s in ds.scenes if s != map_scene]
        if len(others) != 1:
            raise InputError(f"{dataset_url}: {len(others)} scenes besides the map scene; give --scene")
        scene_id = others[0]
    if scene_id not in ds.scenes:
        raise InputError(f"{dataset_url}: no scene {scene_id!r} (have: {', '.join(ds.scenes) or 'none'})")
    check_map_scene(ds, scene_id, map_scene)
    timings: dict = {}
    t0 = time.perf_counter()
    # (seeded by its odometry/TF where it has them: a mapping pass is often throttled to a few scans a second)
    mres = slam_scene(dataset_url, map_scene, config=replace_cfg(config, seed_poses="tf"), mesh_config=mesh_config,
                      quiet=quiet, write=write, force=force)
    timings["map_scene_s"] = time.perf_counter() - t0
    ds = open_dataset(dataset_url)
    mscene, scene = ds.scene(map_scene), ds.scene(scene_id)
    scene.require_complete("slam")
    if write:
        for_ = sorted(set((mscene.attrs.get("mapping_for") or [])) | {scene_id})
        if mscene.attrs.get("role") != MAPPING_ROLE or mscene.attrs.get("mapping_for") != for_:
            w = open_dataset(dataset_url, "r+", created_by="holodata slam")
            w.scene(map_scene).set_attrs({"role": MAPPING_ROLE, "mapping_for": for_})
    if mres.map_points is None or mres.mesh is None:
        raise DatasetError(f"{dataset_url}: map scene {map_scene!r} has no static map (run slam with a mesh)")
    manchor = dict((mscene.attrs.get("slam") or {}).get("anchor") or {})
    fp = _fingerprint(scene, config, mesh_config) + "-map-" + str((mscene.attrs.get("slam") or {}).get("fingerprint"))
    done = scene.attrs.get("slam") or {}
    if (write and not force and done.get("complete") and done.get("fingerprint") == fp
            and "pose/T_world_lidar" in scene and "mesh/faces" in scene and "map/points" in scene):
        res = _stored_result(scene, done)
        if tum is not None:
            write_tum(tum, res.trajectory())
        return res
    release_free_memory()
    imports = _import_in_background(("open3d",))
    t0 = time.perf_counter()
    scans = load_scans(scene, quiet=quiet)
    timings["read_s"] = time.perf_counter() - t0
    imports.join()
    max_range = float(config.max_range or data_max_range(scans))
    t0 = time.perf_counter()
    vmap = map_target(mres.map_points, config)
    timings["map_target_s"] = time.perf_counter() - t0
    guess, guess_src = guess_poses(scene, scans)
    t0 = time.perf_counter()
    if guess is not None:
        g0 = guess[0]
        init = _Fixed(guess, seed=True)
    else:
        g0 = anchor_pose(scene, scans.stamp_ns[:1])[0]
        init = KissStream(scans, config, max_range) if len(scans) > 1 else _Fixed(np.eye(4)[None].repeat(1, 0))
    T0, fit0, rmse0 = localise_first(scans.points[0], vmap, g0, config, max_range)
    if fit0 < config.min_fitness:
        raise DatasetError(f"{dataset_url}: scene {scene_id!r}: its first scan does not localise in map scene "
                           f"{map_scene!r} (fitness {fit0:.2f} < {config.min_fitness} from the {guess_src} guess)")
    D = np.linalg.inv(g0) @ T0
    if len(scans) > 1:
        poses, h = refine(scans, init, config, max_range, quiet=quiet, T0=T0, vmap=vmap, grow_map=False)
    else:
        poses, h = T0[None].copy(), {"fitness": np.array([fit0]), "rmse": np.array([rmse0]), "kiss_fallbacks": 0,
                                     "still_scans": 0, "kiss_scans": 0}
    timings["localise_s"] = time.perf_counter() - t0
    Tl, Tr, finfo = frame_poses(scene, scans, poses)
    fit = np.r_[fit0, h["fitness"][1:]]
    health = {"localisation": {"guess": guess_src, "first_fitness": fit0, "first_rmse_m": rmse0,
                               "first_correction_m": float(np.linalg.norm(D[:3, 3])),
                               "first_correction_deg": float(rotation_angle_deg(D)),
                               "fitness_min": float(fit.min()), "fitness_mean": float(fit.mean()),
                               "rmse_max_m": float(np.max(np.r_[rmse0, h["rmse"][1:]])),
                               "fallbacks": int(h["kiss_fallbacks"]), "still_scans": int(h["still_scans"])}}
    timings = {k: round(v, 3) for k, v in timings.items()}
    anchor = {**manchor, "map_scene": map_scene}
    summary = {"scene": scene_id, "mode": "localisation", "map_scene": map_scene, "scans": len(scans),
               "frames": scene.n_frames, "max_range_m": round(max_range, 3),
               "anchor": {k: v for k, v in anchor.items() if k != "T_world_lidar0"}, "health": health,
               "frames_info": {k: v for k, v in finfo.items() if k != "T_lidar_radar"},
               "mesh": {"from_map_scene": map_scene, "faces": int(len(mres.mesh[1]))}, "timings": timings,
               "fingerprint": fp}
    res = SlamResult(scene_id, scans.stamp_ns.copy(), poses, None, None, Tl, Tr, mres.mesh, summary, mres.map_points)
    if write:
        _write(dataset_url, ds, scene_id, res, replace_cfg(config, mesh=True), mesh_config, anchor, finfo, fp,
               mode={"mode": "localisation", "map_scene": map_scene})
    if tum is not None:
        write_tum(tum, res.trajectory())
    if ply is not None:
        from ...meshio import Mesh, write_ply

        write_ply(ply, Mesh(mres.mesh[0], mres.mesh[1]))
    summary["timings"]["total_s"] = round(time.perf_counter() - t_all, 3)
    return res


def _stored_result(scene, done: dict) -> SlamResult:
    """A finished scene's result read back from the dataset (no recomputation; no kiss-icp poses)."""
    Tl = np.asarray(scene["pose/T_world_lidar"][...], np.float64)
    Tr = np.asarray(scene["pose/T_world_radar"][...], np.float64) if "pose/T_world_radar" in scene else None
    names = set(scene.arrays())
    st = np.asarray(scene["lidar/timestamp_ns"][...] if "lidar/timestamp_ns" in names else scene["time/timestamp_ns"][...],
                    np.int64)
    _, first = np.unique(st, return_index=True)
    first = np.sort(first[st[first] > 0])
    mesh = None
    if "mesh/faces" in names:
        mesh = (np.asarray(scene["mesh/vertices"][...], np.float32), np.asarray(scene["mesh/faces"][...], np.int32))
    summary = dict(done.get("summary") or {})
    summary["skipped"] = "already done with the same inputs and settings (use --force to recompute)"
    points = np.asarray(scene["map/points"][...], np.float64) if "map/points" in names else None
    return SlamResult(scene.id, st[first], Tl[first], None, None, Tl, Tr, mesh, summary, points)


def _write(url, ds, scene_id, res: SlamResult, cfg: SlamConfig, mesh_cfg, anchor, finfo, fp, mode=None) -> None:
    from ...dataset import open_dataset

    meta = ds.meta
    w = open_dataset(url, "r+", created_by="holodata slam", shard_frames=int(meta.get("shard_frames") or 32))
    sc = w.scene(scene_id)
    if (sc.attrs.get("slam") or {}).get("complete"):
        sc.set_attrs({"slam": {**sc.attrs["slam"], "complete": False}})  # a crash below must not look done
    names = set(sc.arrays())
    stale = sorted(n for n in names if n.startswith("gt/"))
    for n in stale:  # ray-traced from the previous mesh/poses: would be silently wrong (raytrace-gt resumes)
        sc.remove(n)
    res.summary["removed_stale"] = stale
    pose_attrs = {"source": "slam", "world_frame": anchor.get("world_frame"), "anchor": anchor.get("kind"),
                  "method": "kiss-icp 1.3 + open3d scan-to-map point-to-plane ICP" if cfg.refine else "kiss-icp 1.3"}
    if (mode or {}).get("map_scene"):
        pose_attrs["method"] = f"open3d scan-to-map point-to-plane ICP against map scene {mode['map_scene']!r}"
        pose_attrs["map_scene"] = mode["map_scene"]
    arrays = [("pose/T_world_lidar", res.T_world_lidar, {"time": "lidar/timestamp_ns (time/timestamp_ns when 0)"})]
    if res.T_world_radar is not None:
        arrays.append(("pose/T_world_radar", res.T_world_radar, {"time": "time/timestamp_ns",
                                                                 "T_lidar_radar": finfo.get("T_lidar_radar")}))
    for name, P, extra in arrays:
        if name in names:
            sc.remove(name)
        a = sc.frame_array(name, per_frame_shape=(4, 4), dtype="float64", dims=["frame", "row", "col"], units="m",
                           fill_value=float("nan"), attrs={**pose_attrs, **extra})
        for k in range(a.n_shards):
            a.write_shard(k, P[a.frames(k)])
    if res.mesh is not None:
        if "mesh/face_class" in names:
            sc.remove("mesh/face_class")
        write_static_map(sc, res.mesh[0], res.mesh[1], res.map_points, "slam")
    sc.set_attrs({"slam": {"complete": True, "fingerprint": fp, "config": cfg.to_attrs(),
                           "mesh_config": mesh_cfg.to_attrs() if cfg.mesh else None,
                           "anchor": anchor, "summary": json_safe(res.summary), **(mode or {})}})


def write_static_map(sc, vertices: np.ndarray, faces: np.ndarray, points: np.ndarray | None, source: str) -> None:
    """Write a :class:`StaticMap`'s ``mesh/vertices``, ``mesh/faces`` and (when given) ``map/points``
    (M,3) float32 into the scene writer ``sc``, each with the ``source`` of the poses they were built
    from: ``holodata register`` uses them only while that matches ``pose/T_world_lidar``'s."""
    sc.write_array("mesh/vertices", np.asarray(vertices, np.float32), dims=["vertex", "xyz"], units="m",
                   attrs={"source": source, "frame": "world"})
    sc.write_array("mesh/faces", np.asarray(faces, np.int32), dims=["face", "corner"], units="1",
                   attrs={"source": source})
    if points is not None:
        sc.write_array("map/points", np.asarray(points, np.float32), dims=["point", "xyz"], units="m",
                       attrs={"source": source, "frame": "world",
                              "what": "static LiDAR returns averaged per mesh voxel (the mesh's input)"})
    elif "map/points" in sc.arrays():
        sc.remove("map/points")


def json_safe(obj):
    import json

    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def slam_dataset(dataset_url, scene_ids=None, single_exports: bool = False, map_scene: str | None = None,
                 **kwargs) -> list[SlamResult]:
    """:func:`slam_scene` for each of ``scene_ids`` (default: every scene with lidar/points).
    ``single_exports``: ``tum``/``ply`` exports are allowed only when one scene is processed.
    ``map_scene``: localise each scene against that mapping pass (:func:`localise_scene`; needs
    ``scene_ids``); without it a scene localised against a mapping pass before is localised against
    that one again (its ``slam.map_scene``)."""
    from ...dataset import open_dataset

    ds = open_dataset(dataset_url)
    if map_scene is not None:
        if not scene_ids:
            raise InputError(f"{dataset_url}: a map scene needs the scenes to localise (give --scene)")
        for sid in scene_ids:
            if sid not in ds.scenes:
                raise InputError(f"{dataset_url}: no scene {sid!r} (have: {', '.join(ds.scenes) or 'none'})")
            check_map_scene(ds, sid, map_scene)
        if single_exports and len(scene_ids) > 1 and (kwargs.get("tum") or kwargs.get("ply")):
            raise InputError(f"{dataset_url}: {len(scene_ids)} scenes; --ply/--tum need one (give --scene)")
        return [localise_scene(dataset_url, sid, map_scene, **kwargs) for sid in scene_ids]
    if scene_ids:
        for sid in scene_ids:
            if sid not in ds.scenes:
                raise InputError(f"{dataset_url}: no scene {sid!r} (have: {', '.join(ds.scenes) or 'none'})")
        ids = list(scene_ids)
    else:
        ids = [s for s in ds.scenes if "lidar/points" in ds.scene(s)]
    if not ids:
        raise InputError(f"{dataset_url}: no scene has lidar/points (nothing for slam)")
    if single_exports and len(ids) > 1 and (kwargs.get("tum") or kwargs.get("ply")):
        raise InputError(f"{dataset_url}: {len(ids)} scenes; --ply/--tum need one (give --scene)")
    # a scene localised against a mapping pass before stays localised against it
    prev = {sid: (ds.scene(sid).attrs.get("slam") or {}).get("map_scene") for sid in ids}
    return [slam_scene(dataset_url, sid, map_scene=prev[sid] if prev[sid] in ds.scenes else None, **kwargs)
            for sid in ids]


__all__ = ["SlamConfig", "SlamResult", "StaticMap", "write_static_map", "Scans", "load_scans", "kiss_odometry", "refine",
           "global_refine",
           "static_mesh", "slam_scene", "slam_dataset", "deskew", "twist", "anchor_pose", "tf_lidar_poses", "frame_poses",
           "localise_scene", "check_map_scene", "recording_tf_poses", "guess_poses", "MAPPING_ROLE", "stream_scans",
           "data_max_range", "mesh_scan_subset"]
