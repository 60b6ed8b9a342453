"""One synthetic recording end to end: world, robot, human, sensor rig, clocks, message schedule.

Time: ``t0`` = EPOCH + seed hours. Radar cycle k covers [t0 + 0.3 s + k/2 s, + 0.5 s) (true time);
LiDAR scans every 0.1 s from t0 + 0.05 s; camera frames every 1/rate from t0 + 0.1 s; odometry
(/tf, /odom) at 30 Hz. Each sensor's header stamps carry its own clock offset; the bag's log time
adds a per-sensor latency. Random streams are seeded per (seed, stream, index), so any message can
be generated independently and the output does not depend on generation order.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..conventions import Grid, RangeBins, yaw_rad
from ..errors import InputError
from ..progress import track
from . import truth as truthio
from .camera import T_LINK_OPTICAL, CameraConfig, CameraModel, StereoModel, look_at
from .human import HumanWalk, footprint_points
from .lidar import LidarConfig, LidarModel, beam_angles, ouster_metadata
from .motion import odometry, path_trajectory, pose_xy_yaw, robot_trajectory
from .radar import RadarConfig, RadarModel, encode_heatmap
from .worlds import CLASS_ID, MATERIAL_ID, World, hidden_from, make_world

EPOCH_S = 1_735_689_600  # 2025-01-01T00:00:00Z
RADAR_START_S = 0.3
LIDAR_START_S = 0.05
CAMERA_START_S = 0.1
ODOM_HZ = 30.0
STREAMS = {"radar": 1, "lidar": 2, "camera": 3, "scenario": 4, "odometry": 5, "stereo": 6, "walkers": 7,
           "mapping": 8, "mapping_lidar": 9, "mapping_odometry": 10}

FRAME_MAP, FRAME_ODOM, FRAME_BASE = "map", "odom", "base_link"
FRAME_RADAR = "radar"
FRAME_CAM_LINK = "zed2i_camera_link"
FRAME_RIGHT_OPT = "zed2i_right_camera_optical_frame"


def _rng(seed: int, stream: str, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, STREAMS[stream], int(index)])


def _trans(x, y, z, yaw_deg=0.0) -> np.ndarray:
    T = pose_xy_yaw(x, y, np.deg2rad(yaw_deg), z)
    return np.asarray(T, float)


@dataclass
class Scenario:
    seed: int
    world: World
    frames: int
    t0_ns: int
    duration_s: float
    truth: object            # Trajectory T_world_base (true time)
    truth_info: dict
    odom: object             # Trajectory T_odom_base
    odom_info: dict
    T_map_odom: np.ndarray
    walk: HumanWalk | None
    T_base_radar: np.ndarray
    T_base_lidar: np.ndarray
    T_world_cam_link: np.ndarray
    radar_cfg: RadarConfig
    lidar_cfg: LidarConfig
    camera_cfg: CameraConfig
    lidar_alt: np.ndarray
    lidar_az: np.ndarray
    clock_offset_ns: dict
    latency_ns: dict
    stereo: bool = False
    walkers: list = field(default_factory=list)  # HumanWalk people visible to every sensor (``visible_walkers``)
    radar_output: str = "heatmap"   # "heatmap" (RadarHeatmap) | "iq" (RadarRawRotation, raw samples)

    def t_s(self, t_ns) -> float:
        """Seconds since the start of the recording (true time)."""
        return (np.asarray(t_ns, np.int64) - self.t0_ns) / 1e9

    def human_mesh(self, t_ns: int):
        return None if self.walk is None else self.walk.mesh_at(float(self.t_s(t_ns)))

    def dynamic_mesh(self, t_ns: int):
        """Everything that moves at ``t_ns``: ``((vertices, faces) | None, face_instance (F,) uint16 | None)``.

        Without visible walkers this is exactly :meth:`human_mesh` (and ``None`` instances). With
        walkers, the walkers' meshes (instances 1..N, in order) and the hidden human (instance N+1)
        are merged into one mesh; ``face_instance`` gives each face's instance id."""
        if not self.walkers:
            return self.human_mesh(t_ns), None
        t = float(self.t_s(t_ns))
        parts = [w.mesh_at(t) for w in self.walkers] + ([self.walk.mesh_at(t)] if self.walk is not None else [])
        verts, faces, inst, n = [], [], [], 0
        for i, (v, f) in enumerate(parts):
            verts.append(v)
            faces.append(f + n)
            inst.append(np.full(len(f), i + 1, np.uint16))
            n += len(v)
        return (np.concatenate(verts), np.concatenate(faces).astype(np.int32)), np.concatenate(inst)

    def radar_cycle(self, k: int) -> tuple[int, int]:
        period = int(round(1e9 / self.radar_cfg.rotation_hz))
        start = self.t0_ns + int(round(RADAR_START_S * 1e9)) + k * period
        return start, start + period


