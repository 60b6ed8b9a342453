"""Raw trajectory folders in PanoRadar's layout (``panoradar_SP/dataset.py``; FIELD-NOTES §"Raw radar"),
written from simulated raw FMCW samples — small stand-ins for the 1.3 TB public release, for the
reader's tests and the README's example.

Layout written by :func:`write_trajectory` (what :mod:`holodata.readers.panoradar_raw` reads)::

    radar_data.npy    (chirp frames, n_tx, n_rx, samples) complex64, int16 scale (x 32768)
    radar_ts.txt      one stamp per chirp frame, seconds
    lidar_data.npy    (frames, rows, columns, 3) float32 xyz, LiDAR frame
    lidar_ts.txt      one stamp per LiDAR frame, seconds
    imu_data.npy      (samples,) float64 yaw rate, deg/s   + imu_ts.txt
    data_params.npz   radar_sep, lidar_sep, imu_sep (first index of every rotation), r_radar,
                      transform (2x2: xy_radar = xy_lidar @ transform)
    motion_output.npz (moving trajectories, optional) v_esti, theta_v_esti, delta_s0_esti per rotation

:func:`box_room_trajectory` simulates one (:class:`BoxRoomRun`: how it records): a radar on a
platform moving at constant velocity through a rectangular room holding point reflectors (the radar
sees the reflectors; the LiDAR sees the walls).
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..radar.chirp import ChirpConfig
from ..radar.simulate import RigEffects, simulate_chirps

INT16_SCALE = 32768.0   # PanoRadar divides the stored samples by this


@dataclass(frozen=True)
class SensorStream:
    """One sensor's samples in a trajectory folder: ``data`` (frames first), ``ts`` one stamp per
    frame (s) and ``sep`` the first frame index of every rotation (PanoRadar's ``*_sep``)."""

    data: np.ndarray
    ts: np.ndarray
    sep: np.ndarray


def write_trajectory(folder, radar: SensorStream, *, chirp: ChirpConfig, lidar: SensorStream | None = None,
                     imu: SensorStream | None = None, transform=None, motion: dict | None = None) -> Path:
    """Write one trajectory folder; returns its path. ``radar.data``: (C, n_virtual, S) complex samples
    (unit scale; stored x 32768 as PanoRadar's int16-scaled values, as (C, n_tx, n_rx, S)); ``lidar.data``
    (frames, rows, columns, 3) xyz; ``imu.data`` (samples,) yaw rate deg/s; stamps in seconds.
    Written into ``folder.partial`` and renamed, so a folder that exists is complete."""
    folder = Path(folder)
    tmp = folder.with_name(folder.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    C, V, S = radar.data.shape
    np.save(tmp / "radar_data.npy",
            (np.asarray(radar.data, np.complex64) * np.float32(INT16_SCALE)).reshape(C, chirp.n_tx, chirp.n_rx, S))
    np.savetxt(tmp / "radar_ts.txt", np.asarray(radar.ts, np.float64), fmt="%.9f")
    params = {"radar_sep": np.asarray(radar.sep, np.int64), "r_radar": np.float64(chirp.rotation_radius_m),
              "transform": np.eye(2) if transform is None else np.asarray(transform, np.float64)}
    if lidar is not None:
        np.save(tmp / "lidar_data.npy", np.asarray(lidar.data, np.float32))
        np.savetxt(tmp / "lidar_ts.txt", np.asarray(lidar.ts, np.float64), fmt="%.9f")
        params["lidar_sep"] = np.asarray(lidar.sep, np.int64)
    if imu is not None:
        np.save(tmp / "imu_data.npy", np.asarray(imu.data, np.float64))
        np.savetxt(tmp / "imu_ts.txt", np.asarray(imu.ts, np.float64), fmt="%.9f")
        params["imu_sep"] = np.asarray(imu.sep, np.int64)
    np.savez(tmp / "data_params.npz", **params)
    if motion is not None:
        np.savez(tmp / "motion_output.npz", **{k: np.asarray(v, np.float64) for k, v in motion.items()})
    if folder.exists():
        shutil.rmtree(folder)
    os.replace(tmp, folder)
    return folder


@dataclass(frozen=True)
class BoxRoom:
    """An axis-aligned room around the platform's start (metres, radar frame at chirp 0: x forward,
    z up, z = 0 the radar's vertical phase reference) with point reflectors of amplitude 1."""

    x: tuple = (-3.0, 5.0)
    y: tuple = (-2.5, 3.0)
    z: tuple = (-0.8, 1.6)
    reflectors: tuple = ((3.0, 0.6, 0.0), (-1.5, -1.2, 0.3), (1.0, 2.2, -0.2))
    lidar_shape: tuple = (16, 256)
    lidar_fov_deg: float = 45.0


def _lidar_scan(room: BoxRoom, centre: np.ndarray, rot_lidar: np.ndarray) -> np.ndarray:
    """(rows, cols, 3) float32: the room's walls seen from ``centre`` (radar frame), in the LiDAR frame."""
    H, W = room.lidar_shape
    el = np.deg2rad(np.linspace(room.lidar_fov_deg / 2, -room.lidar_fov_deg / 2, H))
    az = -2 * np.pi * np.arange(W) / W
    d = np.stack(np.broadcast_arrays(np.cos(el)[:, None] * np.cos(az)[None], np.cos(el)[:, None] * np.sin(az)[None],
                                     np.sin(el)[:, None]), -1).reshape(-1, 3)          # LiDAR frame
    d_r = d @ rot_lidar.T                                                                 # radar frame
    t = np.full(len(d), np.inf)
    for axis, (lo, hi) in enumerate((room.x, room.y, room.z)):
        for wall in (lo, hi):
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (wall - centre[axis]) / d_r[:, axis]
            t = np.where((s > 0) & (s < t), s, t)
    return (d * t[:, None]).reshape(H, W, 3).astype(np.float32)


@dataclass
class Trajectory:
    """What :func:`box_room_trajectory` simulated (for tests: the truth to compare with)."""

    folder: Path
    chirp: ChirpConfig
    n_rotations: int
    velocity: tuple
    room: BoxRoom
    pad: int
    extras: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BoxRoomRun:
    """How :func:`box_room_trajectory` records: ``n_rotations`` rotations while the platform moves at
    ``velocity`` (vx, vy) m/s from chirp 0 on (no yaw); ``pad`` chirps (None: half a 90° window) before
    the first rotation and after the last, as a moving recording's beams need; the LiDAR yawed
    ``lidar_yaw_deg`` from the radar frame (``transform`` then rotates it back), scanning at
    ``lidar_hz``; complex noise of std ``noise_std`` and a direct leakage of amplitude ``leakage`` per
    sample (unit-scale samples); ``motion_file``: a moving trajectory gets ``motion_output.npz`` (true
    velocity); ``seed`` the noise's; ``t0_s`` the first rotation's start stamp (s)."""

    n_rotations: int = 3
    velocity: tuple = (0.0, 0.0)
    pad: int | None = None
    lidar_yaw_deg: float = 0.0
    lidar_hz: float = 10.0
    noise_std: float = 1e-3
    leakage: float = 0.05
    motion_file: bool = True
    seed: int = 0
    t0_s: float = 1000.0


def box_room_trajectory(folder, run: BoxRoomRun = BoxRoomRun(), *, chirp: ChirpConfig | None = None,
                        room: BoxRoom | None = None) -> Trajectory:
    """Simulate and write a PanoRadar raw trajectory of ``run`` (:class:`BoxRoomRun`) through ``room``.

    "static" in the name of the folder or of its parent (the building folder, PanoRadar's rule) marks
    a robot at rest (:func:`holodata.readers.panoradar_raw.motion_rule`).
    """
    chirp = chirp or ChirpConfig()
    room = room or BoxRoom()
    N = chirp.chirps_per_rotation
    pad = N // 8 + 1 if run.pad is None else run.pad
    idx = np.arange(-pad, run.n_rotations * N + pad)
    T = chirp.chirp_period_s
    rng = np.random.default_rng(run.seed)
    leak = run.leakage * np.exp(-np.arange(chirp.n_samples) / 4.0)[None, :].repeat(chirp.n_virtual, 0)
    radar = simulate_chirps(np.asarray(room.reflectors, float), chirp=chirp, chirp_index=idx, n_chirps=N,
                            velocity=run.velocity, effects=RigEffects(noise_std=run.noise_std, leakage=leak, rng=rng))
    radar_ts = run.t0_s + idx * T
    radar_sep = pad + N * np.arange(run.n_rotations + 1)
    yaw = np.deg2rad(run.lidar_yaw_deg)
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])  # lidar -> radar
    n_lidar = int(np.floor((radar_ts[-1] - radar_ts[0]) * run.lidar_hz)) + 1
    lidar_ts = radar_ts[0] + np.arange(n_lidar) / run.lidar_hz
    v3 = np.array([run.velocity[0], run.velocity[1], 0.0])
    lidar = np.stack([_lidar_scan(room, (t - run.t0_s) * v3, rot) for t in lidar_ts])
    sep_ts = run.t0_s + (radar_sep - pad) * T          # rotation starts (the last one may lie past the data)
    lidar_sep = np.searchsorted(lidar_ts, sep_ts)
    imu_ts = radar_ts[0] + np.arange(int((radar_ts[-1] - radar_ts[0]) * 100) + 1) / 100.0
    imu_sep = np.searchsorted(imu_ts, sep_ts)
    out = write_trajectory(folder, SensorStream(radar, radar_ts, radar_sep), chirp=chirp,
                           lidar=SensorStream(lidar, lidar_ts, lidar_sep),
                           imu=SensorStream(np.zeros(len(imu_ts)), imu_ts, imu_sep),
                           transform=rot[:2, :2].T, motion=_motion_output(run, T))
    return Trajectory(out, chirp, run.n_rotations, tuple(run.velocity), room, pad)


