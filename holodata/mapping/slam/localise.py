"""Localisation mode of ``holodata slam`` (``--map-scene``): a scene's scans localised against the
static map slam builds from a mapping pass of the same corner (:func:`localise_scene`)."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ...conventions import rotation_angle_deg
from ...dataset.layout import LIDAR_POINTS, MAP_POINTS, MESH_FACES, POSE_T_WORLD_LIDAR
from ...errors import DatasetError, InputError
from ...geometry.voxels import first_per_voxel
from .config import SlamConfig, SlamOutputs, SlamResult
from .odometry import KissStream, _Fixed
from .pipeline import _export, run_slam
from .points import _o3d_cloud
from .refine import RefineOptions, VoxelMap, _TargetCache, icp, refine
from .scans import _import_in_background, data_max_range, load_scans
from .store import SlamRecord, _fingerprint, _stored_result, _write
from .world import anchor_pose, frame_poses, guess_poses

MAPPING_ROLE = "mapping"   # scene attribute ``role`` of a mapping-pass scene (no train/test split, no raytrace-gt)
# the first scan's map crop reaches this far beyond the LiDAR's range from the guess: the guess may
# be off by the odometry's drift (wider than refine's TARGET_MARGIN_M)
FIRST_TARGET_MARGIN_M = 1.5


def check_map_scene(ds, scene_id: str, map_scene: str) -> None:
    """InputError (one line) unless ``map_scene`` is another scene of ``ds`` with LiDAR scans."""
    if map_scene not in ds.scenes:
        raise InputError(f"{ds.url}: no map scene {map_scene!r} (have: {', '.join(ds.scenes) or 'none'})")
    if map_scene == scene_id:
        raise InputError(f"{ds.url}: scene {scene_id!r} cannot be its own map scene")
    if LIDAR_POINTS not in ds.scene(map_scene):
        raise InputError(f"{ds.url}: map scene {map_scene!r} has no lidar/points (a mapping pass needs LiDAR scans)")


def map_target(points: np.ndarray, cfg: SlamConfig) -> VoxelMap:
    """The refinement's point-to-plane map (:class:`VoxelMap`, ``cfg.map_voxel``) of a static point map
    ``points`` (M,3) world frame (normals from open3d, ``cfg.map_normal_radius`` / ``map_normal_nn``)."""
    import open3d as o3d

    pc = _o3d_cloud(points)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.map_normal_radius, max_nn=cfg.map_normal_nn))
    vm = VoxelMap(cfg.map_voxel)
    vm.add(np.asarray(pc.points), np.asarray(pc.normals))
    return vm


def localise_first(points: np.ndarray, vmap: VoxelMap, guess: np.ndarray, cfg: SlamConfig, max_range: float,
                   distances=(1.0, 0.5, 0.3, 0.1, 0.05)) -> tuple[np.ndarray, float, float]:
    """Scan-to-map ICP of one scan (sensor frame, (N,3)) from ``guess`` (4,4) with wide-to-fine
    correspondence distances (``distances`` m; the guess may be off by the odometry's drift and the
    two recordings' world frames); returns (T_world_lidar, fitness, inlier RMSE m)."""
    p = np.asarray(points, np.float64)
    r2 = np.einsum("ij,ij->i", p, p)
    p = p[(r2 >= cfg.min_range ** 2) & (r2 <= max_range ** 2)]
    src = p[first_per_voxel(p, cfg.source_voxel)]
    tgt = _TargetCache(max_range + FIRST_TARGET_MARGIN_M).cloud(vmap, guess[:3, 3])
    return icp(src, tgt, guess, replace(cfg, icp_iterations=30), distances)


def localise_scene(dataset_url, scene_id: str | None, map_scene: str, *, config: SlamConfig = SlamConfig(),
                   mesh_config=None, quiet: bool = False, outputs: SlamOutputs = SlamOutputs()) -> SlamResult:
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
    scene_id = _scene_beside(open_dataset(dataset_url), dataset_url, scene_id, map_scene)
    timings: dict = {}
    t0 = time.perf_counter()
    # (seeded by its odometry/TF where it has them: a mapping pass is often throttled to a few scans a second)
    mres = run_slam(dataset_url, map_scene, config=replace(config, seed_poses="tf"), mesh_config=mesh_config,
                    quiet=quiet, outputs=replace(outputs, tum=None, ply=None))
    timings["map_scene_s"] = time.perf_counter() - t0
    ds = open_dataset(dataset_url)
    mscene, scene = ds.scene(map_scene), ds.scene(scene_id)
    scene.require_complete("slam")
    if outputs.write:
        _mark_mapping_scene(dataset_url, mscene, scene_id)
    if mres.map_points is None or mres.mesh is None:
        raise DatasetError(f"{dataset_url}: map scene {map_scene!r} has no static map (run slam with a mesh)")
    manchor = dict((mscene.attrs.get("slam") or {}).get("anchor") or {})
    fp = _fingerprint(scene, config, mesh_config) + "-map-" + str((mscene.attrs.get("slam") or {}).get("fingerprint"))
    done = scene.attrs.get("slam") or {}
    if (outputs.write and not outputs.force and done.get("complete") and done.get("fingerprint") == fp
            and POSE_T_WORLD_LIDAR in scene and MESH_FACES in scene and MAP_POINTS in scene):
        return _export(_stored_result(scene, done), outputs.tum, outputs.ply)   # done before: the exports still asked for
    release_free_memory()
    imports = _import_in_background(("open3d",))
    t0 = time.perf_counter()
    scans = load_scans(scene, quiet=quiet)
    timings["read_s"] = time.perf_counter() - t0
    imports.join()
    max_range = float(config.max_range or data_max_range(scans))
    poses, health = _localise(scene, scans, mres, config, max_range, quiet, timings, f"{dataset_url}: scene {scene_id!r}")
    Tl, Tr, finfo = frame_poses(scene, scans, poses)
    timings = {k: round(v, 3) for k, v in timings.items()}
    anchor = {**manchor, "map_scene": map_scene}
    summary = {"scene": scene_id, "mode": "localisation", "map_scene": map_scene, "scans": len(scans),
               "frames": scene.n_frames, "max_range_m": round(max_range, 3),
               "anchor": {k: v for k, v in anchor.items() if k != "T_world_lidar0"}, "health": health,
               "frames_info": {k: v for k, v in finfo.items() if k != "T_lidar_radar"},
               "mesh": {"from_map_scene": map_scene, "faces": int(len(mres.mesh[1]))}, "timings": timings,
               "fingerprint": fp}
    res = SlamResult(scene_id, scans.stamp_ns.copy(), poses, None, None, Tl, Tr, mres.mesh, summary, mres.map_points)
    if outputs.write:
        _write(dataset_url, ds, res, SlamRecord(replace(config, mesh=True), mesh_config, anchor, fp, finfo,
                                                mode={"mode": "localisation", "map_scene": map_scene}))
    _export(res, outputs.tum, outputs.ply)
    summary["timings"]["total_s"] = round(time.perf_counter() - t_all, 3)
    return res


def _scene_beside(ds, url, scene_id: str | None, map_scene: str) -> str:
    """The scene to localise: ``scene_id``, or the one scene besides ``map_scene`` when None; checked
    (:func:`check_map_scene`)."""
    if scene_id is None:
        others = [s for s in ds.scenes if s != map_scene]
        if len(others) != 1:
            raise InputError(f"{url}: {len(others)} scenes besides the map scene; give --scene")
        scene_id = others[0]
    if scene_id not in ds.scenes:
        raise InputError(f"{url}: no scene {scene_id!r} (have: {', '.join(ds.scenes) or 'none'})")
    check_map_scene(ds, scene_id, map_scene)
    return scene_id


def _mark_mapping_scene(url, mscene, scene_id: str) -> None:
    """Give the map scene ``mscene`` the attributes ``role: "mapping"`` and ``mapping_for`` (with
    ``scene_id``) unless it has them."""
    from ...dataset import open_dataset

    for_ = sorted(set(mscene.attrs.get("mapping_for") or []) | {scene_id})
    if mscene.attrs.get("role") != MAPPING_ROLE or mscene.attrs.get("mapping_for") != for_:
        w = open_dataset(url, "r+", created_by="holodata slam")
        w.scene(mscene.id).set_attrs({"role": MAPPING_ROLE, "mapping_for": for_})


def _localise(scene, scans, mres: SlamResult, config: SlamConfig, max_range: float, quiet: bool, timings: dict,
              where: str) -> tuple[np.ndarray, dict]:
    """Step 2 of :func:`localise_scene`: the scans' poses (S,4,4) against the fixed map of the map
    scene's result ``mres`` (its ``map_points``) and the localisation's health figures. DatasetError
    when the first scan does not localise (``where``: the dataset and scene)."""
    map_scene = mres.scene
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
        raise DatasetError(f"{where}: its first scan does not localise in map scene "
                           f"{map_scene!r} (fitness {fit0:.2f} < {config.min_fitness} from the {guess_src} guess)")
    D = np.linalg.inv(g0) @ T0
    if len(scans) > 1:
        poses, h = refine(scans, init, config, max_range, quiet=quiet,
                          options=RefineOptions(T0=T0, vmap=vmap, grow_map=False))
    else:
        poses, h = T0[None].copy(), {"fitness": np.array([fit0]), "rmse": np.array([rmse0]), "kiss_fallbacks": 0,
                                     "still_scans": 0, "kiss_scans": 0}
    timings["localise_s"] = time.perf_counter() - t0
    fit = np.r_[fit0, h["fitness"][1:]]
    health = {"localisation": {"guess": guess_src, "first_fitness": fit0, "first_rmse_m": rmse0,
                               "first_correction_m": float(np.linalg.norm(D[:3, 3])),
                               "first_correction_deg": float(rotation_angle_deg(D)),
                               "fitness_min": float(fit.min()), "fitness_mean": float(fit.mean()),
                               "rmse_max_m": float(np.max(np.r_[rmse0, h["rmse"][1:]])),
                               "fallbacks": int(h["kiss_fallbacks"]), "still_scans": int(h["still_scans"])}}
    return poses, health
