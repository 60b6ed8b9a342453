"""The pipeline of ``holodata register`` (:func:`register_scene`; the package docstring says what
each step does): the LiDAR half beside the camera half, the extrinsic, the human points and
surfaces, the writes; a camera that cannot be registered (:func:`unregistered`); the fingerprint
that skips a scene registered before (:func:`register_fingerprint`, :func:`stored_report`) and the
report (:func:`register_report`)."""
from __future__ import annotations

import time

import numpy as np

from ...dataset.layout import (CALIB_T_WORLD_CAMERA, CAMERA_POINTS_WORLD, CAMERA_TIMESTAMP_NS, HUMAN_FACES,
                               HUMAN_POINTS, HUMAN_VERTICES, MAP_POINTS, MESH_FACES, MESH_VERTICES,
                               POSE_T_WORLD_LIDAR, TIME_TIMESTAMP_NS)
from ...errors import InputError
from ...parallel import cpus, fork_call, release_free_memory
from .camera import _camera_points_through, CameraFrames, noise_coefficient
from .config import RegisterConfig, Registration, RegistrationError
from .extrinsic import register_extrinsic
from .lidar_side import lidar_half
from .scene_inputs import _parse_init, only_camera_scene, scene_mesh, slam_anchor
from .steps import (all_surfaces, body_columns_of, clear_outputs, frame_cuts, human_candidates, human_shift,
                    initial_guess, pick_track, registration_failure, static_camera, track_smoothing, write_outputs)


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


REGISTER_OUTPUTS = (CALIB_T_WORLD_CAMERA, HUMAN_VERTICES, HUMAN_FACES, HUMAN_POINTS)
# scene attribute of a camera that could not be registered: register's report, ``registered`` False
# (the scene finished without a person, :func:`unregistered`); cleared by a registration that passes
REGISTER_FAILED = "register_failed"
# Switches deleted (off by default, never used) after datasets were registered with them:
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