def _motion_output(run: BoxRoomRun, chirp_period_s: float) -> dict | None:
    """``motion_output.npz``'s true motion per rotation (speed m/s, direction rad, travel per chirp m);
    None at rest or without ``run.motion_file``."""
    speed = float(np.hypot(*run.velocity))
    if speed > 0 and run.motion_file:
        return {"v_esti": np.full(run.n_rotations, speed),
                "theta_v_esti": np.full(run.n_rotations, np.arctan2(run.velocity[1], run.velocity[0])),
                "delta_s0_esti": np.full(run.n_rotations, speed * chirp_period_s)}
    return None


def write_raw_bag(folder, out, fmt: str = "mcap", topic: str = "/radar/raw", chirp_config: bool = True) -> Path:
    """Copy the rotations of a PanoRadar raw trajectory ``folder`` into a ROS bag of
    ``holodata_msgs/msg/RadarRawRotation`` messages (:mod:`holodata.messages`; definition embedded),
    one per rotation with its neighbouring chirps and recorded motion, plus ``/tf_static``
    (``base_link → radar``); ``fmt`` "mcap" | "rosbag2" | "rosbag1". ``chirp_config=False`` leaves the
    chirp fields zero (a bag that lacks its chirp configuration, for the error path's test).
    Returns the recording's path."""
    from ..readers.panoradar_raw import PanoRadarRawRecording
    from .recording import BagWriter, RawRotation, recording_path

    rec = PanoRadarRawRecording(Path(folder))
    path = recording_path(Path(out).parent, fmt, Path(out).name)
    if path.exists():
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    with BagWriter(path, fmt) as w:
        w.add("/tf_static", "tf2_msgs/msg/TFMessage", latched=True)
        w.add(topic, "holodata_msgs/msg/RadarRawRotation")
        t0 = int(rec.radar_ts[0] * 1e9)
        w.write("/tf_static", t0, w.tf_message([w.transform("/tf_static", t0, "base_link", "radar", np.eye(4))]))
        chirp = rec.chirp if chirp_config else _zero_chirp(rec.chirp)
        for k in rec.rotations:
            rot, before, after = rec.rotation_iq(k)
            parts = [p for p in (before, rot, after) if p is not None]
            c0, c1 = rec._rot_stamps(k)
            ds0, th = ((float(rec.motion["ds0"][k]), float(rec.motion["theta_v"][k])) if rec.motion is not None
                       else (0.0, 0.0))
            rotation = RawRotation(np.concatenate(parts, axis=0), 0 if before is None else len(before), len(rot),
                                   0 if after is None else len(after), c0, c1, ds0, th)
            msg = w.radar_raw_rotation(topic, (c0 + c1) // 2, "radar", rotation, chirp)
            w.write(topic, (c0 + c1) // 2, msg)
    return path


def _zero_chirp(chirp: ChirpConfig):
    """A stand-in with the chirp fields zeroed (what a recorder that forgot them writes)."""
    from types import SimpleNamespace

    return SimpleNamespace(start_frequency_hz=0.0, slope_hz_per_s=0.0, sample_rate_hz=0.0, n_samples=chirp.n_samples,
                           n_tx=chirp.n_tx, n_rx=chirp.n_rx, antenna_spacing_m=0.0, rotation_radius_m=0.0)
