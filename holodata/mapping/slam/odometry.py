"""kiss-icp odometry over the scans (:func:`kiss_odometry`, :class:`KissStream`) and the SE(3)
helpers for deskewing (:func:`twist`, :func:`deskew`)."""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from ...conventions import transform_points
from ...geometry.voxels import first_per_voxel
from ...progress import track
from .config import Scans, SlamConfig

# kiss-icp settings holodata fixes (kiss-icp's are for cars at speed): its own default map density,
# and an adaptive threshold that starts at 0.5 m (kiss-icp: 2 m) and counts motion from 2 cm
# (kiss-icp: 0.1 m), for a slow indoor robot
KISS_POINTS_PER_VOXEL = 20
KISS_INITIAL_THRESHOLD_M = 0.5
KISS_MIN_MOTION_M = 0.02


class KissStream:
    """kiss-icp 1.3 odometry fed scan by scan on demand (see :func:`kiss_odometry` for the settings):
    :meth:`pose` registers scan ``i``; :meth:`hold` skips it (robot at rest: kiss-icp is not fed, its
    pose repeats). ``poses`` (S,4,4) (first = identity, LiDAR frame) and ``ref`` (S,) reference stamps
    (scan stamp + the scan's last point time when deskewing, kiss-icp's reference) fill as it goes."""

    def __init__(self, scans: Scans, cfg: SlamConfig, max_range: float):
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        kc = KISSConfig()
        kc.data.max_range = float(max_range)
        kc.data.min_range = float(cfg.min_range)
        self.use_t = cfg.deskew and scans.times is not None
        kc.data.deskew = bool(self.use_t)
        kc.mapping.voxel_size = float(cfg.voxel)
        kc.mapping.max_points_per_voxel = KISS_POINTS_PER_VOXEL
        kc.adaptive_threshold.initial_threshold = KISS_INITIAL_THRESHOLD_M
        kc.adaptive_threshold.min_motion_th = KISS_MIN_MOTION_M
        kc.registration.convergence_criterion = float(cfg.kiss_convergence)
        kc.registration.max_num_iterations = int(cfg.kiss_max_iterations)
        self.odo = KissICP(config=kc)
        self.scans, self.cfg = scans, cfg
        self.poses = np.zeros((len(scans), 4, 4))
        self.ref = scans.stamp_ns.copy()
        self.fed = 0
        self.seconds = 0.0

    def pose(self, i: int) -> np.ndarray:
        t0 = time.perf_counter()
        sc, cfg = self.scans, self.cfg
        p = sc.points[i]
        sel = first_per_voxel(p, cfg.kiss_input_voxel) if cfg.kiss_input_voxel > 0 else slice(None)
        p = np.ascontiguousarray(p[sel], np.float64)
        if self.use_t:
            t = np.ascontiguousarray(sc.times[i][sel], np.float64)
            self.odo.register_frame(p, t)
            if np.ptp(t) > 0:
                self.ref[i] = sc.stamp_ns[i] + int(round(float(t.max()) * 1e9))
        else:
            self.odo.register_frame(p, np.zeros(len(p)))
        self.poses[i] = self.odo.last_pose
        self.fed += 1
        self.seconds += time.perf_counter() - t0
        return self.poses[i]

    def hold(self, i: int) -> np.ndarray:
        self.poses[i] = self.poses[i - 1]
        self.ref[i] = self.ref[i - 1] + (self.scans.stamp_ns[i] - self.scans.stamp_ns[i - 1])
        return self.poses[i]


class _Fixed:
    """Given initial poses in the :class:`KissStream` interface (every scan "fed"). ``seed``: they are
    odometry (TF) poses at the scan stamps, whose motion about each scan also deskews it in
    :func:`refine` (a throttled scan rate makes the last refined step a poor guess of it in turns)."""

    def __init__(self, poses: np.ndarray, seed: bool = False):
        self.seed = seed
        self.poses = poses
        self.fed = len(poses)
        self.seconds = 0.0

    def pose(self, i: int) -> np.ndarray:
        return self.poses[i]

    hold = pose


def kiss_odometry(scans: Scans, cfg: SlamConfig, max_range: float, quiet: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Bare kiss-icp odometry on every scan: (S,4,4) poses (first = identity, lidar frame) and their
    reference stamps (S,) ns (scan stamp + the scan's last point time when deskewing, kiss-icp's
    reference). Indoor settings: voxel ``cfg.voxel``, max range from the data, the scan downsampled
    to ``cfg.kiss_input_voxel``, ICP convergence ``cfg.kiss_convergence``."""
    ks = KissStream(scans, cfg, max_range)
    for i in track(range(len(scans)), total=len(scans), description="slam: kiss-icp", quiet=quiet):
        ks.pose(i)
    return ks.poses, ks.ref


# ----------------------------------------------------------------------------------------------
# SE(3) helpers

def twist(Ta: np.ndarray, Tb: np.ndarray, dt: float) -> np.ndarray:
    """Body twist per second (6,) [ω, v] taking pose ``Ta`` to ``Tb`` in ``dt`` s (first order)."""
    if dt <= 0:
        return np.zeros(6)
    D = np.linalg.inv(Ta) @ Tb
    return np.r_[Rotation.from_matrix(D[:3, :3]).as_rotvec(), D[:3, 3]] / dt


def advance(xi: np.ndarray, dt: float) -> np.ndarray:
    """(4,4) pose at ``dt`` s relative to the reference of a sensor moving with body twist ``xi`` [ω, v]
    per second, in the reference frame: ``[R(dt·ω), dt·v]``, the model :func:`deskew` maps points with
    (a point seen at time ``dt`` lies at ``advance(xi, dt) @ p`` in the reference frame)."""
    A = np.eye(4)
    if dt != 0:
        A[:3, :3] = Rotation.from_rotvec(np.asarray(xi[:3], np.float64) * dt).as_matrix()
        A[:3, 3] = np.asarray(xi[3:], np.float64) * dt
    return A


def deskew(points: np.ndarray, times: np.ndarray | None, xi: np.ndarray) -> np.ndarray:
    """Points (N,3) taken at ``times`` (N,) s relative to the reference, sensor moving with body twist
    ``xi`` [ω, v] per second → the same points in the sensor frame at the reference time:
    ``R(t)·p + t·v``, ``R(t)`` the rotation by ``t·|ω|`` about ω/|ω| (Rodrigues, per point). Returns
    ``points`` unchanged when all times are equal or the twist turns less than 1e-12 rad and moves
    less than 1 nm over the scan (the rounding noise of the twist between two equal held poses)."""
    if times is None or len(points) == 0 or np.ptp(times) == 0:
        return points
    t = np.asarray(times, np.float64)
    span = float(np.abs(t).max())
    w = float(np.linalg.norm(xi[:3]))
    if w * span < 1e-12 and float(np.linalg.norm(xi[3:])) * span < 1e-9:
        return points
    p = np.asarray(points, np.float64)
    out = p + t[:, None] * xi[None, 3:]
    if w > 0:
        k = xi[:3] / w
        c, s = np.cos(t * w), np.sin(t * w)
        K = np.zeros((4, 4))
        K[:3, :3] = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]]  # K @ p = k × p
        # (transform_points, not p @ K.T: that product goes to OpenBLAS threads, slow for one scan; slam.md)
        out += transform_points(K, p) * s[:, None] + ((p @ k) * (1.0 - c))[:, None] * k[None, :] - p * (1.0 - c)[:, None]
    return out
