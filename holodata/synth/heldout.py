"""Held-out recordings for ``slam`` and ``register``: a scene family nothing was tuned on.

slam and register were tuned on the demo and benchmark corners (:mod:`holodata.synth.scenario`:
radar + LiDAR + ZED-like camera, the robot stopping short of the junction, exact TF camera pose).
This family differs where real recordings do:

* **LiDAR only** (no radar), an Ouster-like organised ``PointCloud2`` (ouster_ros point layout) on
  ``/ouster/points`` in ``os_sensor``; any beam count and vertical field of view;
* the robot drives **through** an L corridor (into the hidden leg), furniture along both legs;
* a **standard TF tree**: ``map → odom`` static, ``odom → base_link`` at 50 Hz from odometry that
  drifts ``odom_scale`` of the distance, ``base_link → os_sensor`` static; the TF stream starts
  ``tf_late_s`` after the LiDAR (drivers start at different times);
* a world-fixed **RealSense-like depth camera** facing the corner from the hidden side
  (``camera="hidden"``: the far end of the hidden leg looking back) or from the robot's side
  (``camera="robot"``: the junction's far corner looking up the hidden leg), recorded as a 16UC1
  depth image + CameraInfo (``camera_output="depth16"``) or as an organised ``PointCloud2`` in the
  optical frame with NaN for no return, CameraInfo beside it (``"cloud"``); its pose in TF
  (``map → camera_link``) is **hand-measured**: ``guess_cm`` / ``guess_deg`` off the truth;
* a walking person, human-shaped (:func:`holodata.synth.human.human_mesh`) or a box
  (``person="box"``), in the camera's view.

A second family (``corner="T"``, ``camera="wall"``, ``walk="across"``) differs from
both the tuned corners and the one above in corner kind, camera mounting and the person's motion: a
**T junction**; the robot drives up the approach corridor, stops ``stop_short_m`` before the junction
and waits ``dwell_s``; the camera is **wall-mounted high** (2.2-2.5 m, below the ceiling) over the
approach corridor, 1.2-2.0 m before the junction, pitched down across it; the person walks **along the
T's bar, across the camera's view** (from one branch through the junction into the other), so the
corridor's corners hide them at each end of the walk (partial views) and they cross the robot's view.
Its random draws beyond the first family's come from a stream of their own, so the first family's
recordings are unchanged.

Truth (``truth/``): ``extrinsics.json`` (``T_world_camera_optical`` true, ``T_map_camera_link_tf``
the guess), ``trajectory_lidar.tum`` (true T_world_lidar at each scan's header stamp),
``human/<k:06d>.ply`` (the person at scan k's stamp: frame k of a LiDAR-framed scene),
``lidar_instances.npz`` (:func:`holodata.synth.truth.write_lidar_instances`: per scan, the returns
that hit the person, instance 1; the person is posed at the middle of the sweep, as the scan saw it),
``mesh.ply``, ``scene.json`` (the configuration and derived parameters). The world frame is
``map``, the true world.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..progress import track
from ..trajectory import Trajectory
from . import truth as truthio
from .camera import T_LINK_OPTICAL, CameraConfig, CameraModel, look_at
from .human import HumanWalk
from .lidar import LidarConfig, LidarModel, beam_angles
from .motion import DriveProfile, odometry, path_trajectory
from .worlds import CLASS_ID, MATERIAL_ID, World, box_mesh, make_world

TOPICS_DEPTH = {"/camera/depth/image_rect_raw": "sensor_msgs/msg/Image",
                "/camera/depth/camera_info": "sensor_msgs/msg/CameraInfo"}
TOPICS_CLOUD = {"/camera/depth/color/points": "sensor_msgs/msg/PointCloud2",
                "/camera/depth/camera_info": "sensor_msgs/msg/CameraInfo"}
TOPICS_BASE = {"/ouster/points": "sensor_msgs/msg/PointCloud2", "/tf": "tf2_msgs/msg/TFMessage",
               "/tf_static": "tf2_msgs/msg/TFMessage", "/odom": "nav_msgs/msg/Odometry"}
FRAME_CAM_LINK, FRAME_CAM_OPT = "camera_link", "camera_depth_optical_frame"
TF_HZ = 50.0


@dataclass(frozen=True)
class HeldOutConfig:
    """One held-out recording (see the module docstring). Lengths m, angles deg, times s."""

    seed: int = 0
    corner: str = "L"                   # "L" | "T" (the T: walk="across", camera="wall")
    width: float | None = None          # approach corridor width (None: drawn by make_world)
    lidar_rows: int = 64
    lidar_cols: int = 512
    lidar_fov_deg: float = 45.0
    lidar_hz: float = 10.0
    camera: str = "hidden"              # "hidden" | "robot" | "wall" (high over the approach corridor)
    camera_output: str = "depth16"      # "depth16" | "cloud"
    camera_shape: tuple = (240, 320)    # (h, w); hfov 87 deg (D435-like)
    camera_hz: float = 15.0
    depth_noise: float = 1.0            # x the D435-like disparity noise (0.08 px at 848 px, 50 mm)
    person: str = "human"               # "human" | "box"
    furniture: int = 4                  # boxes / shelves along the walls
    guess_cm: float = 7.8
    guess_deg: float = 2.7
    odom_scale: float = 0.01
    tf_late_s: float = 0.3
    start_back_m: float | None = None   # robot start this far behind the junction (None: the corridor's end)
    into_hidden_m: float = 1.8          # ... driving this far up the hidden leg
    speed_mps: float = 0.6
    walk: str = "hidden"                # "hidden": up and down the hidden leg; "across": along the T's bar
    stop_short_m: float | None = None   # the robot stops this far before the junction (None: drives through)
    dwell_s: float = 5.0                # ... and waits this long there

    def check(self) -> None:
        if self.corner not in ("L", "T"):
            raise InputError(f"corner must be 'L' or 'T', got {self.corner!r}")
        if self.camera not in ("hidden", "robot", "wall"):
            raise InputError(f"camera must be 'hidden', 'robot' or 'wall', got {self.camera!r}")
        if self.walk not in ("hidden", "across"):
            raise InputError(f"walk must be 'hidden' or 'across', got {self.walk!r}")
        if self.walk == "across" and self.corner != "T":
            raise InputError("walk='across' walks along a T junction's bar: it needs corner='T'")
        if self.camera_output not in ("depth16", "cloud"):
            raise InputError(f"camera_output must be 'depth16' or 'cloud', got {self.camera_output!r}")
        if self.person not in ("human", "box"):
            raise InputError(f"person must be 'human' or 'box', got {self.person!r}")


def _perturbation(rng: np.random.Generator, cm: float, deg: float) -> np.ndarray:
    """A rigid motion of exactly ``cm`` and ``deg`` about random axes."""
    from scipy.spatial.transform import Rotation

    a, t = rng.normal(size=3), rng.normal(size=3)
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(np.deg2rad(deg) * a / np.linalg.norm(a)).as_matrix()
    D[:3, 3] = cm / 100.0 * t / np.linalg.norm(t)
    return D


def _furnished(world: World, n: int, rng: np.random.Generator) -> tuple[World, list]:
    """``world`` with ``n`` boxes (tables, shelves, cabinets) against the walls of both legs, leaving
    0.6 m either side of the corridor axes free for the robot and the person."""
    V, F, M, C = [world.vertices], [world.faces.astype(np.int64)], [world.face_material], [world.face_class]
    nv = len(world.vertices)
    sgn = -1.0 if world.mirrored else 1.0
    hw = world.width / 2
    origin, u, L, bw = world.hidden_axis
    nrm = np.array([-u[1], u[0]])
    out = []
    for k in range(n):
        sz = rng.uniform([0.4, 0.3, 0.5], [1.4, 0.6, 1.9])
        if k % 2 == 0:     # approach leg, behind the junction
            side = 1.0 if rng.random() < 0.5 else -1.0
            depth = min(sz[1], hw - 0.6)
            if depth < 0.15:
                continue
            x = float(rng.uniform(-6.0, -0.8 - sz[0] / 2))
            c = np.array([x, sgn * side * (hw - depth / 2 - 0.02)])
            yaw = 0.0
        else:              # hidden leg
            side = 1.0 if rng.random() < 0.5 else -1.0
            depth = min(sz[1], bw / 2 - 0.6)
            if depth < 0.15:
                continue
            s = float(rng.uniform(0.8 + sz[0] / 2, max(1.0 + sz[0] / 2, L - 2.5)))
            c = origin + u * s + nrm * side * (bw / 2 - depth / 2 - 0.02)
            yaw = float(np.arctan2(u[1], u[0]))
        v, f = box_mesh([c[0], c[1], sz[2] / 2], [sz[0], depth, sz[2]], yaw)
        V.append(v)
        F.append(f + nv)
        nv += len(v)
        M.append(np.full(len(f), MATERIAL_ID["wood" if rng.random() < 0.6 else "metal"], np.uint8))
        C.append(np.full(len(f), CLASS_ID["box"], np.uint8))
        out.append({"center": np.round(c, 3).tolist(), "size": np.round([sz[0], depth, sz[2]], 3).tolist()})
    return replace(world, vertices=np.concatenate(V), faces=np.concatenate(F).astype(np.int32),
                   face_material=np.concatenate(M), face_class=np.concatenate(C)), out


class _BoxPerson:
    """A 0.45 x 0.3 m box of ``height`` walking like :class:`HumanWalk` (a person a depth camera sees
    as a slab: no limbs, flat faces)."""

    def __init__(self, walk: HumanWalk):
        self.walk = walk

    def mesh_at(self, t_s: float):
        pos, head, _ = self.walk.state(t_s)
        return box_mesh([pos[0], pos[1], self.walk.height / 2], [0.3, 0.45, self.walk.height], head)


def synthesize_heldout(out_dir: str | Path, cfg: HeldOutConfig = HeldOutConfig(), fmt: str = "mcap",
                       quiet: bool = True) -> Path:
    """Write one held-out recording (module docstring) under ``out_dir`` (``recording/`` + ``truth/``);
    returns the recording's path."""
    from .recording import recording_path

    cfg.check()
    out_dir = Path(out_dir)
    truth_dir = out_dir / "truth"
    (truth_dir / "human").mkdir(parents=True, exist_ok=False)
    scene = _HeldOutScene.build(cfg)
    rec = recording_path(out_dir, fmt)
    bag = _HeldOutBag(scene, cfg, truth_dir)
    bag.write(rec, fmt, quiet)
    _write_truth(scene, cfg, truth_dir, bag)
    (out_dir / "README.txt").write_text("holodata held-out recording (holodata.synth.heldout); truth/ is the answer key\n"
                                        + json.dumps({"seed": cfg.seed, "camera": cfg.camera,
                                                      "camera_output": cfg.camera_output}) + "\n")
    return rec


