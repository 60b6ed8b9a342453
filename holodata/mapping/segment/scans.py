"""A scene's organised LiDAR scans as the segmentation reads them (:class:`LidarScans`: range images
a shard at a time, points in the sensor and the world frame, de-skewed)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...conventions import transform_points
from ...dataset.layout import (
    LIDAR_POINT_TIME_NS,
    LIDAR_POINTS,
    LIDAR_RANGE,
    LIDAR_TIMESTAMP_NS,
    POSE_T_WORLD_LIDAR,
    TIME_TIMESTAMP_NS,
)
from ...errors import DatasetError, InputError


# ------------------------------------------------------------------------------------------ dataset
@dataclass
class LidarScans:
    """Organised LiDAR scans of a scene: ``range`` lazy (T,H,W) array; ``stamps`` (T,) int64 ns
    (0 = no scan); ``poses`` (T,4,4) T_world_lidar; ``has_time`` whether per-point times exist."""

    scene: object
    poses: np.ndarray
    stamps: np.ndarray
    shape: tuple
    has_time: bool
    # lidar/range handle and the block of frames of the last sequential read (range_frame)
    _range: object = field(default=None, init=False, repr=False, compare=False)
    _block: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _last: int = field(default=-2, init=False, repr=False, compare=False)

    @classmethod
    def open(cls, scene, url: str = "") -> LidarScans:
        names = set(scene.arrays())
        where = f"{url}: scene {scene.id!r}"
        if LIDAR_RANGE not in names or LIDAR_POINTS not in names:
            raise InputError(f"{where} has no organised LiDAR scans (lidar/range + lidar/points); the grid "
                             f"segmentation needs an Ouster-like organised cloud")
        if POSE_T_WORLD_LIDAR not in names:
            raise InputError(f"{where} has no pose/T_world_lidar (run holodata slam first)")
        poses = np.asarray(scene[POSE_T_WORLD_LIDAR][...], np.float64)
        rng = scene[LIDAR_RANGE]
        if LIDAR_TIMESTAMP_NS in names:
            stamps = np.asarray(scene[LIDAR_TIMESTAMP_NS][...], np.int64)
        else:
            stamps = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64)
        if poses.shape != (scene.n_frames, 4, 4) or rng.shape[0] != scene.n_frames:
            raise DatasetError(f"{where}: pose/T_world_lidar {poses.shape} / lidar/range {rng.shape} do not "
                               f"match {scene.n_frames} frames")
        return cls(scene, poses, stamps, tuple(rng.shape[1:]), LIDAR_POINT_TIME_NS in names)

    def usable(self, k: int) -> bool:
        return bool(self.stamps[k] != 0 and np.isfinite(self.poses[k]).all())

    def trajectory(self):
        from ...trajectory import Trajectory

        ok = np.array([self.usable(k) for k in range(len(self.stamps))])
        ts, ps = self.stamps[ok], self.poses[ok]
        order = np.argsort(ts, kind="stable")
        ts, ps = ts[order], ps[order]
        keep = np.concatenate([[True], np.diff(ts) > 0]) if len(ts) else np.zeros(0, bool)
        return Trajectory(ts[keep], ps[keep]) if keep.any() else None

    def range_frame(self, k: int) -> np.ndarray:
        """(H,W) float32 ``lidar/range`` of frame ``k``. Sequential reads (k, k+1, ...) load the rest of
        the zarr shard at once (one decompression per shard, not per frame); others read one frame."""
        if self._range is None:
            self._range = self.scene[LIDAR_RANGE]
        blk = self._block
        sequential, self._last = k == self._last + 1, k
        if blk is not None and blk[0] <= k < blk[1]:
            return blk[2][k - blk[0]]
        if not sequential:
            return np.asarray(self._range[k], np.float32)
        step = int((getattr(self._range, "shards", None) or self._range.chunks)[0])
        end = min((k // step + 1) * step, len(self.stamps))
        self._block = blk = (k, end, np.asarray(self._range[k:end], np.float32))
        return blk[2][0]

    def _returns(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(``lidar/range`` (H,W) float32, its finite pixels (H,W) bool, ``lidar/points`` (N,3) float64:
        one point per finite pixel in row-major order, checked) of frame ``k``."""
        r = self.range_frame(k)
        fin = np.isfinite(r)
        pts = np.asarray(self.scene.ragged(LIDAR_POINTS, k), np.float64)
        n_fin = int(fin.sum())
        if len(pts) != n_fin:
            raise DatasetError(f"scene {self.scene.id!r} frame {k}: lidar/points has {len(pts)} points for "
                               f"{n_fin} valid lidar/range pixels (expected the valid pixels in row-major order)")
        return r, fin, pts

    def scan(self, k: int, traj=None, deskew: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frame ``k``: (valid (H,W) bool, sensor points (H,W,3) float64, world points (H,W,3) float64,
        NaN where not valid). World points use per-point poses interpolated from ``traj`` at
        ``stamp + point_time`` when ``deskew`` and per-point times exist, else the scan pose
        (:meth:`deskew_points`)."""
        H, W = self.shape
        r, fin, pts = self._returns(k)
        valid = fin & (r > 0)
        P = np.zeros((H, W, 3))
        P[fin] = pts
        f = np.isfinite(P)
        valid &= f[..., 0] & f[..., 1] & f[..., 2]
        if not self.usable(k):
            return np.zeros((H, W), bool), P, np.full((H, W, 3), np.nan)
        tt = None
        if deskew and self.has_time and traj is not None and len(traj) > 1:
            t = np.asarray(self.scene.ragged(LIDAR_POINT_TIME_NS, k), np.int64).reshape(-1)
            tt = np.zeros((H, W), np.int64)
            if len(t) == len(pts):
                tt[fin] = t
        return valid, P, self.deskew_points(k, P, valid, tt, traj)

    def scan_world(self, k: int, traj=None, deskew: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``k``: (valid (H,W) bool, world points of the valid returns (N,3) float64 in row-major
        order) — ``valid`` and ``Pw[valid]`` of :meth:`scan`, the same values; a scan taken at rest is
        transformed as its list of returns, without the (H,W,3) grids."""
        H, W = self.shape
        r, fin, pts = self._returns(k)
        f = np.isfinite(pts)
        vf = (r[fin] > 0) & f[:, 0] & f[:, 1] & f[:, 2]     # scan(): valid = finite range > 0, finite point
        valid = np.zeros((H, W), bool)
        valid[fin] = vf
        if not self.usable(k) or not vf.any():
            return np.zeros((H, W), bool) if not self.usable(k) else valid, np.zeros((0, 3))
        tt = None
        if deskew and self.has_time and traj is not None and len(traj) > 1:
            t = np.asarray(self.scene.ragged(LIDAR_POINT_TIME_NS, k), np.int64).reshape(-1)
            tv = t[vf] if len(t) == len(pts) else np.zeros(int(vf.sum()), np.int64)
            s = int(self.stamps[k])
            if not _constant_pose(traj, s + min(int(tv.min()), 0), s + max(int(tv.max()), 0)):
                tt = np.zeros((H, W), np.int64)
                if len(t) == len(pts):
                    tt[fin] = t
        if tt is None:
            return valid, transform_points(self.poses[k], pts[vf])
        P = np.zeros((H, W, 3))
        P[fin] = pts
        return valid, self.deskew_points(k, P, valid, tt, traj)[valid]

    def deskew_points(self, k: int, P: np.ndarray, valid: np.ndarray, tt: np.ndarray | None, traj=None) -> np.ndarray:
        """(H,W,3) world points (NaN where not ``valid``) of scan ``k``'s sensor points ``P`` (H,W,3) m
        with per-point times ``tt`` (H,W) int64 ns after the scan stamp: point i goes through
        ``poses[k] @ inv(traj(stamp)) @ traj(stamp + tt_i)`` (``traj`` interpolated, SLERP). ``tt`` or
        ``traj`` None: the scan pose for every point. Shortcuts with the same result up to rounding
        (~1e-15 m): one transform when ``traj`` holds the same pose over the whole time span of the scan
        (the robot at rest: most scans of a recording that stands), one pose per column when the
        returns of a column share one time (the Ouster layout; no per-point gather), else one pose per
        distinct time."""
        H, W = valid.shape
        if not valid.any():
            return np.full((H, W, 3), np.nan)
        s = int(self.stamps[k])
        tv = tt[valid] if tt is not None else None
        if tv is None or traj is None or len(traj) < 2 or _constant_pose(traj, s + min(int(tv.min()), 0),
                                                                          s + max(int(tv.max()), 0)):
            Pw = transform_points(self.poses[k], P)        # the whole grid: cheaper than gathering
            Pw[~valid] = np.nan
            return Pw
        Pw = np.full((H, W, 3), np.nan)
        T0 = self.poses[k] @ np.linalg.inv(traj.interpolate(np.array([s]))[0])
        tcol = np.where(valid, tt, np.iinfo(np.int64).min).max(0)
        if (tt == tcol[None, :])[valid].all():
            has = np.flatnonzero(valid.any(0))
            Ts = T0 @ traj.interpolate(tcol[has] + s)                     # (C,4,4): one pose per column
            Pw[:, has] = transform_points(Ts[None], P[:, has])
            Pw[~valid] = np.nan
            return Pw
        ut, inv = np.unique(tv + s, return_inverse=True)                # one pose per distinct time
        Ts = T0 @ traj.interpolate(ut)
        Pw[valid] = np.einsum("nij,nj->ni", Ts[inv, :3, :3], P[valid]) + Ts[inv, :3, 3]
        return Pw


def _constant_pose(traj, t0: int, t1: int) -> bool:
    """True when trajectory ``traj`` interpolates one and the same pose over [t0, t1] (ns): every
    pose from the last one at or before ``t0`` to the first one at or after ``t1`` is identical
    (clamped at the ends, as :meth:`Trajectory.interpolate` is)."""
    ts = traj.timestamp_ns
    i0 = max(int(np.searchsorted(ts, t0, "right")) - 1, 0)
    i1 = min(int(np.searchsorted(ts, t1, "left")), len(ts) - 1)
    seg = traj.poses[i0:max(i1, i0) + 1]
    return bool((seg == seg[0]).all())
