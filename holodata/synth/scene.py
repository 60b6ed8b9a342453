"""One synthetic scene: world, robot, human, sensor rig and clocks (:class:`Scenario`,
:class:`SceneSpec`, :func:`build_scenario`) and the sensor models bound to it (:class:`Sensors`).

Time: ``t0`` = EPOCH + seed hours. Radar cycle k covers [t0 + 0.3 s + k/2 s, + 0.5 s) (true time);
LiDAR scans every 0.1 s from t0 + 0.05 s; camera frames every 1/rate from t0 + 0.1 s; odometry
(/tf, /odom) at 30 Hz. Each sensor's header stamps carry its own clock offset; the bag's log time
adds a per-sensor latency. Random streams are seeded per (seed, stream, index), so any message can
be generated independently and the output does not depend on generation order.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..conventions import Grid, RangeBins
from ..errors import InputError
from ..trajectory import Trajectory
from .camera import T_LINK_OPTICAL, CameraConfig, CameraModel, StereoModel, look_at
from .human import HumanWalk, footprint_points
from .lidar import LidarConfig, LidarModel, beam_angles
from .motion import odometry, pose_xy_yaw, robot_trajectory
from .radar import RadarConfig, RadarModel
from .spec import SceneSpec
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


def counting_put(bw, topics: dict, counts: dict):
    """Declare ``topics`` ({topic: message type}) on the recording writer ``bw`` (static TF and the
    Ouster metadata latched, as drivers publish them) and return ``put(topic, t_ns, msg)``, which
    writes a message and counts it in ``counts`` (the recording's per-topic message counts)."""
    for topic, typ in topics.items():
        bw.add(topic, typ, latched=topic in ("/tf_static", "/ouster/metadata"))

    def put(topic, t_ns, msg):
        bw.write(topic, t_ns, msg)
        counts[topic] += 1

    return put


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
    truth: Trajectory        # T_world_base (true time)
    truth_info: dict
    odom: Trajectory         # T_odom_base
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


def build_scenario(spec: SceneSpec = SceneSpec()) -> Scenario:
    """Everything about one recording except the sensor data itself (:class:`SceneSpec`: what it
    shows). The scenario stream's draws come in a fixed order: the rig, the person, the camera, the
    clocks; the robot's path, odometry and visible walkers draw from streams of their own."""
    world = _corner_world(spec)
    rng = _rng(spec.seed, "scenario")
    radar_cfg = _radar_config(spec)
    period_s = 1.0 / radar_cfg.rotation_hz
    duration = RADAR_START_S + spec.frames * period_s + 0.3
    t0 = (EPOCH_S + (int(spec.seed) % 100_000) * 3600) * 1_000_000_000
    rig = _Rig.draw(spec, rng)
    person = _PersonDraws.draw(rng)
    run = _RobotRun.find(world, spec, rig, person, duration, t0)
    odom, oinfo = odometry(run.truth, _rng(spec.seed, "odometry"), rate_hz=ODOM_HZ)
    T_map_odom = run.truth.interpolate(np.array([odom.timestamp_ns[0]]))[0]
    a, b, s_b = run.hidden_walk(world, spec, person)
    walk = HumanWalk(a, b, person.speed, person.height, float(rng.uniform(0, 1))) if spec.human else None
    if not spec.human:
        rng.uniform(0, 1)
    T_world_cam_link = _camera_pose(world, a, b, s_b, rng)
    clock, latency = _clocks(rng)
    walkers = (_visible_walkers(world, spec.seed, int(spec.visible_walkers), run.start, run.stop)
               if spec.visible_walkers else [])
    return Scenario(spec.seed, world, spec.frames, t0, duration, run.truth, run.info, odom, oinfo, T_map_odom, walk,
                    rig.T_base_radar, rig.T_base_lidar, T_world_cam_link, radar_cfg, rig.lidar_cfg, rig.camera_cfg,
                    rig.lidar_alt, rig.lidar_az, clock, latency, bool(spec.stereo_images), walkers, spec.radar_output)


def _corner_world(spec: SceneSpec) -> World:
    """The corner's world (:func:`make_world`, its own seed); a bad corner kind or width is an :class:`InputError`."""
    try:
        return make_world(spec.corner, spec.width, spec.seed)
    except ValueError as err:
        raise InputError(str(err)) from err


def _radar_config(spec: SceneSpec) -> RadarConfig:
    return RadarConfig(grid=spec.grid or Grid(), range_bins=spec.range_bins or RangeBins(), encoding=spec.radar_encoding,
                       **({"chirps_per_rotation": int(spec.radar_chirps)} if spec.radar_chirps else {}))


@dataclass(frozen=True)
class _Rig:
    """The robot's sensors: radar and LiDAR mounts on base_link (4×4, drawn: radar 5-12 cm ahead and
    38-50 cm up, LiDAR up to 8 cm behind and 70-85 cm up, each yawed within ±1°), the LiDAR's
    configuration and beam angles (deg) and the depth camera's configuration."""

    T_base_radar: np.ndarray
    T_base_lidar: np.ndarray
    lidar_cfg: LidarConfig
    lidar_alt: np.ndarray
    lidar_az: np.ndarray
    camera_cfg: CameraConfig

    @classmethod
    def draw(cls, spec: SceneSpec, rng: np.random.Generator) -> _Rig:
        T_base_radar = _trans(float(rng.uniform(0.05, 0.12)), float(rng.uniform(-0.02, 0.02)),
                              float(rng.uniform(0.38, 0.5)), float(rng.uniform(-1.0, 1.0)))
        T_base_lidar = _trans(float(rng.uniform(-0.08, 0.0)), 0.0, float(rng.uniform(0.7, 0.85)),
                              float(rng.uniform(-1.0, 1.0)))
        rows, cols = spec.lidar_shape
        lidar_cfg = LidarConfig(rows=int(rows), cols=int(cols), vertical_fov_deg=float(spec.lidar_vertical_fov_deg))
        alt, az = beam_angles(lidar_cfg, rng)
        cam_cfg = CameraConfig()
        if tuple(spec.camera_shape) != (cam_cfg.height, cam_cfg.width):
            cam_cfg = cam_cfg.scaled(int(spec.camera_shape[1]), int(spec.camera_shape[0]))
        return cls(T_base_radar, T_base_lidar, lidar_cfg, alt, az, cam_cfg)


@dataclass(frozen=True)
class _PersonDraws:
    """The hidden person's draws: height m, speed m/s (0 a quarter of the time: standing), lateral
    offset from the hidden branch's axis as a fraction of the free half-width, walk length m, jitter
    of the walk's start m, and the seed of the robot's trajectory."""

    height: float
    speed: float
    lat_frac: float
    walk_len: float
    s_jit: float
    traj_seed: int

    @classmethod
    def draw(cls, rng: np.random.Generator) -> _PersonDraws:
        height = float(rng.uniform(1.5, 1.95))
        speed = 0.0 if rng.random() < 0.25 else float(rng.uniform(0.5, 1.2))
        lat_frac = float(rng.uniform(-1, 1))
        walk_len = float(rng.uniform(1.0, 2.5))
        s_jit = float(rng.uniform(0.0, 0.5))
        return cls(height, speed, lat_frac, walk_len, s_jit, int(rng.integers(2**31)))

    def lateral(self, world: World) -> float:
        """Offset (m) of the walk from the hidden branch's axis."""
        return self.lat_frac * max(0.0, world.hidden_axis[3] / 2 - 0.45)


@dataclass(frozen=True)
class _RobotRun:
    """The data pass's robot: start and stop (2,) m, true trajectory and its parameters, the plan-view
    viewpoints (N,2) of its radar and LiDAR (with a 15 cm margin), the walk starts ``s_grid`` (m along
    the hidden branch) tried and which of them (``ok``) hide a person's footprint from every viewpoint."""

    start: np.ndarray
    stop: np.ndarray
    truth: Trajectory
    info: dict
    viewers: np.ndarray
    s_grid: np.ndarray
    ok: list

    @classmethod
    def find(cls, world: World, spec: SceneSpec, rig: _Rig, person: _PersonDraws, duration: float, t0: int) -> _RobotRun:
        """The robot stops early enough that some stretch of the hidden branch stays out of its sight
        (wide corridors need a longer distance to the corner): the stop moves back 0.5 m at a time."""
        origin, u, L, _ = world.hidden_axis
        nrm = np.array([-u[1], u[0]])
        lat = person.lateral(world)
        for attempt in range(16):
            stop0 = (world.robot_stop if spec.robot_stop_x is None
                     else np.array([float(spec.robot_stop_x), world.robot_stop[1]]))
            stop = stop0 - np.array([0.5 * attempt, 0.0])
            start = world.robot_start if world.robot_start[0] < stop[0] - 1.0 else stop - np.array([1.0, 0.0])
            truth, tinfo = robot_trajectory(start, stop, duration, t0, np.random.default_rng(person.traj_seed))
            viewers = _viewpoints(truth, rig)
            s_grid = np.arange(0.5, L - 1.0 - person.walk_len, 0.1)
            ok = [bool(hidden_from(world.floor_polygon, viewers,
                                   footprint_points(origin + u * s + nrm * lat, 0.45)).all()) for s in s_grid]
            if any(ok):
                return cls(start, stop, truth, tinfo, viewers, s_grid, ok)
        raise InputError(f"corner {spec.corner} seed {spec.seed}: no place on the hidden side is out of the robot's sight")

    def hidden_walk(self, world: World, spec: SceneSpec, person: _PersonDraws) -> tuple[np.ndarray, np.ndarray, float]:
        """The person's walk from ``a`` to ``b`` (2,) m, starting at the first hidden walk start (plus
        the jitter), and where it ends along the hidden branch ``s_b`` m; refused if any of it would be
        visible from the robot."""
        origin, u, L, _ = world.hidden_axis
        nrm = np.array([-u[1], u[0]])
        lat = person.lateral(world)
        s_a = float(self.s_grid[int(np.argmax(self.ok))]) + person.s_jit
        s_b = min(s_a + person.walk_len, L - 1.0)
        a, b = origin + u * s_a + nrm * lat, origin + u * s_b + nrm * lat
        seg = np.concatenate([footprint_points(a + (b - a) * f, 0.45) for f in np.linspace(0, 1, 11)])
        if not hidden_from(world.floor_polygon, self.viewers, seg).all():
            raise InputError(f"corner {spec.corner} seed {spec.seed}: the human's walk would be visible from the robot")
        return a, b, s_b


def _viewpoints(truth, rig: _Rig) -> np.ndarray:
    """Plan-view positions (N,2) of the radar and the LiDAR at 60 times along ``truth``, each also
    shifted by 15 cm forward and sideways (a margin for the sensors' extent)."""
    ts = np.linspace(truth.timestamp_ns[0], truth.timestamp_ns[-1], 60).astype(np.int64)
    P = truth.interpolate(ts)
    viewers = np.concatenate([(P @ T)[:, :2, 3] for T in (rig.T_base_radar, rig.T_base_lidar)])
    return np.concatenate([viewers + np.array(o) for o in
                           ((0, 0), (0.15, 0), (0, 0.15), (0, -0.15), (0.15, 0.15), (0.15, -0.15))])


def _camera_pose(world: World, a: np.ndarray, b: np.ndarray, s_b: float, rng: np.random.Generator) -> np.ndarray:
    """T_world_cam_link (4,4): in the hidden branch 1.8-2.8 m beyond the walk's end ``s_b``, 1.0-1.5 m
    up, looking back at the middle of the walk ``a``-``b``."""
    origin, u, L, bw = world.hidden_axis
    nrm = np.array([-u[1], u[0]])
    s_cam = min(s_b + float(rng.uniform(1.8, 2.8)), L - 0.25)
    eye = np.r_[origin + u * s_cam + nrm * float(rng.uniform(-0.3, 0.3)) * bw, float(rng.uniform(1.0, 1.5))]
    target = np.r_[(a + b) / 2, 0.9]
    return look_at(eye, target)


def _clocks(rng: np.random.Generator) -> tuple[dict, dict]:
    """Per-sensor clock offsets and log latencies (ns): radar ±3 ms / 30-45 ms, LiDAR ±2 ms / 2-6 ms,
    camera ±8 ms / 20-40 ms, odometry 0 / 1 ms."""
    clock = {"radar": int(rng.integers(-3_000_000, 3_000_001)), "lidar": int(rng.integers(-2_000_000, 2_000_001)),
             "camera": int(rng.integers(-8_000_000, 8_000_001)), "odometry": 0}
    latency = {"radar": int(rng.integers(30_000_000, 45_000_001)), "lidar": int(rng.integers(2_000_000, 6_000_001)),
               "camera": int(rng.integers(20_000_000, 40_000_001)), "odometry": 1_000_000}
    return clock, latency


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
        self._rotations: dict = {}   # raw samples of the cycles radar_rotation still needs (_rotation_chirps)
        self.stereo = StereoModel(sc.camera_cfg, sc.T_world_cam_link @ T_LINK_OPTICAL,
                                  [m.lidar_reflectivity for m in w.materials], w.face_material,
                                  w.materials[MATERIAL_ID["human"]].lidar_reflectivity) if sc.stereo else None

    def _radar_paths(self, k: int, T_cols: np.ndarray | None = None) -> tuple[dict, np.ndarray, np.ndarray]:
        """The specular paths of cycle k's beams (:meth:`RadarModel.paths`) and the beams' world-frame
        origins and directions (H*W, 3): column j from the rotation centre at its time, its pose
        ``T_cols[j]`` (W,4,4) T_world_radar when given, else the true trajectory's at that time."""
        sc, cfg = self.sc, self.sc.radar_cfg
        g = cfg.grid
        start, end = sc.radar_cycle(k)
        if T_cols is None:
            t_cols = start + np.round((np.arange(g.W) + 0.5) / g.W * (end - start)).astype(np.int64)
            T_cols = sc.truth.interpolate(t_cols) @ sc.T_base_radar             # (W,4,4)
        D = np.einsum("wij,hwj->hwi", T_cols[:, :3, :3], g.directions()).reshape(-1, 3)
        O = np.broadcast_to(T_cols[None, :, :3, 3], (g.H, g.W, 3)).reshape(-1, 3)
        human = sc.dynamic_mesh((start + end) // 2)[0]
        tr = self.trace(O, D, human, cfg.max_bounces, cfg.range_bins.max_range)
        return self.radar.paths(tr, O, D), O, D

    def radar_frame(self, k: int, T_cols: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
        """(n_range, H, W) float32 heatmap of cycle k and per-frame stats (``T_cols``: see :meth:`_radar_paths`)."""
        paths, _, _ = self._radar_paths(k, T_cols)
        hm = self.radar.cube(paths, _rng(self.sc.seed, "radar", k))
        return hm, path_stats(paths)

    def radar_rotation(self, k: int) -> tuple[dict, dict]:
        """Raw samples of cycle k (``radar_output="iq"``) and per-frame stats: {chirps (nb+N+na, V, S)
        complex64, n_before, n_rotation, n_after, travel_per_chirp m, heading rad}. The rotation's N
        chirps (chirp n at ``start + (n + ½)/N`` of the cycle) come with the n_syn/2 chirps before and
        after it that its first and last beams need: the previous rotation's last chirps and the next
        one's first, the same samples in both messages, as a rig records each chirp once (cycles are
        contiguous, so those chirps' times coincide); before the first rotation and after the last they
        are synthesised from that rotation's own paths. The motion fields are the odometry's (what the
        robot knows): its displacement over the cycle, in the radar frame at the cycle start."""
        sc, cfg = self.sc, self.sc.radar_cfg
        N, pad = cfg.chirps_per_rotation, cfg.imaging()[1] // 2

        def rows(j, n0, n1):    # chirps n0 .. n1 - 1 of cycle j
            c, lo, _ = self._rotation_chirps(j)
            return c[n0 - lo:n1 - lo]

        stats = self._rotation_chirps(k)[2]
        before = rows(k, -pad, 0) if k == 0 else rows(k - 1, N - pad, N)
        after = rows(k, N, N + pad) if k == sc.frames - 1 else rows(k + 1, 0, pad)
        chirps = np.concatenate([before, rows(k, 0, N), after])
        for old in [j for j in self._rotations if j < k]:
            del self._rotations[old]
        start, end = sc.radar_cycle(k)
        a, b = sc.odom.interpolate(np.array([start, end])) @ sc.T_base_radar
        d = a[:3, :3].T @ (b[:3, 3] - a[:3, 3])
        return {"chirps": chirps, "n_before": pad, "n_rotation": N, "n_after": pad,
                "travel_per_chirp": float(np.hypot(d[0], d[1]) / N), "heading": float(np.arctan2(d[1], d[0]))}, stats

    def _rotation_chirps(self, k: int) -> tuple[np.ndarray, int, dict]:
        """(chirps, lo, stats): the raw samples of cycle k's own chirps ``lo`` .. N − 1 from its paths
        (``lo`` = −n_syn/2 for the first cycle, else 0; up to N − 1 + n_syn/2 for the last), and the
        paths' stats. Thermal noise is drawn for chirps −n_syn/2 .. N − 1 + n_syn/2 from the cycle's
        own stream and each chirp takes its own draw. Kept until :meth:`radar_rotation` has used them."""
        if k in self._rotations:
            return self._rotations[k]
        sc, cfg = self.sc, self.sc.radar_cfg
        paths, O, D = self._radar_paths(k)
        start, end = sc.radar_cycle(k)
        N, pad = cfg.chirps_per_rotation, cfg.imaging()[1] // 2
        lo, hi = (-pad if k == 0 else 0), (N + pad if k == sc.frames - 1 else N)
        n = np.arange(lo, hi)
        t = start + np.round((n + 0.5) / N * (end - start)).astype(np.int64)
        poses = sc.truth.interpolate(t) @ sc.T_base_radar
        chirps = self.radar.iq(paths, O, D, poses, n, None)
        if cfg.noise_amplitude > 0:
            chirps += self.radar.raw_noise(_rng(sc.seed, "radar", k), (N + 2 * pad,) + chirps.shape[1:])[lo + pad:hi + pad]
        self._rotations[k] = (chirps, lo, path_stats(paths))
        return self._rotations[k]

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


def drop_medians(frame_stats: list[dict]) -> dict:
    """Median LOS→NLOS drops (dB) over a recording's frames (:func:`path_stats` rows): ``los_nlos_drop_db``
    (every NLOS path) and ``los_nlos_human_drop_db`` (NLOS human paths); None where no frame has one."""
    out = {}
    for key in ("los_nlos_drop_db", "los_nlos_human_drop_db"):
        v = np.array([r[key] for r in frame_stats], float)
        out[key] = float(np.nanmedian(v)) if np.isfinite(v).any() else None
    return out


def attenuation_db(drops: dict) -> float | None:
    """A corner's attenuation (dB) for the paper's bands: the drop to the human when there is one (the
    bands are about the human), else to any NLOS path (``drops``: :func:`drop_medians`' keys)."""
    for key in ("los_nlos_human_drop_db", "los_nlos_drop_db"):
        v = drops.get(key)
        if v is not None and np.isfinite(float(v)):
            return float(v)
    return None


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