def build_scenario(corner: str = "L", width: float | None = None, frames: int = 20, seed: int = 0,
                   human: bool = True, grid: Grid | None = None, range_bins: RangeBins | None = None,
                   lidar_shape=(64, 1024), camera_shape=(376, 672), radar_encoding: str = "float16",
                   stereo_images: bool = False, visible_walkers: int = 0,
                   lidar_vertical_fov_deg: float = LidarConfig.vertical_fov_deg,
                   robot_stop_x: float | None = None, radar_chirps: int | None = None) -> Scenario:
    """Everything about one recording except the sensor data itself.

    ``visible_walkers`` N > 0 adds N people walking back and forth along the approach corridor (the
    robot's), visible to every sensor, for scoring LiDAR human segmentation against per-scan truth
    masks (``truth/lidar_instances.npz``). They draw from their own random stream, so N = 0 leaves
    every output byte-identical to a recording made without the option. ``robot_stop_x`` (m, the
    junction starts at x = 0): where the robot stops instead of the world's drawn stop (0.6-1.2 m
    short of the junction); closer to the junction the radar reaches more of the hidden branch
    (more NLOS ground truth). Either way the stop moves back in 0.5 m steps until some stretch of the
    hidden branch is out of the robot's sight for the person."""
    try:
        world = make_world(corner, width, seed)
    except ValueError as err:
        raise InputError(str(err)) from err
    rng = _rng(seed, "scenario")
    radar_cfg = RadarConfig(grid=grid or Grid(), range_bins=range_bins or RangeBins(), encoding=radar_encoding,
                            **({"chirps_per_rotation": int(radar_chirps)} if radar_chirps else {}))
    period_s = 1.0 / radar_cfg.rotation_hz
    duration = RADAR_START_S + frames * period_s + 0.3
    t0 = (EPOCH_S + (int(seed) % 100_000) * 3600) * 1_000_000_000
    T_base_radar = _trans(float(rng.uniform(0.05, 0.12)), float(rng.uniform(-0.02, 0.02)), float(rng.uniform(0.38, 0.5)),
                          float(rng.uniform(-1.0, 1.0)))
    T_base_lidar = _trans(float(rng.uniform(-0.08, 0.0)), 0.0, float(rng.uniform(0.7, 0.85)), float(rng.uniform(-1.0, 1.0)))
    rows, cols = lidar_shape
    lidar_cfg = LidarConfig(rows=int(rows), cols=int(cols), vertical_fov_deg=float(lidar_vertical_fov_deg))
    alt, az = beam_angles(lidar_cfg, rng)
    cam_cfg = CameraConfig()
    if tuple(camera_shape) != (cam_cfg.height, cam_cfg.width):
        cam_cfg = cam_cfg.scaled(int(camera_shape[1]), int(camera_shape[0]))
    origin, u, L, bw = world.hidden_axis
    nrm = np.array([-u[1], u[0]])
    height = float(rng.uniform(1.5, 1.95))
    speed = 0.0 if rng.random() < 0.25 else float(rng.uniform(0.5, 1.2))
    lat = float(rng.uniform(-1, 1)) * max(0.0, bw / 2 - 0.45)
    walk_len = float(rng.uniform(1.0, 2.5))
    s_jit = float(rng.uniform(0.0, 0.5))
    traj_seed = int(rng.integers(2**31))

    # the robot stops early enough that some stretch of the hidden branch stays out of its sight
    # (wide corridors need a longer distance to the corner)
    for attempt in range(16):
        stop0 = world.robot_stop if robot_stop_x is None else np.array([float(robot_stop_x), world.robot_stop[1]])
        stop = stop0 - np.array([0.5 * attempt, 0.0])
        start = world.robot_start if world.robot_start[0] < stop[0] - 1.0 else stop - np.array([1.0, 0.0])
        truth, tinfo = robot_trajectory(start, stop, duration, t0, np.random.default_rng(traj_seed))
        ts = np.linspace(truth.timestamp_ns[0], truth.timestamp_ns[-1], 60).astype(np.int64)
        P = truth.interpolate(ts)
        viewers = np.concatenate([(P @ T)[:, :2, 3] for T in (T_base_radar, T_base_lidar)])
        viewers = np.concatenate([viewers + np.array(o) for o in
                                  ((0, 0), (0.15, 0), (0, 0.15), (0, -0.15), (0.15, 0.15), (0.15, -0.15))])
        s_grid = np.arange(0.5, L - 1.0 - walk_len, 0.1)
        ok = [bool(hidden_from(world.floor_polygon, viewers, footprint_points(origin + u * s + nrm * lat, 0.45)).all())
              for s in s_grid]
        if any(ok):
            break
    else:
        raise InputError(f"corner {corner} seed {seed}: no place on the hidden side is out of the robot's sight")
    odom, oinfo = odometry(truth, _rng(seed, "odometry"), rate_hz=ODOM_HZ)
    T_map_odom = truth.interpolate(np.array([odom.timestamp_ns[0]]))[0]
    s_a = float(s_grid[int(np.argmax(ok))]) + s_jit
    s_b = min(s_a + walk_len, L - 1.0)
    a, b = origin + u * s_a + nrm * lat, origin + u * s_b + nrm * lat
    seg = np.concatenate([footprint_points(a + (b - a) * f, 0.45) for f in np.linspace(0, 1, 11)])
    if not hidden_from(world.floor_polygon, viewers, seg).all():
        raise InputError(f"corner {corner} seed {seed}: the human's walk would be visible from the robot")
    walk = HumanWalk(a, b, speed, height, float(rng.uniform(0, 1))) if human else None
    if not human:
        rng.uniform(0, 1)

    # camera: in the hidden branch beyond the walk, looking back at it
    s_cam = min(s_b + float(rng.uniform(1.8, 2.8)), L - 0.25)
    eye = np.r_[origin + u * s_cam + nrm * float(rng.uniform(-0.3, 0.3)) * bw, float(rng.uniform(1.0, 1.5))]
    target = np.r_[(a + b) / 2, 0.9]
    T_world_cam_link = look_at(eye, target)

    clock = {"radar": int(rng.integers(-3_000_000, 3_000_001)), "lidar": int(rng.integers(-2_000_000, 2_000_001)),
             "camera": int(rng.integers(-8_000_000, 8_000_001)), "odometry": 0}
    latency = {"radar": int(rng.integers(30_000_000, 45_000_001)), "lidar": int(rng.integers(2_000_000, 6_000_001)),
               "camera": int(rng.integers(20_000_000, 40_000_001)), "odometry": 1_000_000}
    walkers = _visible_walkers(world, seed, int(visible_walkers), start, stop) if visible_walkers else []
    return Scenario(seed, world, frames, t0, duration, truth, tinfo, odom, oinfo, T_map_odom, walk,
                    T_base_radar, T_base_lidar, T_world_cam_link, radar_cfg, lidar_cfg, cam_cfg, alt, az, clock, latency,
                    bool(stereo_images), walkers)


