"""The segmentation's background model of a scene's scans (step 1 of :mod:`holodata.mapping.segment`):
the voxel model of the world-frame scans plus the floor plane (:func:`build_background`), and what
it says of a scan's returns (:func:`in_background`, :func:`background_masks`,
:func:`surely_without_foreground`)."""
from __future__ import annotations

import numpy as np

from ...progress import track
from .config import SegmentConfig
from .core import above_floor, floor_plane
from .scans import LidarScans


def background_from_points(points_world: list, origins, cfg: SegmentConfig):
    """:class:`VoxelBackground` of world-frame scans with the segmentation's settings (free-space test
    with the scans' ``origins`` when ``cfg.free_space``)."""
    from ..background import VoxelBackground

    use = cfg.free_space and origins is not None and len(origins)
    return VoxelBackground.build(points_world, voxel=cfg.voxel, min_fraction=cfg.min_fraction, min_hits=cfg.min_hits,
                                 origins=np.asarray(origins) if use else None)


def build_background(scans: LidarScans, cfg: SegmentConfig, traj=None, quiet: bool = True):
    """Voxel background model of a scene's scans (world frame). With ``cfg.free_space`` the scan
    origins go to :meth:`VoxelBackground.build` (free-space test: a voxel people walk through is seen
    through by other scans and drops out; the comparison with the occupancy count alone:
    ``docs/design/segment.md``)."""
    return _background_pass(scans, cfg, traj, quiet)[0]


def _background_pass(scans: LidarScans, cfg: SegmentConfig, traj=None, quiet: bool = True, keep: bool = False):
    """(background model, kept) of :func:`build_background`; ``keep``: kept = {frame: float32 world
    points (N,3) of the valid returns in row-major order} of the usable
    scans (the lists the model is built from, no copy), for :func:`segment_scene` ``world_points``."""
    pts, origins, kept = [], [], {}
    for k in track(range(len(scans.stamps)), len(scans.stamps), "background", quiet):
        _, pw = scans.scan_world(k, traj, cfg.deskew)
        if not scans.usable(k):
            continue
        pts.append(pw.astype(np.float32))
        origins.append(scans.poses[k][:3, 3])
        if keep:
            kept[k] = pts[-1]
    origins = np.array(origins) if origins else None
    bg = background_from_points(pts, origins, cfg)
    if cfg.floor_margin_m > 0:
        bg.floor = floor_plane(pts, origins)
    return bg, kept




def surely_without_foreground(bg, points_world32: np.ndarray, cfg: SegmentConfig) -> bool:
    """True when a scan whose valid returns have the float32 world points ``points_world32`` (N,3)
    has fewer than ``cfg.min_points`` foreground returns (returns outside the background model
    ``bg`` and its floor, as :func:`background_masks` decides on the float64 points), so that
    :func:`segment_scan` finds nothing in it. Returns whose float64 point might be classified
    otherwise — within 1e-6·(|x|+1) m (>15x the float32 rounding) of a voxel face or of the floor
    margin — count as foreground, so the answer is exact for the float64 points."""
    p = np.asarray(points_world32, np.float64).reshape(-1, 3)
    need = max(cfg.min_points, 1)
    if len(p) < need:
        return True
    q = np.divide(p, bg.voxel, dtype=np.float64)
    ijk = np.floor(q)                                # voxel indices, as VoxelBackground.contains computes them
    fg = ~bg._lookup(ijk, bool(cfg.tolerance_voxels))
    q -= ijk
    tol = 1e-6 * (np.abs(p) + 1.0)
    near = np.minimum(q, 1.0 - q) * bg.voxel <= tol
    amb = near[:, 0] | near[:, 1] | near[:, 2]
    floor = getattr(bg, "floor", None)
    if floor is not None and cfg.floor_margin_m > 0:
        h = above_floor(floor, p)
        fg &= ~(h < cfg.floor_margin_m)
        amb |= np.abs(h - cfg.floor_margin_m) <= tol[:, 2] + abs(floor[0]) * tol[:, 0] + abs(floor[1]) * tol[:, 1]
    return int((fg | amb).sum()) < need


def in_background(bg, points_world: np.ndarray, tolerance_voxels: int = 0) -> np.ndarray:
    """(N,) bool: world points whose voxel is a background voxel (``tolerance_voxels`` 0), or lies
    within one voxel of one (1: :meth:`VoxelBackground.contains`)."""
    if tolerance_voxels:
        return bg.contains(points_world)
    return bg.contains(points_world, 0)



def background_masks(bg, valid: np.ndarray, points_world: np.ndarray, cfg: SegmentConfig) -> np.ndarray:
    """The background (H,W) bool of one scan for :func:`segment_scan`: returns in a background voxel
    (:func:`in_background`, ``cfg.tolerance_voxels``) or within ``cfg.floor_margin_m`` of the floor
    plane ``bg.floor`` (when the model has one)."""
    v = np.asarray(valid, bool)
    p = points_world[v]
    bgm = np.zeros(v.shape, bool)
    bgm[v] = in_background(bg, p, cfg.tolerance_voxels)
    floor = getattr(bg, "floor", None)
    if floor is not None and cfg.floor_margin_m > 0:
        bgm[v] |= above_floor(floor, p) < cfg.floor_margin_m
    return bgm