@dataclass(frozen=True)
class _HeldOutScene:
    """Everything about one held-out recording but the sensor data: the furnished world (and its
    furniture's description), the robot's true trajectory and drifting odometry (with their
    parameters), ``T_map_odom`` and the LiDAR mount ``T_base_lidar`` (4×4), the person's walk (and
    what the sensors see walking it: the walk or a box), the camera's eye and target (3,) m, its true
    pose and the hand-measured guess in TF (4×4), and the sensors' configurations and LiDAR beam
    angles (deg)."""

    world: World
    furniture: list
    truth: Trajectory        # T_world_base (true time)
    truth_info: dict
    odom: Trajectory         # T_odom_base
    odom_info: dict
    T_map_odom: np.ndarray
    T_base_lidar: np.ndarray
    walk: HumanWalk
    height: float
    person: HumanWalk | _BoxPerson   # what the sensors see walking the walk
    eye: np.ndarray
    target: np.ndarray
    T_world_link: np.ndarray
    T_guess_link: np.ndarray
    cam_cfg: CameraConfig
    lidar_cfg: LidarConfig
    lidar_alt: np.ndarray
    lidar_az: np.ndarray

    @property
    def T_world_opt(self) -> np.ndarray:
        return self.T_world_link @ T_LINK_OPTICAL

    @classmethod
    def build(cls, cfg: HeldOutConfig) -> _HeldOutScene:
        """The scene of ``cfg``: the first family's draws from the stream (seed, 23), in this order
        (furniture, trajectory, odometry, LiDAR mount, person, camera, TF guess, LiDAR beams); the
        second family's from (seed, 43)."""
        rng = np.random.default_rng([int(cfg.seed), 23])
        world, furniture = _furnished(make_world(cfg.corner, cfg.width, cfg.seed), cfg.furniture, rng)
        rng2 = np.random.default_rng([int(cfg.seed), 43])   # the second family's own draws (module docstring)
        path, t_end = _route(world, cfg)
        t0 = (1_700_000_000 + int(cfg.seed) * 3600) * 1_000_000_000
        truth, tinfo = path_trajectory(path, t0, rng, DriveProfile(speed=cfg.speed_mps, t_start=0.6, t_end=t_end))
        odom, oinfo = odometry(truth, rng, rate_hz=TF_HZ, scale_error=float(rng.choice([-1, 1])) * cfg.odom_scale,
                               yaw_bias_dps=float(rng.uniform(-0.1, 0.1)))
        T_map_odom = truth.interpolate(np.array([odom.timestamp_ns[0]]))[0]
        T_base_lidar = np.eye(4)
        T_base_lidar[:3, 3] = [float(rng.uniform(-0.1, 0.1)), 0.0, float(rng.uniform(0.45, 0.9))]
        walk, height = _walk(world, cfg, rng, rng2)
        eye, target = _camera_eye(world, cfg, rng, rng2)
        T_world_link = look_at(eye, target)
        T_guess_link = T_world_link @ _perturbation(rng, cfg.guess_cm, cfg.guess_deg)
        lidar_cfg = LidarConfig(rows=cfg.lidar_rows, cols=cfg.lidar_cols, rate_hz=cfg.lidar_hz,
                                vertical_fov_deg=cfg.lidar_fov_deg)
        alt, az = beam_angles(lidar_cfg, rng)
        person = walk if cfg.person == "human" else _BoxPerson(walk)
        return cls(world, furniture, truth, tinfo, odom, oinfo, T_map_odom, T_base_lidar, walk, height, person, eye,
                   target, T_world_link, T_guess_link, _camera_config(cfg), lidar_cfg, alt, az)


