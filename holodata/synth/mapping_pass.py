"""The mapping pass: the robot's drive through the empty corner before the data pass
(:func:`mapping_legs`, :func:`build_mapping_pass`) written as its own recording
(:func:`write_mapping_recording`)."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..progress import track
from ..trajectory import Trajectory
from . import truth as truthio
from .data_pass import _odometry_msg
from .lidar import ouster_metadata
from .motion import DriveProfile, odometry, path_trajectory
from .scene import (
    FRAME_BASE,
    FRAME_MAP,
    FRAME_ODOM,
    LIDAR_START_S,
    ODOM_HZ,
    Scenario,
    Sensors,
    _rng,
    counting_put,
)
from .topics import MAPPING_TOPICS
from .worlds import World

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

    truth: Trajectory
    odom: Trajectory
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
    angles, and the radar's bounces reach them (docs/design/synth.md). From
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
    drive = DriveProfile(speed=speed, turn_radius=radius, max_yaw_rate=MAPPING_YAW_RATE_RPS)
    _, info = path_trajectory(None, 0, np.random.default_rng(0), drive, legs=legs)  # its duration
    t0 = sc.t0_ns - int(round((info["duration_s"] + MAPPING_GAP_S) * 1e9))
    truth, info = path_trajectory(None, t0, rng, drive, legs=legs)
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
        put = counting_put(bw, topics, counts)
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
