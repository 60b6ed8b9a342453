"""SLAM proper on one scene (steps 1-5 of :mod:`holodata.mapping.slam`): the scans read beside the
odometry and refinement (:func:`_scans_and_poses`, :func:`_odometry`), the per-frame poses, the
static mesh, the writes and the optional exports (:func:`run_slam`, which
:func:`~holodata.mapping.slam.entry.slam_scene` runs on a scene without a map scene, and the
localisation mode on its map scene)."""
from __future__ import annotations

import time

import numpy as np

from ...dataset.layout import MAP_POINTS, MESH_FACES, POSE_T_WORLD_LIDAR
from ...errors import InputError
from ...trajectory import Trajectory, write_tum
from .config import Scans, SlamConfig, SlamOutputs, SlamResult
from .odometry import KissStream, _Fixed, kiss_odometry
from .refine import RefineOptions, global_refine, refine
from .scans import _import_in_background, _StreamBroken, data_max_range, load_scans, stream_scans
from .store import SlamRecord, _fingerprint, _stored_result, _write
from .world import anchor_pose, frame_poses, guess_poses, level_tf_poses, static_mesh, tf_agreement


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
        poses, h1 = refine(scans, ks, config, max_range, quiet=quiet,
                           options=RefineOptions(T0=T0, ready=ready, vertical=vertical))
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


def run_slam(dataset_url, scene_id: str | None = None, *, config: SlamConfig = SlamConfig(), mesh_config=None,
             quiet: bool = False, outputs: SlamOutputs = SlamOutputs()) -> SlamResult:
    """:func:`~holodata.mapping.slam.entry.slam_scene` without a map scene: SLAM proper on one scene of
    the dataset at ``dataset_url`` (``scene_id`` None: its only scene), its arguments and result. The
    localisation mode runs it on the map scene first (:func:`~.localise.localise_scene`)."""
    from ...dataset import open_dataset
    from ...parallel import release_free_memory
    from ..mesh import MeshConfig

    t_all = time.perf_counter()
    release_free_memory()      # (slam forks the mesh's background model)
    mesh_config = mesh_config or MeshConfig()
    ds = open_dataset(dataset_url)
    scene = ds.scene(_only_scene(ds, dataset_url, scene_id))
    scene.require_complete("slam")
    fp = _fingerprint(scene, config, mesh_config if config.mesh else None)
    done = scene.attrs.get("slam") or {}
    if (outputs.write and not outputs.force and done.get("complete") and done.get("fingerprint") == fp
            and POSE_T_WORLD_LIDAR in scene and (not config.mesh or (MESH_FACES in scene and MAP_POINTS in scene))):
        return _export(_stored_result(scene, done), outputs.tum, outputs.ply)
    timings: dict = {}
    health: dict = {}
    scans, (max_range, T0, anchor, poses, K, kref, background) = _scans_and_poses(scene, config, health, timings, quiet)
    Tl, Tr, finfo = frame_poses(scene, scans, poses)
    mesh = map_points = minfo = None
    if config.mesh:
        t0 = time.perf_counter()
        sm = static_mesh(scans, poses, config, max_range, mesh_config, background, quiet=quiet)
        timings["mesh_s"] = time.perf_counter() - t0
        mesh, map_points, minfo = (sm.vertices, sm.faces), sm.points, sm.info
    timings = {k: round(v, 3) for k, v in timings.items()}
    summary = {"scene": scene.id, "scans": len(scans), "frames": scene.n_frames, "max_range_m": round(max_range, 3),
               "anchor": {k: v for k, v in anchor.items() if k != "T_world_lidar0"}, "health": health,
               "frames_info": {k: v for k, v in finfo.items() if k != "T_lidar_radar"}, "mesh": minfo,
               "timings": timings, "fingerprint": fp}
    agree = tf_agreement(scene, scans.stamp_ns, poses)
    if agree is not None:
        summary["tf_agreement"] = agree
    res = SlamResult(scene.id, scans.stamp_ns.copy(), poses, K, kref, Tl, Tr, mesh, summary, map_points)
    if outputs.write:
        _write(dataset_url, ds, res, SlamRecord(config, mesh_config, anchor, fp, finfo))
    _export(res, outputs.tum, outputs.ply)
    summary["timings"]["total_s"] = round(time.perf_counter() - t_all, 3)
    return res


def _only_scene(ds, url, scene_id: str | None) -> str:
    """``scene_id``, or the dataset's only scene when None (InputError when it has several or none)."""
    if scene_id is None:
        if len(ds.scenes) != 1:
            raise InputError(f"{url}: {len(ds.scenes)} scenes ({', '.join(ds.scenes) or 'none'}); give --scene")
        scene_id = ds.scenes[0]
    return scene_id


def _scans_and_poses(scene, config: SlamConfig, health: dict, timings: dict, quiet: bool):
    """The scene's scans and their poses (:func:`_odometry`'s tuple): with the refinement the scans are
    read while it works on the first ones (the reading thread's zarr decoding and open3d's ICP leave the
    GIL free for the other); a stream that breaks (:class:`_StreamBroken`) is read again whole."""
    t0 = time.perf_counter()
    imports = _import_in_background(("kiss_icp.kiss_icp", "open3d"))
    streamed = stream_scans(scene) if config.refine else None
    if streamed is None:
        scans, feed = load_scans(scene, quiet=quiet), None
        timings["read_s"] = time.perf_counter() - t0
    else:
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
    return scans, odo


def _export(res: SlamResult, tum, ply) -> SlamResult:
    """Write the optional exports of ``res``: its LiDAR trajectory as TUM (``tum``) and its mesh as PLY
    (``ply``, when it has one); returns ``res``. Each replaces only a file holodata wrote
    (:func:`holodata.ownership.write_file`)."""
    from ...ownership import write_file

    if tum is not None:
        write_file(tum, "holodata slam --tum", lambda p: write_tum(p, res.trajectory()))
    if ply is not None and res.mesh is not None:
        from ...meshio import Mesh, write_ply

        write_file(ply, "holodata slam --ply", lambda p: write_ply(p, Mesh(res.mesh[0], res.mesh[1])))
    return res