def _visible_walkers(world: World, seed: int, n: int, start: np.ndarray, stop: np.ndarray) -> list:
    """``n`` people walking along the approach corridor (axis y = 0, walls y = ±width/2), off the
    robot's line: lanes alternate sides at ``|y| = width/2 - 0.4`` m (at least 0.35 m off axis), each
    walking between a point behind the robot's start and one short of the junction (x = -0.4 m),
    at 0.7-1.3 m/s with a random phase. People sharing a side split its stretch into consecutive
    pieces 0.6 m apart (one each), so nobody walks through anybody (N <= 2: one per side)."""
    if n < 0:
        raise InputError(f"visible_walkers must be >= 0, got {n}")
    rng = _rng(seed, "walkers")
    half = world.width / 2
    lane = max(0.35, half - 0.4)
    x0 = min(float(start[0]), float(stop[0])) - 2.0
    out = []
    for i in range(n):
        side = 1.0 if i % 2 == 0 else -1.0
        y = side * min(lane, half - 0.3) + float(rng.uniform(-0.05, 0.05))
        a = np.array([x0 + float(rng.uniform(-0.5, 0.5)), y])
        b = np.array([-0.4 - float(rng.uniform(0.0, 0.3)), y])
        out.append(HumanWalk(a, b, float(rng.uniform(0.7, 1.3)), float(rng.uniform(1.55, 1.9)), float(rng.uniform(0, 1))))
    for side in (0, 1):
        group = out[side::2]
        if len(group) < 2:
            continue
        lo, hi = min(w.a[0] for w in group), max(w.b[0] for w in group)
        piece = (hi - lo - 0.6 * (len(group) - 1)) / len(group)
        for j, w in enumerate(group):
            x = lo + j * (piece + 0.6)
            w.a, w.b = np.array([x, w.a[1]]), np.array([x + piece, w.b[1]])
    return out



