"""The pipeline of ``holodata register`` (:func:`register_scene`; the package docstring says what
each step does): the LiDAR half beside the camera half, the extrinsic, the human points and
surfaces, the writes; a camera that cannot be registered (:func:`unregistered`); the fingerprint
that skips a scene registered before (:func:`register_fingerprint`, :func:`stored_report`) and the
report (:func:`register_report`)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...dataset.layout import (
    CALIB_T_WORLD_CAMERA,
    CAMERA_POINTS_WORLD,
    CAMERA_TIMESTAMP_NS,
    HUMAN_FACES,
    HUMAN_POINTS,
    HUMAN_VERTICES,
    MAP_POINTS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_LIDAR,
    TIME_TIMESTAMP_NS,
)
from ...errors import InputError
from ...parallel import cpus, fork_call, release_free_memory
from .camera import CameraFrames, _camera_points_through, noise_coefficient
from .config import RegisterConfig, Registration, RegistrationError
from .extrinsic import register_extrinsic
from .lidar_side import lidar_half
from .scene_inputs import _parse_init, only_camera_scene, scene_mesh, slam_anchor
from .steps import (
    all_surfaces,
    body_columns_of,
    clear_outputs,
    frame_cuts,
    human_candidates,
    human_shift,
    initial_guess,
    pick_track,
    registration_failure,
    static_camera,
    track_smoothing,
    write_outputs,
)


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
    ``skipped`` set, as slam does. The steps are :class:`_Registering`'s, theirs :mod:`.steps`'."""
    run = _Registering.open(url, scene_id, init, cfg or RegisterConfig(), segment_cfg, quiet)
    skipped = None if force or run.resuming else stored_report(run.scene, run.cfg, run.fingerprint)
    if skipped is not None:
        return skipped
    return run.run()


@dataclass
class RegisterFacts:
    """What register's reports (:func:`register_report`, :func:`unregistered`) say of a run besides the
    person: the extrinsic's result ``reg``, where the guess came from (``init_source``: "tf" |
    "--init") and the guess ``T_init`` (4,4), whether the map is slam's stored one (``slam_map``; else
    built from the LiDAR scans), the settings ``cfg``, the run's ``seconds`` so far, its ``timings``
    (s, by step) and its ``fingerprint`` (:func:`register_fingerprint`)."""

    reg: Registration
    init_source: str
    T_init: np.ndarray
    slam_map: bool
    cfg: RegisterConfig
    seconds: float
    timings: dict
    fingerprint: str

    @property
    def map_source(self) -> str:
        return "slam (map/points)" if self.slam_map else "built from the LiDAR scans"


def _summary(scene_id: str, report: dict, seg_summary: dict | None) -> dict:
    """What :func:`register_scene` returns: the scene's ``report`` less its settings and guess, with the
    segmentation's summary when there is one."""
    out = {"scene": scene_id, **{k: v for k, v in report.items() if k not in ("params", "T_init")}}
    if seg_summary:
        out["segment"] = seg_summary
    return out


