"""The data pass written as a recording: the message schedule (every sensor's messages in log-time
order) and :func:`write_recording` (the bag plus ``truth/``); clocks and streams as in
:mod:`holodata.synth.scene`."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..conventions import yaw_rad
from ..progress import track
from . import truth as truthio
from .camera import T_LINK_OPTICAL
from .lidar import ouster_metadata
from .radar import encode_heatmap
from .result import SynthResult
from .scene import (
    CAMERA_START_S,
    FRAME_BASE,
    FRAME_CAM_LINK,
    FRAME_MAP,
    FRAME_ODOM,
    FRAME_RADAR,
    FRAME_RIGHT_OPT,
    LIDAR_START_S,
    Scenario,
    Sensors,
    _trans,
    counting_put,
    drop_medians,
)
from .topics import RAW_TOPIC, STEREO_TOPICS, TOPICS
from .worlds import CLASS_ID


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


def write_recording(sc: Scenario, out_dir: Path, fmt: str, quiet: bool = False) -> SynthResult:
    """Write the data pass of ``sc`` into ``out_dir``: the recording (format ``fmt``, every message of
    :func:`_schedule` in log-time order) and ``truth/`` (mesh, trajectories, human meshes, frames,
    extrinsics, ``scene.json``); ``truth/`` must not exist yet."""
    dp = _DataPass(sc, Path(out_dir), fmt)
    dp.write_bag(quiet)
    dp.write_truth()
    return dp.result()


def _data_topics(sc: Scenario) -> dict:
    """{topic: message type} of the data pass: ``TOPICS`` (plus ``STEREO_TOPICS`` with stereo), the
    heatmap topic replaced by the raw one for ``radar_output="iq"``."""
    from ..messages import RADAR_RAW_TYPE as RAW_TYPE

    topics = dict(TOPICS, **(STEREO_TOPICS if sc.stereo else {}))
    if sc.radar_output == "iq":
        topics = {(RAW_TOPIC if t == "/radar/heatmap" else t): (RAW_TYPE if t == "/radar/heatmap" else v)
                  for t, v in topics.items()}
    return topics


class _DataPass:
    """One data pass being written: the sensor models of ``sc``, the recording's path and topics, and
    what the messages leave for ``truth/`` (per radar frame its row and true pose, per LiDAR scan its
    true pose and with visible walkers its instance image, hits on the hidden person)."""

    def __init__(self, sc: Scenario, out_dir: Path, fmt: str):
        from .recording import recording_path

        self.sc, self.out_dir, self.fmt = sc, out_dir, fmt
        self.sensors = Sensors(sc)
        self.truth_dir = out_dir / "truth"
        self.truth_dir.mkdir(parents=True, exist_ok=False)
        self.human_dir = self.truth_dir / "human" if sc.walk is not None else None
        if self.human_dir is not None:
            self.human_dir.mkdir()
        self.rec = recording_path(out_dir, fmt)
        self.topics = _data_topics(sc)
        self.counts = {t: 0 for t in self.topics}
        self.frame_rows: list[dict] = []
        self.radar_tum: list[tuple[int, np.ndarray]] = []   # (header stamp, T_world_radar) per radar frame
        self.lidar_tum: list[tuple[int, np.ndarray]] = []   # (header stamp, T_world_lidar) per scan
        self.lidar_human_hits, self.camera_human_pixels = 0, 0
        self.inst_rows: list[tuple[int, np.ndarray]] = []  # (header stamp, instance image) per scan, with walkers
        self.storage = Path()
        self.stats: dict = {}
        self.scene_path = self.truth_dir / "scene.json"

    # ------------------------------------------------------------------ the recording
    def write_bag(self, quiet: bool) -> None:
        """Every scheduled message into the recording, in log-time order."""
        from .recording import BagWriter

        events = _schedule(self.sc)
        handlers = {"static": self._static, "metadata": self._metadata, "odom": self._odom, "radar": self._radar,
                    "lidar": self._lidar, "camera": self._camera}
        with BagWriter(self.rec, self.fmt) as bw:
            self.bw = bw
            self.put = counting_put(bw, self.topics, self.counts)
            for log_ns, _, kind, idx, t_ns in track(events, len(events), "synth", quiet):
                handlers[kind](log_ns, idx, t_ns)
            self.storage = Path(bw.storage_file)

    def _static(self, log_ns: int, _idx: int, t_ns: int) -> None:
        sc, bw, cam_cfg = self.sc, self.bw, self.sc.camera_cfg
        tfs = [bw.transform("/tf_static", t_ns, FRAME_MAP, FRAME_ODOM, sc.T_map_odom),
               bw.transform("/tf_static", t_ns, FRAME_BASE, FRAME_RADAR, sc.T_base_radar),
               bw.transform("/tf_static", t_ns, FRAME_BASE, sc.lidar_cfg.frame_id, sc.T_base_lidar),
               bw.transform("/tf_static", t_ns, FRAME_MAP, FRAME_CAM_LINK, sc.T_world_cam_link),
               bw.transform("/tf_static", t_ns, FRAME_CAM_LINK, cam_cfg.cloud_frame_id, np.eye(4)),
               bw.transform("/tf_static", t_ns, FRAME_CAM_LINK, cam_cfg.frame_id, T_LINK_OPTICAL)]
        if sc.stereo:
            T_right = _trans(0.0, -cam_cfg.baseline_m, 0.0) @ T_LINK_OPTICAL
            tfs.append(bw.transform("/tf_static", t_ns, FRAME_CAM_LINK, FRAME_RIGHT_OPT, T_right))
        self.put("/tf_static", log_ns, bw.tf_message(tfs))

    def _metadata(self, log_ns: int, _idx: int, _t_ns: int) -> None:
        sc = self.sc
        md = ouster_metadata(sc.lidar_cfg, sc.lidar_alt, sc.lidar_az, f"SYN{sc.seed:09d}")
        self.put("/ouster/metadata", log_ns, self.bw.string(json.dumps(md, sort_keys=True)))

    def _odom(self, log_ns: int, idx: int, t_ns: int) -> None:
        bw, T = self.bw, self.sc.odom.poses[idx]
        self.put("/tf", log_ns, bw.tf_message([bw.transform("/tf", t_ns, FRAME_ODOM, FRAME_BASE, T)]))
        self.put("/odom", log_ns, _odometry_msg(bw, self.sc, idx, t_ns))

    def _radar(self, log_ns: int, idx: int, _t_ns: int) -> None:
        """Radar frame ``idx`` (a heatmap, or raw samples with ``radar_output="iq"``) stamped mid-cycle
        in the radar's clock, and its truth: true pose, the human's mesh and centre, the path stats."""
        sc = self.sc
        s, e = sc.radar_cycle(idx)
        off = sc.clock_offset_ns["radar"]
        stamp = (s + e) // 2 + off
        st = self._radar_message(log_ns, idx, stamp)
        mid = (s + e) // 2
        self.radar_tum.append((stamp, sc.truth.interpolate(np.array([mid]))[0] @ sc.T_base_radar))
        hc = sc.walk.center_at(float(sc.t_s(mid))) if sc.walk is not None else np.full(3, np.nan)
        if self.human_dir is not None:
            hv, hf = sc.human_mesh(mid)
            truthio.write_mesh(self.human_dir / f"{idx:06d}.ply", hv, hf, np.full(len(hf), CLASS_ID["human"], np.uint8),
                               {CLASS_ID["human"]: "human"})
        self.frame_rows.append({"frame": idx, "stamp_ns": stamp, "cycle_start_ns": s + off, "cycle_end_ns": e + off,
                                "true_mid_ns": mid, "human_x": hc[0], "human_y": hc[1], "human_z": hc[2],
                                "los_nlos_drop_db": st["los_nlos_drop_db"],
                                "los_nlos_human_drop_db": st["los_nlos_human_drop_db"]})

    def _radar_message(self, log_ns: int, idx: int, stamp: int) -> dict:
        """Write radar frame ``idx``'s message; returns its path stats."""
        from .recording import RawRotation

        sc, bw, rcfg = self.sc, self.bw, self.sc.radar_cfg
        s, e = sc.radar_cycle(idx)
        off = sc.clock_offset_ns["radar"]
        if sc.radar_output == "iq":
            r, st = self.sensors.radar_rotation(idx)
            rot = RawRotation(r["chirps"], r["n_before"], r["n_rotation"], r["n_after"], s + off, e + off,
                              r["travel_per_chirp"], r["heading"])
            self.put(RAW_TOPIC, log_ns, bw.radar_raw_rotation(RAW_TOPIC, stamp, FRAME_RADAR, rot, rcfg.imaging()[0]))
        else:
            hm, st = self.sensors.radar_frame(idx)
            msg = bw.radar_heatmap("/radar/heatmap", stamp, FRAME_RADAR, encode_heatmap(hm, rcfg.encoding),
                                   hm.shape, rcfg, s + off, e + off)
            self.put("/radar/heatmap", log_ns, msg)
        return st

    def _lidar(self, log_ns: int, idx: int, t_ns: int) -> None:
        sc = self.sc
        pts, st = self.sensors.lidar_scan(idx, t_ns)
        self.lidar_human_hits += st["human_hits"]
        stamp = t_ns + sc.clock_offset_ns["lidar"]
        if "instance" in st:
            self.inst_rows.append((stamp, st["instance"]))
        self.put("/ouster/points", log_ns, self.bw.point_cloud("/ouster/points", stamp, sc.lidar_cfg.frame_id, pts))
        self.lidar_tum.append((stamp, sc.truth.interpolate(np.array([t_ns]))[0] @ sc.T_base_lidar))

    def _camera(self, log_ns: int, idx: int, t_ns: int) -> None:
        """Camera frame ``idx``: depth image, its CameraInfo and xyz cloud (and the stereo pair)."""
        bw, cam_cfg = self.bw, self.sc.camera_cfg
        depth, st = self.sensors.camera_frame(idx, t_ns)
        self.camera_human_pixels += st["human_pixels"]
        stamp = t_ns + self.sc.clock_offset_ns["camera"]
        self.put("/zed2i/zed_node/depth/depth_registered", log_ns,
                 bw.image_32fc1("/zed2i/zed_node/depth/depth_registered", stamp, cam_cfg.frame_id, depth))
        self.put("/zed2i/zed_node/depth/camera_info", log_ns,
                 bw.camera_info("/zed2i/zed_node/depth/camera_info", stamp, cam_cfg.frame_id, cam_cfg))
        cloud = self.sensors.camera.cloud(depth)
        xyz = np.zeros(cloud.shape[:2], np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3,
                                                  "offsets": [0, 4, 8], "itemsize": 12}))
        xyz["x"], xyz["y"], xyz["z"] = cloud[..., 0], cloud[..., 1], cloud[..., 2]
        self.put("/zed2i/zed_node/point_cloud/cloud_registered", log_ns,
                 bw.point_cloud("/zed2i/zed_node/point_cloud/cloud_registered", stamp, cam_cfg.cloud_frame_id, xyz))
        if self.sc.stereo:
            self._stereo(log_ns, idx, t_ns, stamp)

    def _stereo(self, log_ns: int, idx: int, t_ns: int, stamp: int) -> None:
        bw, cam_cfg = self.bw, self.sc.camera_cfg
        left, right = self.sensors.stereo_pair(idx, t_ns)
        for side, img, frame, tx in (("left", left, cam_cfg.frame_id, 0.0),
                                     ("right", right, FRAME_RIGHT_OPT, -cam_cfg.fx * cam_cfg.baseline_m)):
            self.put(f"/zed2i/zed_node/{side}/image_rect_gray", log_ns,
                     bw.image_mono8(f"/zed2i/zed_node/{side}/image_rect_gray", stamp, frame, img))
            self.put(f"/zed2i/zed_node/{side}/camera_info", log_ns,
                     bw.camera_info(f"/zed2i/zed_node/{side}/camera_info", stamp, frame, cam_cfg, tx))

    # ------------------------------------------------------------------ truth/
    def write_truth(self) -> None:
        """``truth/``: the files the messages left (:meth:`_write_truth_files`), then ``scene.json``."""
        self._write_truth_files()
        self.stats = self._stats()
        truthio.write_json(self.scene_path, self._scene())

    def _write_truth_files(self) -> None:
        sc, truth_dir, w = self.sc, self.truth_dir, self.sc.world
        truthio.write_mesh(truth_dir / "mesh.ply", w.vertices, w.faces, w.face_class, w.class_names)
        np.save(truth_dir / "mesh_face_material.npy", w.face_material)
        tb = np.arange(sc.truth.timestamp_ns[0], sc.truth.timestamp_ns[-1] + 1, 10_000_000, dtype=np.int64)
        truthio.write_trajectory(truth_dir / "trajectory_base.tum", tb, sc.truth.interpolate(tb))
        truthio.write_trajectory(truth_dir / "trajectory_radar.tum", [r[0] for r in self.radar_tum],
                                 np.stack([r[1] for r in self.radar_tum]))
        if self.lidar_tum:
            truthio.write_trajectory(truth_dir / "trajectory_lidar.tum", [r[0] for r in self.lidar_tum],
                                     np.stack([r[1] for r in self.lidar_tum]))
        truthio.write_trajectory(truth_dir / "odometry.tum", sc.odom.timestamp_ns, sc.odom.poses)
        truthio.write_frames_csv(truth_dir / "radar_frames.csv", self.frame_rows)
        if sc.walkers:
            truthio.write_lidar_instances(truth_dir / "lidar_instances.npz", self.inst_rows, len(sc.walkers),
                                          sc.walk is not None)
        truthio.write_json(truth_dir / "extrinsics.json", _extrinsics(sc))

    def _stats(self) -> dict:
        """Returns on the hidden person (LiDAR points, camera pixels), median LOS→NLOS drops (dB) and
        the paper's attenuation band of the drop to the person (< 10 dB low, 10-20 medium, > 20 high)."""
        stats = {
            "lidar_human_hits": self.lidar_human_hits,
            "camera_human_pixels": self.camera_human_pixels,
            **drop_medians(self.frame_rows),
        }
        d = stats["los_nlos_human_drop_db"]
        stats["attenuation_band"] = None if d is None else ("low" if d < 10 else "medium" if d <= 20 else "high")
        return stats

    def _scene(self) -> dict:
        """``truth/scene.json``: the world, the recording's configuration, counts and stats."""
        sc, rcfg = self.sc, self.sc.radar_cfg
        scene = sc.world.describe()
        scene.update({
            "holodata_synth_version": 1,
            "seed": sc.seed, "frames": sc.frames, "format": self.fmt, "t0_ns": sc.t0_ns, "duration_s": sc.duration_s,
            "human": None if sc.walk is None else {"height_m": sc.walk.height, "speed_mps": sc.walk.speed,
                                                   "a": sc.walk.a, "b": sc.walk.b, "phase0": sc.walk.phase0},
            "robot": sc.truth_info, "odometry": sc.odom_info,
            "radar": rcfg.describe(), "lidar": sc.lidar_cfg.describe(), "camera": sc.camera_cfg.describe(),
            "lidar_beam_altitude_deg": sc.lidar_alt, "lidar_beam_azimuth_deg": sc.lidar_az,
            "clock_offset_ns": sc.clock_offset_ns, "latency_ns": sc.latency_ns,
            "topics": self.topics, "counts": self.counts, "stats": self.stats,
            "recording": str(self.rec.relative_to(self.out_dir)),
            "storage_file": str(self.storage.relative_to(self.out_dir)),
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
            scale, noise = self.sensors.radar.raw_scale()
            scene["radar_output"] = {"kind": "iq", "topic": RAW_TOPIC, "chirp": chirp.to_attrs(), "n_syn": n_syn,
                                     "chirps_around_rotation": n_syn // 2, "amplitude_scale": scale,
                                     "noise_std_per_sample": noise,
                                     "scatterers": "every specular path at its image source (beam origin + range x "
                                                   "first direction), amplitude |a| x amplitude_scale"}
        if sc.walkers:
            scene["visible_walkers"] = [{"a": w.a, "b": w.b, "speed_mps": w.speed, "height_m": w.height,
                                         "phase0": w.phase0, "instance": i + 1} for i, w in enumerate(sc.walkers)]
        return scene

    def result(self) -> SynthResult:
        sc, w, truth_dir = self.sc, self.sc.world, self.truth_dir
        return SynthResult(out_dir=self.out_dir, recording=self.rec, storage_file=self.storage, format=self.fmt,
                           truth_dir=truth_dir, scene_json=self.scene_path, mesh=truth_dir / "mesh.ply",
                           trajectory_radar=truth_dir / "trajectory_radar.tum",
                           trajectory_base=truth_dir / "trajectory_base.tum", human_dir=self.human_dir,
                           n_frames=sc.frames, corner=w.corner, width_m=w.width, seed=sc.seed, human=sc.walk is not None,
                           topics=self.topics, counts=self.counts, stats=self.stats)


def _extrinsics(sc: Scenario) -> dict:
    """``truth/extrinsics.json``: the true mounts and camera pose (4×4) and the frames' names."""
    cam_cfg = sc.camera_cfg
    return {
        "T_base_radar": sc.T_base_radar, "T_base_lidar": sc.T_base_lidar,
        "T_world_camera_link": sc.T_world_cam_link, "T_world_camera_optical": sc.T_world_cam_link @ T_LINK_OPTICAL,
        "T_camera_link_optical": T_LINK_OPTICAL, "T_map_odom": sc.T_map_odom,
        "frames": {"world": FRAME_MAP, "odom": FRAME_ODOM, "base": FRAME_BASE, "radar": FRAME_RADAR,
                   "lidar": sc.lidar_cfg.frame_id, "camera_link": FRAME_CAM_LINK,
                   "camera_optical": cam_cfg.frame_id, "camera_cloud": cam_cfg.cloud_frame_id},
    }


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