# ---------------------------------------------------------------------------------- sensors
class Sensors:
    """Ray scene + sensor models for a scenario (built once)."""

    def __init__(self, sc: Scenario):
        from ..raytrace import RayScene

        w = sc.world
        self.sc = sc
        self.scene = RayScene(w.vertices, w.faces, face_class=w.face_class, class_names=w.class_names)
        self.radar = RadarModel(sc.radar_cfg, w.materials, w.face_material, MATERIAL_ID["human"],
                                noise_seed=int(_rng(sc.seed, "radar", 1 << 30).integers(2**63)))
        self.lidar = LidarModel(sc.lidar_cfg, sc.lidar_alt, sc.lidar_az, w.face_material, w.face_class, w.materials,
                                MATERIAL_ID["human"], CLASS_ID["ceiling"])
        self.camera = CameraModel(sc.camera_cfg, sc.T_world_cam_link @ T_LINK_OPTICAL)
        self.cast_log: list | None = None  # set to [] to record the radar's backend casts (benchmarks)
        self.stereo = StereoModel(sc.camera_cfg, sc.T_world_cam_link @ T_LINK_OPTICAL,
                                  [m.lidar_reflectivity for m in w.materials], w.face_material,
                                  w.materials[MATERIAL_ID["human"]].lidar_reflectivity) if sc.stereo else None

    def _radar_paths(self, k: int) -> tuple[dict, np.ndarray, np.ndarray]:
        """The specular paths of cycle k's beams (:meth:`RadarModel.paths`) and the beams' world-frame
        origins and directions (H*W, 3): column j from the rotation centre at its time."""
        sc, cfg = self.sc, self.sc.radar_cfg
        g = cfg.grid
        start, end = sc.radar_cycle(k)
        t_cols = start + np.round((np.arange(g.W) + 0.5) / g.W * (end - start)).astype(np.int64)
        T_cols = sc.truth.interpolate(t_cols) @ sc.T_base_radar             # (W,4,4)
        D = np.einsum("wij,hwj->hwi", T_cols[:, :3, :3], g.directions()).reshape(-1, 3)
        O = np.broadcast_to(T_cols[None, :, :3, 3], (g.H, g.W, 3)).reshape(-1, 3)
        human = sc.dynamic_mesh((start + end) // 2)[0]
        tr = self.trace(O, D, human, cfg.max_bounces, cfg.range_bins.max_range)
        return self.radar.paths(tr, O, D), O, D

    def radar_frame(self, k: int) -> tuple[np.ndarray, dict]:
        """(n_range, H, W) float32 heatmap of cycle k and per-frame stats."""
        paths, _, _ = self._radar_paths(k)
        hm = self.radar.cube(paths, _rng(self.sc.seed, "radar", k))
        return hm, path_stats(paths)

    def radar_rotation(self, k: int) -> tuple[dict, dict]:
        """Raw samples of cycle k (``radar_output="iq"``) and per-frame stats: {chirps (nb+N+na, V, S)
        complex64, n_before, n_rotation, n_after, travel_per_chirp m, heading rad}. The rotation's N
        chirps (chirp n at ``start + (n + ½)/N`` of the cycle) come with the n_syn/2 chirps before and
        after it that its first and last beams need; the motion fields are the odometry's (what the
        robot knows): its displacement over the cycle, in the radar frame at the cycle start."""
        sc, cfg = self.sc, self.sc.radar_cfg
        paths, O, D = self._radar_paths(k)
        start, end = sc.radar_cycle(k)
        _, n_syn = cfg.imaging()
        N, pad = cfg.chirps_per_rotation, n_syn // 2
        n = np.arange(-pad, N + pad)
        t = start + np.round((n + 0.5) / N * (end - start)).astype(np.int64)
        poses = sc.truth.interpolate(t) @ sc.T_base_radar
        chirps = self.radar.iq(paths, O, D, poses, n, _rng(sc.seed, "radar", k))
        a, b = sc.odom.interpolate(np.array([start, end])) @ sc.T_base_radar
        d = a[:3, :3].T @ (b[:3, 3] - a[:3, 3])
        return {"chirps": chirps, "n_before": pad, "n_rotation": N, "n_after": pad,
                "travel_per_chirp": float(np.hypot(d[0], d[1]) / N), "heading": float(np.arctan2(d[1], d[0]))}, \
            path_stats(paths)

    def trace(self, O, D, human, max_bounces: int, max_range: float):
        """Multi-bounce trace through the static world plus this frame's human. The human is merged
        into a per-frame scene (a few hundred triangles: the BVH build is negligible), so one cast
        per bounce serves both; ``hit_dynamic``/``face`` are then rewritten to the dynamic-mesh
        convention of :class:`holodata.raytrace.TraceResult`."""
        from ..raytrace import RayScene

        if human is None:
            self.scene.cast_log = self.cast_log
            return self.scene.trace(O, D, max_bounces=max_bounces, max_range=max_range, labels=False)
        w = self.sc.world
        hv, hf = human
        nf = len(w.faces)
        merged = RayScene(np.concatenate([w.vertices, hv]), np.concatenate([w.faces, hf + len(w.vertices)]))
        merged.cast_log = self.cast_log
        self.last_scene = merged
        tr = merged.trace(O, D, max_bounces=max_bounces, max_range=max_range, labels=False)
        tr.hit_dynamic = tr.face >= nf
        tr.face = np.where(tr.hit_dynamic, tr.face - nf, tr.face)
        return tr

    def lidar_scan(self, i: int, start_ns: int):
        """(points, stats); with visible walkers ``stats["instance"]`` is the (rows, cols) uint16 truth
        instance image (0 = no return on a person) and ``human_hits`` counts the hidden human only."""
        sc = self.sc
        t_cols = start_ns + self.lidar.column_times_ns()
        T_cols = sc.truth.interpolate(t_cols) @ sc.T_base_lidar
        mid = start_ns + int(5e8 / sc.lidar_cfg.rate_hz)
        dyn, face_inst = sc.dynamic_mesh(mid)
        pts, st = self.lidar.scan(self.scene, T_cols, dyn, _rng(sc.seed, "lidar", i), face_instance=face_inst)
        if face_inst is not None:
            st["human_hits"] = int((st["instance"] == len(sc.walkers) + 1).sum()) if sc.walk is not None else 0
        return pts, st

    def camera_frame(self, i: int, t_ns: int):
        return self.camera.frame(self.scene, self.sc.dynamic_mesh(t_ns)[0], _rng(self.sc.seed, "camera", i))

    def stereo_pair(self, i: int, t_ns: int):
        return self.stereo.pair(self.scene, self.sc.dynamic_mesh(t_ns)[0], _rng(self.sc.seed, "stereo", i))


def path_stats(paths: dict) -> dict:
    """LOS structure vs NLOS human power from per-path amplitudes (dB drop, NaN if no NLOS human)."""
    p = np.abs(paths["amp"]) ** 2
    los = (paths["bounce"] == 1) & ~paths["human"]
    nlos_h = (paths["bounce"] >= 2) & paths["human"]
    nlos = paths["bounce"] >= 2
    out = {"n_paths": int(len(p)), "nlos_human_paths": int(nlos_h.sum())}
    out["los_nlos_drop_db"] = float(10 * np.log10(p[los].mean() / p[nlos].mean())) if los.any() and nlos.any() else float("nan")
    out["los_nlos_human_drop_db"] = (float(10 * np.log10(p[los].mean() / p[nlos_h].mean()))
                                     if los.any() and nlos_h.any() else float("nan"))
    return out


# ---------------------------------------------------------------------------------- writing
def _schedule(sc: Scenario) -> list[tuple[int, int, str, int, int]]:
    """(log_ns, priority, kind, index, sensor_time_ns) events, sorted."""
    ev = []
    end_ns = sc.radar_cycle(sc.frames - 1)[1]
    ev.append((sc.t0_ns, 0, "static", 0, sc.t0_ns))
    ev.append((sc.t0_ns + 1_000_000, 1, "metadata", 0, sc.t0_ns))
    for k in range(sc.frames):
        s, e = sc.radar_cycle(k)
        ev.append((e + sc.latency_ns["radar"], 5, "radar", k, s))
    step = int(round(1e9 / sc.lidar_cfg.rate_hz))
    t, i = sc.t0_ns + int(LIDAR_START_S * 1e9), 0
    while t + step <= end_ns:
        ev.append((t + step + sc.latency_ns["lidar"], 4, "lidar", i, t))
        t, i = t + step, i + 1
    step = int(round(1e9 / sc.camera_cfg.rate_hz))
    t, i = sc.t0_ns + int(CAMERA_START_S * 1e9), 0
    while t <= end_ns:
        ev.append((t + sc.latency_ns["camera"], 3, "camera", i, t))
        t, i = t + step, i + 1
    for i, t in enumerate(sc.odom.timestamp_ns):
        if t > end_ns:
            break
        ev.append((int(t) + sc.latency_ns["odometry"], 2, "odom", i, int(t)))
    ev.sort()
    return ev


def write_recording(sc: Scenario, out_dir: Path, fmt: str, quiet: bool = False):
    from ..messages import RADAR_RAW_TYPE as RAW_TYPE
    from . import RAW_TOPIC, STEREO_TOPICS, TOPICS, SynthResult
    from .recording import BagWriter, recording_path

    out_dir = Path(out_dir)
    sensors = Sensors(sc)
    truth_dir = out_dir / "truth"
    truth_dir.mkdir(parents=True, exist_ok=False)
    human_dir = truth_dir / "human" if sc.walk is not None else None
    if human_dir is not None:
        human_dir.mkdir()
    rec = recording_path(out_dir, fmt)
    topics = dict(TOPICS, **(STEREO_TOPICS if sc.stereo else {}))
    if sc.radar_output == "iq":
        topics = {(RAW_TOPIC if t == "/radar/heatmap" else t): (RAW_TYPE if t == "/radar/heatmap" else v)
                  for t, v in topics.items()}
    counts = {t: 0 for t in topics}
    frame_rows, radar_tum, lidar_tum = [], [], []
    lidar_human_hits, camera_human_pixels = 0, 0
    inst_rows: list[tuple[int, np.ndarray]] = []  # (header stamp, instance image) per scan, with walkers
    events = _schedule(sc)
    cam_cfg, rcfg = sc.camera_cfg, sc.radar_cfg
    T_world_cam_opt = sc.T_world_cam_link @ T_LINK_OPTICAL
    with BagWriter(rec, fmt) as bw:
        for topic, typ in topics.items():
            bw.add(topic, typ, latched=topic in ("/tf_static", "/ouster/metadata"))

        def put(topic, t_ns, msg):
            bw.write(topic, t_ns, msg)
            counts[topic] += 1

        for log_ns, _, kind, idx, t_ns in track(events, len(events), "synth", quiet):
            if kind == "static":
                tfs = [bw.transform("/tf_static", t_ns, FRAME_MAP, FRAME_ODOM, sc.T_map_odom),
                       bw.transform("/tf_static", t_ns, FRAME_BASE, FRAME_RADAR, sc.T_base_radar),
                       bw.transform("/tf_static", t_ns, FRAME_BASE, sc.lidar_cfg.frame_id, sc.T_base_lidar),
                       bw.transform("/tf_static", t_ns, FRAME_MAP, FRAME_CAM_LINK, sc.T_world_cam_link),
                       bw.transform("/tf_static", t_ns, FRAME_CAM_LINK, cam_cfg.cloud_frame_id, np.eye(4)),
                       bw.transform("/tf_static", t_ns, FRAME_CAM_LINK, cam_cfg.frame_id, T_LINK_OPTICAL)]
                if sc.stereo:
                    T_right = _trans(0.0, -cam_cfg.baseline_m, 0.0) @ T_LINK_OPTICAL
                    tfs.append(bw.transform("/tf_static", t_ns, FRAME_CAM_LINK, FRAME_RIGHT_OPT, T_right))
                put("/tf_static", log_ns, bw.tf_message(tfs))
            elif kind == "metadata":
                md = ouster_metadata(sc.lidar_cfg, sc.lidar_alt, sc.lidar_az, f"SYN{sc.seed:09d}")
                put("/ouster/metadata", log_ns, bw.string(json.dumps(md, sort_keys=True)))
            elif kind == "odom":
                T = sc.odom.poses[idx]
                put("/tf", log_ns, bw.tf_message([bw.transform("/tf", t_ns, FRAME_ODOM, FRAME_BASE, T)]))
                put("/odom", log_ns, _odometry_msg(bw, sc, idx, t_ns))
            elif kind == "radar":
                s, e = sc.radar_cycle(idx)
                off = sc.clock_offset_ns["radar"]
                stamp = (s + e) // 2 + off
                if sc.radar_output == "iq":
                    r, st = sensors.radar_rotation(idx)
                    msg = bw.radar_raw_rotation(RAW_TOPIC, stamp, FRAME_RADAR, r["chirps"], r["n_before"], r["n_rotation"],
                                                r["n_after"], rcfg.imaging()[0], s + off, e + off, r["travel_per_chirp"],
                                                r["heading"])
                    put(RAW_TOPIC, log_ns, msg)
                else:
                    hm, st = sensors.radar_frame(idx)
                    msg = bw.radar_heatmap("/radar/heatmap", stamp, FRAME_RADAR, encode_heatmap(hm, rcfg.encoding),
                                           hm.shape, rcfg, s + off, e + off)
                    put("/radar/heatmap", log_ns, msg)
                mid = (s + e) // 2
                radar_tum.append((stamp, sc.truth.interpolate(np.array([mid]))[0] @ sc.T_base_radar))
                hc = sc.walk.center_at(float(sc.t_s(mid))) if sc.walk is not None else np.full(3, np.nan)
                if human_dir is not None:
                    hv, hf = sc.human_mesh(mid)
                    truthio.write_mesh(human_dir / f"{idx:06d}.ply", hv, hf, np.full(len(hf), CLASS_ID["human"], np.uint8),
                                       {CLASS_ID["human"]: "human"})
                frame_rows.append({"frame": idx, "stamp_ns": stamp, "cycle_start_ns": s + off, "cycle_end_ns": e + off,
                                   "true_mid_ns": mid, "human_x": hc[0], "human_y": hc[1], "human_z": hc[2],
                                   "los_nlos_drop_db": st["los_nlos_drop_db"],
                                   "los_nlos_human_drop_db": st["los_nlos_human_drop_db"]})
            elif kind == "lidar":
                pts, st = sensors.lidar_scan(idx, t_ns)
                lidar_human_hits += st["human_hits"]
                stamp = t_ns + sc.clock_offset_ns["lidar"]
                if "instance" in st:
                    inst_rows.append((stamp, st["instance"]))
                put("/ouster/points", log_ns, bw.point_cloud("/ouster/points", stamp, sc.lidar_cfg.frame_id, pts))
                lidar_tum.append((stamp, sc.truth.interpolate(np.array([t_ns]))[0] @ sc.T_base_lidar))
            elif kind == "camera":
                depth, st = sensors.camera_frame(idx, t_ns)
                camera_human_pixels += st["human_pixels"]
                stamp = t_ns + sc.clock_offset_ns["camera"]
                put("/zed2i/zed_node/depth/depth_registered", log_ns,
                    bw.image_32fc1("/zed2i/zed_node/depth/depth_registered", stamp, cam_cfg.frame_id, depth))
                put("/zed2i/zed_node/depth/camera_info", log_ns,
                    bw.camera_info("/zed2i/zed_node/depth/camera_info", stamp, cam_cfg.frame_id, cam_cfg))
                cloud = sensors.camera.cloud(depth)
                xyz = np.zeros(cloud.shape[:2], np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3,
                                                          "offsets": [0, 4, 8], "itemsize": 12}))
                xyz["x"], xyz["y"], xyz["z"] = cloud[..., 0], cloud[..., 1], cloud[..., 2]
                put("/zed2i/zed_node/point_cloud/cloud_registered", log_ns,
                    bw.point_cloud("/zed2i/zed_node/point_cloud/cloud_registered", stamp, cam_cfg.cloud_frame_id, xyz))
                if sc.stereo:
                    left, right = sensors.stereo_pair(idx, t_ns)
                    for side, img, frame, tx in (("left", left, cam_cfg.frame_id, 0.0),
                                                 ("right", right, FRAME_RIGHT_OPT, -cam_cfg.fx * cam_cfg.baseline_m)):
                        put(f"/zed2i/zed_node/{side}/image_rect_gray", log_ns,
                            bw.image_mono8(f"/zed2i/zed_node/{side}/image_rect_gray", stamp, frame, img))
                        put(f"/zed2i/zed_node/{side}/camera_info", log_ns,
                            bw.camera_info(f"/zed2i/zed_node/{side}/camera_info", stamp, frame, cam_cfg, tx))
        storage = bw.storage_file

    # ------------------------------------------------------------------ truth/
    w = sc.world
    mesh_path = truth_dir / "mesh.ply"
    truthio.write_mesh(mesh_path, w.vertices, w.faces, w.face_class, w.class_names)
    np.save(truth_dir / "mesh_face_material.npy", w.face_material)
    tb = np.arange(sc.truth.timestamp_ns[0], sc.truth.timestamp_ns[-1] + 1, 10_000_000, dtype=np.int64)
    truthio.write_trajectory(truth_dir / "trajectory_base.tum", tb, sc.truth.interpolate(tb))
    truthio.write_trajectory(truth_dir / "trajectory_radar.tum", [r[0] for r in radar_tum], np.stack([r[1] for r in radar_tum]))
    if lidar_tum:
        truthio.write_trajectory(truth_dir / "trajectory_lidar.tum", [r[0] for r in lidar_tum],
                                 np.stack([r[1] for r in lidar_tum]))
    truthio.write_trajectory(truth_dir / "odometry.tum", sc.odom.timestamp_ns, sc.odom.poses)
    truthio.write_frames_csv(truth_dir / "radar_frames.csv", frame_rows)
    if sc.walkers:
        truthio.write_lidar_instances(truth_dir / "lidar_instances.npz", inst_rows, len(sc.walkers),
                                      sc.walk is not None)
    truthio.write_json(truth_dir / "extrinsics.json", {
        "T_base_radar": sc.T_base_radar, "T_base_lidar": sc.T_base_lidar,
        "T_world_camera_link": sc.T_world_cam_link, "T_world_camera_optical": T_world_cam_opt,
        "T_camera_link_optical": T_LINK_OPTICAL, "T_map_odom": sc.T_map_odom,
        "frames": {"world": FRAME_MAP, "odom": FRAME_ODOM, "base": FRAME_BASE, "radar": FRAME_RADAR,
                   "lidar": sc.lidar_cfg.frame_id, "camera_link": FRAME_CAM_LINK,
                   "camera_optical": cam_cfg.frame_id, "camera_cloud": cam_cfg.cloud_frame_id},
    })
    drops = np.array([r["los_nlos_human_drop_db"] for r in frame_rows], float)
    drops_all = np.array([r["los_nlos_drop_db"] for r in frame_rows], float)
    stats = {
        "lidar_human_hits": lidar_human_hits,
        "camera_human_pixels": camera_human_pixels,
        "los_nlos_drop_db": float(np.nanmedian(drops_all)) if np.isfinite(drops_all).any() else None,
        "los_nlos_human_drop_db": float(np.nanmedian(drops)) if np.isfinite(drops).any() else None,
    }
    d = stats["los_nlos_human_drop_db"]
    stats["attenuation_band"] = None if d is None else ("low" if d < 10 else "medium" if d <= 20 else "high")
    scene = w.describe()
    scene.update({
        "holodata_synth_version": 1,
        "seed": sc.seed, "frames": sc.frames, "format": fmt, "t0_ns": sc.t0_ns, "duration_s": sc.duration_s,
        "human": None if sc.walk is None else {"height_m": sc.walk.height, "speed_mps": sc.walk.speed,
                                               "a": sc.walk.a, "b": sc.walk.b, "phase0": sc.walk.phase0},
        "robot": sc.truth_info, "odometry": sc.odom_info,
        "radar": rcfg.describe(), "lidar": sc.lidar_cfg.describe(), "camera": cam_cfg.describe(),
        "lidar_beam_altitude_deg": sc.lidar_alt, "lidar_beam_azimuth_deg": sc.lidar_az,
        "clock_offset_ns": sc.clock_offset_ns, "latency_ns": sc.latency_ns,
        "topics": topics, "counts": counts, "stats": stats,
        "recording": str(rec.relative_to(out_dir)), "storage_file": str(Path(storage).relative_to(out_dir)),
        "conventions": {
            "radar_stamp": "header.stamp = mid-cycle in the radar clock; cycle_start_ns/cycle_end_ns likewise",
            "radar_elevation_units": "radians (elevation_max/elevation_min in the message)",
            "trajectory_radar": "line k = radar frame k, stamped with its header stamp; true pose at mid-cycle",
            "human_dir": "truth/human/<frame:06d>.ply = world-frame human mesh at radar frame's mid-cycle",
            "radar_beam_origin": "rotation centre, moving with the robot during the cycle (per-column pose)",
        },
    })
    if sc.radar_output == "iq":
        chirp, n_syn = rcfg.imaging()
        scale, noise = sensors.radar.raw_scale()
        scene["radar_output"] = {"kind": "iq", "topic": RAW_TOPIC, "chirp": chirp.to_attrs(), "n_syn": n_syn,
                                 "chirps_around_rotation": n_syn // 2, "amplitude_scale": scale,
                                 "noise_std_per_sample": noise,
                                 "scatterers": "every specular path at its image source (beam origin + range x "
                                               "first direction), amplitude |a| x amplitude_scale"}
    if sc.walkers:
        scene["visible_walkers"] = [{"a": w.a, "b": w.b, "speed_mps": w.speed, "height_m": w.height,
                                     "phase0": w.phase0, "instance": i + 1} for i, w in enumerate(sc.walkers)]
    scene_path = truth_dir / "scene.json"
    truthio.write_json(scene_path, scene)
    return SynthResult(out_dir=out_dir, recording=rec, storage_file=Path(storage), format=fmt, truth_dir=truth_dir,
                       scene_json=scene_path, mesh=mesh_path, trajectory_radar=truth_dir / "trajectory_radar.tum",
                       trajectory_base=truth_dir / "trajectory_base.tum", human_dir=human_dir, n_frames=sc.frames,
                       corner=w.corner, width_m=w.width, seed=sc.seed, human=sc.walk is not None,
                       topics=topics, counts=counts, stats=stats)