class _Registering:
    """:func:`register_scene` of one scene as named steps sharing their state: the inputs checked and
    the scene marked unfinished (:meth:`prepare`), the LiDAR half forked beside the camera half
    (:func:`lidar_half`), 1.-2. the static camera and the map (:meth:`camera_and_map`), 3. the
    extrinsic (:meth:`extrinsic`; a camera that cannot be registered: :meth:`refuse`), 4. the
    person's track (:meth:`humans`, :meth:`track`), 5. the surfaces and writes, the segmentation
    waited for (:meth:`segmentation`). ``timings`` collects each step's seconds."""

    def __init__(self, url: str, scene, init, cfg: RegisterConfig, segment_cfg, quiet: bool, t0: float):
        self.url, self.scene, self.init, self.cfg, self.segment_cfg, self.quiet, self.t0 = \
            url, scene, init, cfg, segment_cfg, quiet, t0
        self.where = f"{url}: scene {scene.id!r}"
        self.fingerprint = register_fingerprint(scene, cfg, init, segment_cfg)
        self.resuming = "register" in scene.unfinished    # an interrupted run: its outputs are not to be trusted
        self.timings: dict = {}
        self.outputs_touched = False

    @classmethod
    def open(cls, url: str, scene_id: str | None, init, cfg: RegisterConfig, segment_cfg, quiet: bool) -> _Registering:
        """The run on scene ``scene_id`` (None: the one scene with a camera) of the dataset at ``url``."""
        from ...dataset import open_dataset
        from ..segment import _scene_id

        t0 = time.perf_counter()
        ds = open_dataset(url)
        scene = ds.scene(_scene_id(ds, url, scene_id) if scene_id is not None else only_camera_scene(ds, url))
        scene.require_complete("register")
        return cls(url, scene, init, cfg, segment_cfg, quiet, t0)

    def run(self) -> dict:
        self.prepare()
        # 1.-2. the LiDAR half (segmentation, map) and the camera half (depth images, static depth) are
        # independent until the extrinsic: side by side in two processes (the LiDAR one quiet)
        self.stored_map, self.lidar = lidar_half(self.scene, self.cfg, self.segment_cfg, self.processes, self.quiet,
                                                 self.where)
        try:
            static, M = self.camera_and_map()
            reg = self.extrinsic(static, M)
            if not reg.accepted:
                self.refuse(reg)
            report, seg_summary = self.humans(reg, static, M)
        except BaseException as err:
            self.abandon(err)
            raise
        return _summary(self.scene.id, report, seg_summary)

    def prepare(self) -> None:
        """The camera and LiDAR arrays and poses checked before any work starts, the initial guess, and
        the scene marked unfinished before the first write (lidar/instance, by the LiDAR half), finished
        with the ``register`` report after the last."""
        from ...dataset import open_dataset
        from ..segment import LidarScans

        scene, url = self.scene, self.url
        release_free_memory()      # (before the forks below)
        self.cam = CameraFrames.open(scene, url)
        LidarScans.open(scene, url)
        self.T_init, self.init_source = initial_guess(scene, url, _parse_init(self.init))
        self.processes = register_processes(self.cfg)
        self.sw = open_dataset(url, "r+").scene(scene.id)
        self.sw.begin("register", rerun=f"rerun holodata register DATASET --scene {scene.id} to finish it")

    def camera_and_map(self):
        """1.-2.: (the static camera, :class:`~.steps.StaticCamera`; the LiDAR map (M,3) world). InputError
        when the camera has no point or the map too few."""
        t1 = time.perf_counter()
        static = static_camera(self.cam, self.cfg, self.quiet)
        if static is None:
            if self.stored_map is None:
                self.lidar.early()
            raise InputError(f"{self.where}: camera/points is empty in every frame")
        self.timings["camera_s"], t1 = time.perf_counter() - t1, time.perf_counter()
        M = self.stored_map if self.stored_map is not None else self.lidar.early()   # (the LiDAR process goes on segmenting)
        self.timings["map_wait_s"] = time.perf_counter() - t1
        if len(M) < 100:
            raise InputError(f"{self.where}: the LiDAR map is empty (no usable scans/poses)")
        return static, M

    def extrinsic(self, static, M: np.ndarray) -> Registration:
        """3. the extrinsic (onto slam's mesh near the camera where it was built from these poses)."""
        scene, cfg = self.scene, self.cfg
        t1 = time.perf_counter()
        reg = register_extrinsic(static.points, M, self.T_init, cfg, sigma=static.sigma,
                                 mesh=scene_mesh(scene) if cfg.mesh_target else None,
                                 anchor=slam_anchor(scene) if self.init_source == "tf" else None)
        self.timings["extrinsic_s"], self.t2 = time.perf_counter() - t1, time.perf_counter()
        return reg

    def facts(self, reg: Registration) -> RegisterFacts:
        return RegisterFacts(reg, self.init_source, self.T_init, self.stored_map is not None, self.cfg,
                             time.perf_counter() - self.t0, self.timings, self.fingerprint)

    def refuse(self, reg: Registration) -> None:
        """The camera cannot be registered: the scene stays usable (mesh, poses, lidar/instance) and
        finished, without a person (:func:`unregistered`); raises :class:`RegistrationError`."""
        self.outputs_touched = True
        line = registration_failure(self.where, reg, self.cfg, self.init_source)
        report, seg_summary = unregistered(self.sw, self.facts(reg), self.lidar, line, self.scene.n_frames)
        raise RegistrationError(line, report=_summary(self.scene.id, report, seg_summary))

    def humans(self, reg: Registration, static, M: np.ndarray) -> tuple[dict, dict | None]:
        """4. the person in every frame (camera/points_world written by a second process meanwhile), 5.
        their closed surfaces, then the writes and the report. Returns (report, segmentation summary)."""
        cfg, T = self.cfg, reg.T
        self.outputs_touched = True
        clear_outputs(self.sw, cfg)
        cam_world = fork_call(camera_world, self.scene, T, label=f"{self.where}: camera/points_world",
                              enabled=self.processes > 1) if cfg.write_camera_world else None
        cand = human_candidates(self.cam, static, M, T, cfg, self.processes, self.quiet, self.where)
        del static.images
        self.timings["candidates_s"] = time.perf_counter() - self.t2
        picks, columns, shift, cuts = self.track(cand, static, M, T)
        self.timings["picks_s"] = time.perf_counter() - self.t2 - self.timings["candidates_s"]
        if cam_world is not None:
            cam_world()
        surfaces = all_surfaces(picks.points, columns, shift, T[:3, 3], cfg, self.processes, self.where)
        self.timings["humans_s"] = time.perf_counter() - self.t2
        write_outputs(self.sw, surfaces, picks.points, T)
        seg_summary = self.segmentation()
        report = register_report(self.facts(reg), surfaces, cand.carved, picks.repicked, shift, cuts)
        self.sw.finish("register", {"register": report, REGISTER_FAILED: None})
        return report, seg_summary

    def track(self, cand, static, M: np.ndarray, T: np.ndarray):
        """4. the person of interest picked from the candidates along its track, each frame's solid behind
        its front, the frames partly hidden, and each frame's shift (velocity compensation plus track
        smoothing): (picks, columns, shift (T,3), cuts (T,))."""
        scene, cfg = self.scene, self.cfg
        eye, f_px = T[:3, 3], float(self.cam.K[0, 0])
        ts = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64)
        cts = np.asarray(scene[CAMERA_TIMESTAMP_NS][...], np.int64) if CAMERA_TIMESTAMP_NS in scene.arrays() else ts
        sigma_a = noise_coefficient(static.med, static.mad)
        picks = pick_track(cand.frames, M, eye, f_px, np.where(cts != 0, cts, ts), cfg, sigma_a)
        shift = human_shift(picks.points, cts, ts, cfg)
        columns = body_columns_of(picks, eye, f_px, cts, cfg)
        cuts = frame_cuts(picks, static.med, cfg, sigma_a)
        shift = shift + track_smoothing(picks.points, columns, shift, eye, ts, cfg, cuts)
        picks.pixels = []
        return picks, columns, shift, cuts

    def segmentation(self) -> dict | None:
        """The LiDAR half's segmentation of every scan (lidar/instance) waited for: its summary or None."""
        t1 = time.perf_counter()
        seg_summary = None
        if self.lidar is not None:
            _, seg_summary, lidar_timings = self.lidar()
            self.timings.update(lidar_timings)
        self.timings["segment_wait_s"] = time.perf_counter() - t1
        return seg_summary

    def abandon(self, err: BaseException) -> None:
        """After ``err``: the LiDAR process joined (it must not write on after register has failed), and
        the scene's unfinished mark taken back when register was refused (or failed on an error of its
        own) before its outputs were touched (lidar/instance, if written, is whole: its shards committed,
        the LiDAR process joined): the scene is as consistent as before, so the failure leaves no mark;
        an interrupt (Ctrl-C) does."""
        if self.lidar is not None:
            self.lidar.join()
        if isinstance(err, Exception) and not self.outputs_touched and not self.resuming:
            self.sw.finish("register")


