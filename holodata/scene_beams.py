"""Per-frame beam geometry and ground truth in the radar frame of that frame (below both the learned
stages and evaluate, which read it).

Every consumer of range images — evaluate's un-mirroring, the learned stage two, the oracle —
reads the beams from here, so all of them start each beam where the ground truth was traced from
(the scene's ``gt.origin_model``, :mod:`holodata.beams`) and look along the direction it had at
its column's time, expressed in the radar frame of the frame's pose ``pose/T_world_radar[k]``.
GT points and normals (world frame in the dataset) are moved into that same frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holodata.beams import OriginModel, column_poses, frame_beams, gt_origin_model, scene_origin_model
from holodata.conventions import Grid
from holodata.dataset.layout import GT_NORMAL, GT_POINT, POSE_T_WORLD_RADAR, RADAR_CYCLE_NS, TIME_TIMESTAMP_NS
from holodata.trajectory import Trajectory


@dataclass
class FrameGeometry:
    """One frame, radar frame of ``pose``: ``origins``/``directions`` (H,W,3) float64 per beam;
    ``gt_point``/``gt_normal`` (B,H,W,3) float64 (NaN = none) or None where the scene lacks them;
    ``pose`` (4,4) T_world_radar."""

    origins: np.ndarray
    directions: np.ndarray
    pose: np.ndarray
    gt_point: np.ndarray | None = None
    gt_normal: np.ndarray | None = None

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """(…,3) radar-frame points of this frame to the world frame."""
        return points @ self.pose[:3, :3].T + self.pose[:3, 3]


class SceneBeams:
    """Beam geometry of the frames of one dataset scene (poses, times and rotation cycles read
    once). ``grid``: the dataset's full beam grid; ``origin``: the beam-origin model (default: the
    one the scene's GT was traced with, else the recording's, else the default of docs/format.md §2; a scene
    without frame times has no column times, so one pose per frame)."""

    def __init__(self, scene, grid: Grid, origin: OriginModel | None = None):
        attrs = dict(scene.attrs)
        names = set(scene.arrays())
        self.scene, self.grid = scene, grid
        self.origin = origin or gt_origin_model(attrs) or scene_origin_model(attrs)[0]
        if TIME_TIMESTAMP_NS not in names and self.origin.column_time:
            self.origin = OriginModel(self.origin.rotation_radius, False, self.origin.rotation_hz)
        T = scene.n_frames
        if POSE_T_WORLD_RADAR in names:
            poses = np.asarray(scene[POSE_T_WORLD_RADAR][...], np.float64)
        else:
            poses = np.broadcast_to(np.eye(4), (T, 4, 4)).copy()
        ts = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64) if TIME_TIMESTAMP_NS in names else np.arange(T)
        self.traj = Trajectory(ts, poses)
        self.cycles = np.asarray(scene[RADAR_CYCLE_NS][...], np.int64) if RADAR_CYCLE_NS in names else None
        self._has = {n: n in names for n in (GT_POINT, GT_NORMAL)}

    def beams(self, k: int, f: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(origins, directions) (H',W',3) of frame k in its radar frame, rows and columns strided
        by ``f`` (the evaluation's downsampling)."""
        cyc = None if self.cycles is None else self.cycles[k]
        col = column_poses(self.traj, k, self.grid, self.origin, cyc)
        o, d = frame_beams(self.grid, self.traj.poses[k], self.origin, col)
        return o[::f, ::f], d[::f, ::f]

    def to_radar(self, k: int, points: np.ndarray) -> np.ndarray:
        """World-frame points (…,3) into frame k's radar frame."""
        T = self.traj.poses[k]
        return (np.asarray(points, np.float64) - T[:3, 3]) @ T[:3, :3]

    def frame(self, k: int, f: int = 1) -> FrameGeometry:
        """Beams and GT points/normals of frame k (radar frame, strided by ``f``)."""
        o, d = self.beams(k, f)
        T = self.traj.poses[k]
        gp = gn = None
        if self._has[GT_POINT]:
            gp = self.to_radar(k, np.asarray(self.scene[GT_POINT][k], np.float64)[:, ::f, ::f])
        if self._has[GT_NORMAL]:
            gn = np.asarray(self.scene[GT_NORMAL][k], np.float64)[:, ::f, ::f] @ T[:3, :3]
        return FrameGeometry(o, d, T, gp, gn)


def frame_geometry(scene, k: int, grid: Grid, downsample: int = 1) -> FrameGeometry:
    """:meth:`SceneBeams.frame` for one frame (reads the scene's poses; loop with SceneBeams)."""
    return SceneBeams(scene, grid).frame(k, downsample)


__all__ = ["FrameGeometry", "SceneBeams", "frame_geometry"]