def _odometry_msg(bw, sc: Scenario, i: int, t_ns: int):
    T = bw.types
    P = sc.odom.poses[i]
    j0, j1 = max(0, i - 1), min(len(sc.odom) - 1, i + 1)
    dt = max(1e-9, (sc.odom.timestamp_ns[j1] - sc.odom.timestamp_ns[j0]) / 1e9)
    D = np.linalg.inv(sc.odom.poses[j0]) @ sc.odom.poses[j1]
    v = D[:3, 3] / dt
    wz = yaw_rad(D) / dt
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(P[:3, :3]).as_quat()
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    pose = T["geometry_msgs/msg/PoseWithCovariance"](
        pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=float(P[0, 3]), y=float(P[1, 3]),
                                                                                z=float(P[2, 3])),
                                         orientation=Q(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))),
        covariance=np.diag([0.01, 0.01, 1e-6, 1e-6, 1e-6, 0.02]).ravel())
    twist = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=V3(x=float(v[0]), y=float(v[1]), z=0.0), angular=V3(x=0.0, y=0.0, z=float(wz))),
        covariance=np.diag([0.005, 0.005, 1e-6, 1e-6, 1e-6, 0.01]).ravel())
    return T["nav_msgs/msg/Odometry"](header=bw.header("/odom", t_ns, FRAME_ODOM), child_frame_id=FRAME_BASE,
                                      pose=pose, twist=twist)


