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
   else its TF radar poses ``pose/T_world_radar`` with ``source: tf`` through the extrinsics, or the
   source recording's TF), the first scan TF covers is anchored at its TF pose, so the map lives in
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
:mod:`.store` (the writes and a finished scene read back); this module holds the entry points
(:func:`slam_scene`, :func:`slam_dataset`) and slam's steps.

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

import time
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...trajectory import Trajectory, write_tum
from .config import Scans, SlamConfig, SlamResult
from .scans import _import_in_background, _StreamBroken, data_max_range, load_scans, stream_scans
from .odometry import KissStream, _Fixed, deskew, kiss_odometry, twist
from .refine import global_refine, mesh_scan_subset, refine
from .store import _fingerprint, _stored_result, _write, write_static_map
from .localise import MAPPING_ROLE, check_map_scene, localise_scene
from .world import (StaticMap, anchor_pose, frame_poses, guess_poses, level_tf_poses, recording_tf_poses, static_mesh,
                    tf_agreement, tf_lidar_poses)
from ...dataset.layout import LIDAR_POINTS, MAP_POINTS, MESH_FACES, POSE_T_WORLD_LIDAR


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
    from ...parallel import release_free_memory
    from ..mesh import MeshConfig

    if map_scene is not None:
        return localise_scene(dataset_url, scene_id, map_scene, config=config, mesh_config=mesh_config, quiet=quiet,
                              write=write, tum=tum, ply=ply, force=force)
    t_all = time.perf_counter()
    release_free_memory()      # (slam forks the mesh's background model)
    mesh_config = mesh_config or MeshConfig()
    ds = open_dataset(dataset_url)
    scene = ds.scene(_only_scene(ds, dataset_url, scene_id))
    scene.require_complete("slam")
    fp = _fingerprint(scene, config, mesh_config if config.mesh else None)
    done = scene.attrs.get("slam") or {}
    if (write and not force and done.get("complete") and done.get("fingerprint") == fp
            and POSE_T_WORLD_LIDAR in scene and (not config.mesh or (MESH_FACES in scene and MAP_POINTS in scene))):
        return _export(_stored_result(scene, done), tum, ply)
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
    if write:
        _write(dataset_url, ds, scene.id, res, config, mesh_config, anchor, finfo, fp)
    _export(res, tum, ply)
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
        ids = [s for s in ds.scenes if LIDAR_POINTS in ds.scene(s)]
    if not ids:
        raise InputError(f"{dataset_url}: no scene has lidar/points (nothing for slam)")
    if single_exports and len(ids) > 1 and (kwargs.get("tum") or kwargs.get("ply")):
        raise InputError(f"{dataset_url}: {len(ids)} scenes; --ply/--tum need one (give --scene)")
    # a scene localised against a mapping pass before stays localised against it; a data pass whose own
    # mapping pass is in the dataset (<id>_map, role mapping: ingest of a synth folder) is localised in it
    cfg = kwargs.get("config") or SlamConfig()
    prev = {sid: (ds.scene(sid).attrs.get("slam") or {}).get("map_scene")
            or (own_mapping_pass(ds, sid) if cfg.refine and cfg.mesh else None) for sid in ids}
    prev = {sid: m if m in ds.scenes else None for sid, m in prev.items()}
    if not scene_ids:   # a mapping pass is slammed as the map of the scenes localised in it, not on its own
        ids = [s for s in ids if s not in set(prev.values())]
    return [slam_scene(dataset_url, sid, map_scene=prev[sid], **kwargs) for sid in ids]


def own_mapping_pass(ds, scene_id: str) -> str | None:
    """``<scene_id>_map`` when reader dataset ``ds`` holds it as a mapping pass (scene role, see
    :mod:`holodata.dataset.splits`) and ``scene_id`` is a data pass; else None."""
    from ...dataset.splits import DATA, MAPPING, scene_role

    m = f"{scene_id}_map"
    if m in ds.scenes and scene_role(ds.scene(m).attrs) == MAPPING and scene_role(ds.scene(scene_id).attrs) == DATA:
        return m
    return None


__all__ = ["SlamConfig", "SlamResult", "StaticMap", "write_static_map", "Scans", "load_scans", "kiss_odometry", "refine",
           "global_refine",
           "static_mesh", "slam_scene", "slam_dataset", "deskew", "twist", "anchor_pose", "tf_lidar_poses", "frame_poses",
           "localise_scene", "check_map_scene", "recording_tf_poses", "guess_poses", "MAPPING_ROLE", "stream_scans",
           "data_max_range", "mesh_scan_subset"]