def _route(world: World, cfg: HeldOutConfig) -> tuple[np.ndarray, float]:
    """The robot's waypoints (K,2) m and its rest at the end (s): from ``start_back_m`` behind the
    junction (at most 1 m short of the corridor's end) through it and ``into_hidden_m`` up the hidden
    leg, or with ``stop_short_m`` up the approach corridor, then waiting ``dwell_s`` short of the junction."""
    sgn = -1.0 if world.mirrored else 1.0
    hw, w2 = world.width / 2, world.hidden_width
    la = -float(world.floor_polygon[:, 0].min())
    back = min(la - 1.0, cfg.start_back_m if cfg.start_back_m is not None else la - 1.0)
    path = np.array([[-back, 0.0], [w2 / 2, 0.0], [w2 / 2, sgn * (hw + cfg.into_hidden_m)]])
    t_end = 0.6
    if cfg.stop_short_m is not None:      # up the approach corridor, then waiting short of the junction
        path, t_end = np.array([[-back, 0.0], [-min(float(cfg.stop_short_m), back - 0.5), 0.0]]), float(cfg.dwell_s)
    return path, t_end


def _walk(world: World, cfg: HeldOutConfig, rng: np.random.Generator, rng2: np.random.Generator) -> tuple[HumanWalk, float]:
    """The person's walk and height (m): up and down the hidden leg, in the camera's view, or with
    ``walk="across"`` along the T's bar (from the other branch, through the junction, up this one)."""
    sgn = -1.0 if world.mirrored else 1.0
    hw, w2 = world.width / 2, world.hidden_width
    origin, u, L, bw = world.hidden_axis
    nrm = np.array([-u[1], u[0]])
    height = float(rng.uniform(1.55, 1.95))
    lat = float(rng.uniform(-1, 1)) * max(0.0, bw / 2 - 0.7)
    s_a = float(rng.uniform(cfg.into_hidden_m + 1.0, cfg.into_hidden_m + 1.6))
    s_b = min(s_a + float(rng.uniform(1.5, 2.5)), L - 1.6)
    walk = HumanWalk(origin + u * s_a + nrm * lat, origin + u * max(s_b, s_a + 0.5) + nrm * lat,
                     float(rng.uniform(0.5, 1.1)), height, float(rng.uniform(0, 1)))
    if cfg.walk == "across":   # along the T's bar: from the other branch, through the junction, up this one
        x = w2 / 2 + min(0.25 * w2, 0.3) * float(rng2.uniform(0.0, 1.0))
        ya, yb = -(hw + float(rng2.uniform(1.2, 2.0))), hw + float(rng2.uniform(1.2, 2.0))
        walk = HumanWalk(np.array([x, sgn * ya]), np.array([x, sgn * yb]), walk.speed, height, walk.phase0)
    return walk, height