# ---------------------------------------------------------------------------------- mapping pass
MAPPING_GAP_S = 30.0      # the mapping pass ends this long before the data pass starts
MAPPING_SPEED_MPS = 0.8   # cruise speed of the mapping pass
MAPPING_SCAN_HZ = 2.0     # LiDAR scans kept (throttled from the 10 Hz sensor) during the mapping pass
MAPPING_YAW_RATE_RPS = 0.4  # at most this yaw rate in the turns (12 deg between two kept scans)


@dataclass
class MappingPass:
    """The robot's mapping drive through the empty corner before the data pass (no person, LiDAR
    and odometry only). ``truth`` T_world_base (true time, same world as the data pass), ``odom``
    T_odom_base, ``T_map_odom``, ``t0_ns`` its start, ``scan_hz`` the kept LiDAR scans' rate,
    ``info`` path parameters."""

    truth: object
    odom: object
    odom_info: dict
    T_map_odom: np.ndarray
    t0_ns: int
    scan_hz: float
    info: dict


def mapping_legs(world: World, start_x: float) -> list:
    """The mapping pass's legs [(waypoints (K,2) m, reverse)]: from ``start_x`` on the approach
    corridor's axis (y = 0) to the junction point J where the hidden branch's centre line crosses
    that axis, and up the hidden branch to 1.5 m short of its end. A T or cross first turns into the
    branch opposite the hidden one (3 m, or to 1.5 m short of its end) and backs out of it straight
    through J into the hidden branch: from J alone the LiDAR sees that branch's walls only at grazing
    angles, and the radar's bounces reach them (T_11 lost 4 % of its NLOS ground truth there). From
    J the LiDAR looks down the cross's continuation head-on."""
    origin, u, L, _ = world.hidden_axis
    s_j = -float(origin[1]) / float(u[1])
    J = origin + u * s_j
    end = origin + u * max(0.5, L - 1.5)
    start = np.array([float(start_x), 0.0])
    if world.corner in ("T", "cross"):
        other = J - u * min(3.0, L - 1.5 + s_j)
        return [(np.array([start, J, other]), False), (np.array([other, end]), True)]
    return [(np.array([start, J, end]), False)]