def unregistered(sw, facts: RegisterFacts, lidar, line: str, n_frames: int) -> tuple[dict, dict | None]:
    """A camera that cannot be registered (``facts.reg`` not accepted; ``line`` the one-line reason,
    :func:`registration_failure`) costs the scene its person, not the scene: a previous run's person
    and extrinsic (made from other inputs or settings) are removed, the LiDAR half (``lidar``, or
    None) finishes the segmentation, and the scene (``n_frames`` frames) is finished through scene
    writer ``sw`` with the report in the scene attribute :data:`REGISTER_FAILED` (``registered`` False,
    ``warning``: ``line``, every attempt's numbers) and no ``register`` attribute (it declares
    register's outputs). Its mesh and poses stay: raytrace-gt traces it without a person, validate
    accepts it. Returns (the report, the segmentation summary or None)."""
    clear_outputs(sw, facts.cfg, calib=True)
    seg_summary = None
    if lidar is not None:
        _, seg_summary, lidar_timings = lidar()
        facts.timings.update(lidar_timings)
    report = {"registered": False, "warning": line, "extrinsic": facts.reg.to_attrs(), "init": facts.init_source,
              "T_init": np.asarray(facts.T_init).tolist(), "map": facts.map_source,
              "frames_with_human": 0, "frames": int(n_frames), "params": facts.cfg.to_attrs(), "seconds": facts.seconds,
              "timings": facts.timings, "fingerprint": facts.fingerprint}
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


def register_report(facts: RegisterFacts, surfaces: list, carved: np.ndarray, repicked: int, shift: np.ndarray,
                    cuts: np.ndarray) -> dict:
    """The scene attribute ``register``: the extrinsic's report, where the guess and the map came
    from (``facts``), frames with a person (``surfaces`` per frame; and those partly hidden, placed
    from the track: ``frames_cut``, with each frame's cut share ``cut_share`` from ``cuts`` (T,)),
    the map points the camera sees through (``carved`` (M,) bool), the frames picked again
    (``repicked``), the largest velocity ``shift`` (T,3) m, the settings, timings and the fingerprint."""
    n = len(surfaces)
    cuts = np.asarray(cuts, float)
    cfg = facts.cfg
    return {"registered": True, "extrinsic": facts.reg.to_attrs(), "init": facts.init_source,
            "T_init": np.asarray(facts.T_init).tolist(), "map": facts.map_source,
            "frames_with_human": int(sum(len(s[1]) > 0 for s in surfaces)), "frames": n,
            "frames_cut": np.flatnonzero(cuts >= cfg.cut_share).tolist(), "cut_share": np.round(cuts, 3).tolist(),
            "map_points_seen_through": int(carved.sum()), "frames_repicked": repicked, "params": cfg.to_attrs(),
            "surface": "voxel boundary (half-filled voxels) of elliptic per-run columns behind the "
                       "visible front (closed)",
            "velocity_shift_m_max": float(np.nanmax(np.linalg.norm(shift, axis=1))) if n else 0.0,
            "seconds": facts.seconds, "timings": facts.timings, "fingerprint": facts.fingerprint}