def _camera_eye(world: World, cfg: HeldOutConfig, rng: np.random.Generator,
                rng2: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The depth camera's eye and target (3,) m for ``cfg.camera``: "hidden" at the far end of the
    hidden leg looking back, "robot" at the junction's far corner looking up the hidden leg, "wall"
    high over the approach corridor, pitched down across the junction (its draws after "robot"'s)."""
    sgn = -1.0 if world.mirrored else 1.0
    hw, w2 = world.width / 2, world.hidden_width
    origin, u, L, bw = world.hidden_axis
    nrm = np.array([-u[1], u[0]])
    if cfg.camera == "hidden":
        eye = np.r_[origin + u * (L - 0.3) + nrm * float(rng.uniform(-0.25, 0.25)) * bw, float(rng.uniform(1.0, 1.6))]
        target = np.r_[origin, 0.8]
    else:
        eye = np.r_[w2 - 0.25, sgn * (-hw + 0.25), float(rng.uniform(1.2, 1.8))]
        target = np.r_[origin + u * (0.5 * L), 0.7]
    if cfg.camera == "wall":   # high over the approach corridor, pitched down across the junction
        eye = np.r_[-float(rng2.uniform(1.2, 2.0)), float(rng2.uniform(-0.3, 0.3)) * hw,
                    min(float(rng2.uniform(2.2, 2.5)), world.height - 0.15)]
        target = np.r_[0.55 * w2, 0.0, 0.9]
    return eye, target


def _camera_config(cfg: HeldOutConfig) -> CameraConfig:
    """A RealSense-D435-like depth camera of ``cfg.camera_shape``: 87° horizontal field of view, depth
    noise ``cfg.depth_noise`` × 0.08 px of disparity (scaled from 430 px focal length), 0.3-10 m."""
    h, w = int(cfg.camera_shape[0]), int(cfg.camera_shape[1])
    fx = 0.5 * w / np.tan(np.deg2rad(87.0) / 2)
    return CameraConfig(w, h, fx, fx, (w - 1) / 2, (h - 1) / 2, 0.05, cfg.camera_hz,
                        0.08 * fx / 430.0 * cfg.depth_noise, 0.3, 10.0, 0.02, FRAME_CAM_OPT, FRAME_CAM_LINK)


class _HeldOutBag:
    """The held-out recording's messages: LiDAR scans (stamp = scan start), camera frames, TF from
    ``tf_late_s`` on; what the scans leave for ``truth/`` (true LiDAR poses, the person's returns and
    meshes)."""

    def __init__(self, sc: _HeldOutScene, cfg: HeldOutConfig, truth_dir: Path):
        from ..raytrace import RayScene

        w = sc.world
        self.sc, self.cfg, self.truth_dir = sc, cfg, truth_dir
        self.scene = RayScene(w.vertices, w.faces, face_class=w.face_class, class_names=w.class_names)
        self.lidar = LidarModel(sc.lidar_cfg, sc.lidar_alt, sc.lidar_az, w.face_material, w.face_class, w.materials,
                                MATERIAL_ID["human"], CLASS_ID["ceiling"])
        self.camera = CameraModel(sc.cam_cfg, sc.T_world_opt)
        self.t_first, self.t_last = int(sc.truth.timestamp_ns[0]), int(sc.truth.timestamp_ns[-1])
        self.period = int(1e9 / cfg.lidar_hz)
        self.scans = np.arange(self.t_first, self.t_last - self.period, self.period, dtype=np.int64)
        self.cams = np.arange(self.t_first + int(0.013e9), self.t_last, int(1e9 / cfg.camera_hz), dtype=np.int64)
        self.lidar_tum: list[np.ndarray] = []            # true T_world_lidar per scan
        self.inst_rows: list[tuple[int, np.ndarray]] = []   # (scan stamp, (rows, cols) person mask) per scan

    def t_s(self, t) -> float:
        return (int(t) - self.t_first) / 1e9

    def events(self) -> list[tuple[int, int, str, int]]:
        """(log_ns, priority, kind, index), sorted: static TF and odometry TF from ``tf_late_s`` on, scans
        logged 3 ms after they end, camera frames 25 ms after their stamp."""
        tf_from = self.t_first + int(self.cfg.tf_late_s * 1e9)
        events = ([(tf_from, 0, "static", 0)]
                  + [(int(t), 1, "odom", i) for i, t in enumerate(self.sc.odom.timestamp_ns) if t >= tf_from]
                  + [(int(t + self.period + 3_000_000), 2, "lidar", i) for i, t in enumerate(self.scans)]
                  + [(int(t + 25_000_000), 3, "camera", i) for i, t in enumerate(self.cams)])
        events.sort()
        return events

    def write(self, rec: Path, fmt: str, quiet: bool) -> None:
        from .recording import BagWriter

        events = self.events()
        topics = dict(TOPICS_BASE, **(TOPICS_DEPTH if self.cfg.camera_output == "depth16" else TOPICS_CLOUD))
        handlers = {"static": self._static, "odom": self._odom, "lidar": self._lidar, "camera": self._camera}
        with BagWriter(rec, fmt) as bw_:
            self.bw = bw_
            for topic, typ in topics.items():
                bw_.add(topic, typ, latched=topic == "/tf_static")
            for log_ns, _, kind, i in track(events, len(events), "heldout", quiet):
                handlers[kind](log_ns, i)

    def _static(self, log_ns: int, _i: int) -> None:
        sc, bw_ = self.sc, self.bw
        tfs = [bw_.transform("/tf_static", log_ns, "map", "odom", sc.T_map_odom),
               bw_.transform("/tf_static", log_ns, "base_link", sc.lidar_cfg.frame_id, sc.T_base_lidar),
               bw_.transform("/tf_static", log_ns, "map", FRAME_CAM_LINK, sc.T_guess_link),
               bw_.transform("/tf_static", log_ns, FRAME_CAM_LINK, FRAME_CAM_OPT, T_LINK_OPTICAL)]
        bw_.write("/tf_static", log_ns, bw_.tf_message(tfs))

    def _odom(self, log_ns: int, i: int) -> None:
        bw_, odom = self.bw, self.sc.odom
        t = int(odom.timestamp_ns[i])
        bw_.write("/tf", log_ns, bw_.tf_message([bw_.transform("/tf", t, "odom", "base_link", odom.poses[i])]))

    def _lidar(self, log_ns: int, i: int) -> None:
        """Scan ``i`` (the person posed at the middle of the sweep) and its truth: the returns on the
        person, the true LiDAR pose and the person's mesh at the scan's stamp."""
        sc, bw_ = self.sc, self.bw
        t = int(self.scans[i])
        T_cols = sc.truth.interpolate(t + self.lidar.column_times_ns()) @ sc.T_base_lidar
        mid = t + self.period // 2
        hm = sc.person.mesh_at(self.t_s(mid))
        # face_instance only labels the returns (stats["instance"]); the scan itself is unchanged
        pts, st = self.lidar.scan(self.scene, T_cols, hm, np.random.default_rng([self.cfg.seed, 1, i]),
                                  face_instance=np.ones(len(hm[1]), np.uint16))
        self.inst_rows.append((t, st["instance"]))
        bw_.write("/ouster/points", log_ns, bw_.point_cloud("/ouster/points", t, sc.lidar_cfg.frame_id, pts))
        self.lidar_tum.append(sc.truth.interpolate(np.array([t]))[0] @ sc.T_base_lidar)
        hv, hf = sc.person.mesh_at(self.t_s(t))
        truthio.write_mesh(self.truth_dir / "human" / f"{i:06d}.ply", hv, hf,
                           np.full(len(hf), CLASS_ID["human"], np.uint8), {CLASS_ID["human"]: "human"})

    def _camera(self, log_ns: int, i: int) -> None:
        """Camera frame ``i``: a 16UC1 depth image or an organised cloud (optical frame, NaN for no
        return), its CameraInfo after it."""
        sc, bw_, cam_cfg = self.sc, self.bw, self.sc.cam_cfg
        t = int(self.cams[i])
        depth, _ = self.camera.frame(self.scene, sc.person.mesh_at(self.t_s(t)), np.random.default_rng([self.cfg.seed, 2, i]))
        info = bw_.camera_info("/camera/depth/camera_info", t, FRAME_CAM_OPT, cam_cfg)
        if self.cfg.camera_output == "depth16":
            bw_.write("/camera/depth/image_rect_raw", log_ns,
                      bw_.image_16uc1("/camera/depth/image_rect_raw", t, FRAME_CAM_OPT, depth))
        else:
            p = self.camera.rays * depth[..., None]      # optical frame, NaN for no return
            xyz = np.zeros((cam_cfg.height, cam_cfg.width), np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3,
                                                                      "offsets": [0, 4, 8], "itemsize": 16}))
            xyz["x"], xyz["y"], xyz["z"] = p[..., 0], p[..., 1], p[..., 2]
            bw_.write("/camera/depth/color/points", log_ns,
                      bw_.point_cloud("/camera/depth/color/points", t, FRAME_CAM_OPT, xyz))
        bw_.write("/camera/depth/camera_info", log_ns, info)