def build_mapping_pass(sc: Scenario, scan_hz: float = MAPPING_SCAN_HZ, speed: float = MAPPING_SPEED_MPS) -> MappingPass:
    """The mapping pass of scenario ``sc`` (:func:`mapping_legs` from 1 m short of the approach
    corridor's end wall, ``speed`` m/s, turns of radius 0.4 times the narrower corridor's width). It ends
    :data:`MAPPING_GAP_S` before the data pass starts; its odometry starts again at identity (a
    separate recording) with its own drift."""
    w = sc.world
    rng = _rng(sc.seed, "mapping")
    # from 1 m short of the approach corridor's end wall: the radar reaches that far (9.6 m), and door
    # recesses and pilasters behind the data pass are only mapped by driving past them
    start_x = float(w.floor_polygon[:, 0].min()) + 1.0
    legs = mapping_legs(w, start_x)
    radius = 0.4 * min(w.width, w.hidden_width)
    kw = dict(speed=speed, turn_radius=radius, max_yaw_rate=MAPPING_YAW_RATE_RPS, legs=legs)
    _, info = path_trajectory(None, 0, np.random.default_rng(0), **kw)  # its duration
    t0 = sc.t0_ns - int(round((info["duration_s"] + MAPPING_GAP_S) * 1e9))
    truth, info = path_trajectory(None, t0, rng, **kw)
    odom, oinfo = odometry(truth, _rng(sc.seed, "mapping_odometry"), rate_hz=ODOM_HZ)
    T_map_odom = truth.interpolate(np.array([odom.timestamp_ns[0]]))[0]
    return MappingPass(truth, odom, oinfo, T_map_odom, t0, float(scan_hz), info)


def write_mapping_recording(sc: Scenario, mp: MappingPass, out_dir: Path, fmt: str, quiet: bool = False) -> dict:
    """Write the mapping pass as its own recording ``out_dir/mapping`` (rosbag2 directory, or
    ``mapping.bag``): ``/ouster/points`` + ``/ouster/metadata``, ``/tf`` + ``/odom`` (its own drifting
    odometry), ``/tf_static`` (map→odom, base_link→os_sensor); its truth goes to
    ``truth/mapping_trajectory_base.tum``, ``truth/mapping_trajectory_lidar.tum`` and
    ``truth/mapping_odometry.tum`` (the data pass's world frame). Returns the ``mapping_pass`` entry
    of ``truth/scene.json``."""
    from .recording import BagWriter, recording_path

    out_dir = Path(out_dir)
    sensors = Sensors(sc)
    rec = recording_path(out_dir, fmt, name="mapping")
    from . import MAPPING_TOPICS

    topics = dict(MAPPING_TOPICS)
    counts = {t: 0 for t in topics}
    t_end = int(mp.truth.timestamp_ns[-1])
    ev = [(mp.t0_ns, 0, "static", 0, mp.t0_ns), (mp.t0_ns + 1_000_000, 1, "metadata", 0, mp.t0_ns)]
    step = int(round(1e9 / mp.scan_hz))
    scan_ns = int(round(1e9 / sc.lidar_cfg.rate_hz))
    t, i = mp.t0_ns + int(LIDAR_START_S * 1e9), 0
    while t + scan_ns <= t_end:
        ev.append((t + scan_ns + sc.latency_ns["lidar"], 4, "lidar", i, t))
        t, i = t + step, i + 1
    for k, tt in enumerate(mp.odom.timestamp_ns):
        ev.append((int(tt) + sc.latency_ns["odometry"], 2, "odom", k, int(tt)))
    ev.sort()
    msc = _MappingView(sc, mp)
    lidar_tum = []
    with BagWriter(rec, fmt) as bw:
        for topic, typ in topics.items():
            bw.add(topic, typ, latched=topic in ("/tf_static", "/ouster/metadata"))

        def put(topic, t_ns, msg):
            bw.write(topic, t_ns, msg)
            counts[topic] += 1

        for log_ns, _, kind, idx, t_ns in track(ev, len(ev), "synth: mapping pass", quiet):
            if kind == "static":
                tfs = [bw.transform("/tf_static", t_ns, FRAME_MAP, FRAME_ODOM, mp.T_map_odom),
                       bw.transform("/tf_static", t_ns, FRAME_BASE, sc.lidar_cfg.frame_id, sc.T_base_lidar)]
                put("/tf_static", log_ns, bw.tf_message(tfs))
            elif kind == "metadata":
                md = ouster_metadata(sc.lidar_cfg, sc.lidar_alt, sc.lidar_az, f"SYN{sc.seed:09d}")
                put("/ouster/metadata", log_ns, bw.string(json.dumps(md, sort_keys=True)))
            elif kind == "odom":
                put("/tf", log_ns, bw.tf_message([bw.transform("/tf", t_ns, FRAME_ODOM, FRAME_BASE, mp.odom.poses[idx])]))
                put("/odom", log_ns, _odometry_msg(bw, msc, idx, t_ns))
            else:
                T_cols = mp.truth.interpolate(t_ns + sensors.lidar.column_times_ns()) @ sc.T_base_lidar
                pts, _ = sensors.lidar.scan(sensors.scene, T_cols, None, _rng(sc.seed, "mapping_lidar", idx))
                stamp = t_ns + sc.clock_offset_ns["lidar"]
                put("/ouster/points", log_ns, bw.point_cloud("/ouster/points", stamp, sc.lidar_cfg.frame_id, pts))
                lidar_tum.append((stamp, mp.truth.interpolate(np.array([t_ns]))[0] @ sc.T_base_lidar))
        storage = bw.storage_file
    truth_dir = out_dir / "truth"
    tb = np.arange(mp.truth.timestamp_ns[0], mp.truth.timestamp_ns[-1] + 1, 10_000_000, dtype=np.int64)
    truthio.write_trajectory(truth_dir / "mapping_trajectory_base.tum", tb, mp.truth.interpolate(tb))
    truthio.write_trajectory(truth_dir / "mapping_trajectory_lidar.tum", [r[0] for r in lidar_tum],
                             np.stack([r[1] for r in lidar_tum]))
    truthio.write_trajectory(truth_dir / "mapping_odometry.tum", mp.odom.timestamp_ns, mp.odom.poses)
    return {"recording": str(rec.relative_to(out_dir)), "storage_file": str(Path(storage).relative_to(out_dir)),
            "t0_ns": mp.t0_ns, "duration_s": mp.info["duration_s"], "scan_hz": mp.scan_hz, "scans": counts["/ouster/points"],
            "robot": mp.info, "odometry": mp.odom_info, "T_map_odom": mp.T_map_odom, "topics": topics, "counts": counts,
            "human": None, "world_frame": "the data pass's (truth/mesh.ply)"}


class _MappingView:
    """What :func:`_odometry_msg` reads of a scenario (``odom``), for the mapping pass."""

    def __init__(self, sc: Scenario, mp: MappingPass):
        self.odom = mp.odom