def _write_truth(sc: _HeldOutScene, cfg: HeldOutConfig, truth_dir: Path, bag: _HeldOutBag) -> None:
    """``truth/`` beside the person's meshes (module docstring): the mesh, trajectories, the person's
    LiDAR returns, extrinsics (true and the TF guess) and ``scene.json``."""
    world = sc.world
    truthio.write_mesh(truth_dir / "mesh.ply", world.vertices, world.faces, world.face_class, world.class_names)
    truthio.write_trajectory(truth_dir / "trajectory_lidar.tum", bag.scans, np.stack(bag.lidar_tum))
    truthio.write_lidar_instances(truth_dir / "lidar_instances.npz", bag.inst_rows, 1, False)
    tb = np.arange(bag.t_first, bag.t_last + 1, 10_000_000, dtype=np.int64)
    truthio.write_trajectory(truth_dir / "trajectory_base.tum", tb, sc.truth.interpolate(tb))
    truthio.write_json(truth_dir / "extrinsics.json", {
        "T_world_camera_link": sc.T_world_link, "T_world_camera_optical": sc.T_world_opt,
        "T_map_camera_link_tf": sc.T_guess_link, "T_base_lidar": sc.T_base_lidar, "T_map_odom": sc.T_map_odom,
        "frames": {"world": "map", "odom": "odom", "base": "base_link", "lidar": sc.lidar_cfg.frame_id,
                   "camera_link": FRAME_CAM_LINK, "camera_optical": FRAME_CAM_OPT}})
    truthio.write_json(truth_dir / "scene.json", {
        "family": "heldout", "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "world": world.describe(), "furniture": sc.furniture, "trajectory": sc.truth_info, "odometry": sc.odom_info,
        "human": {"speed_mps": sc.walk.speed, "height_m": sc.height, "a": sc.walk.a, "b": sc.walk.b, "kind": cfg.person},
        "camera": {"eye": sc.eye, "target": sc.target, "K": sc.cam_cfg.K(), "shape": [sc.cam_cfg.height, sc.cam_cfg.width]},
        "lidar": sc.lidar_cfg.describe(), "scans": len(bag.scans), "camera_frames": len(bag.cams)})
