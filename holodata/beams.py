"""Where each radar beam of a frame starts and which way it looks: the beam-origin model.

A rotating-array radar (PanoRadar/HoloRadar, paper §3 and appendix A) forms one heatmap per
rotation. Column ``j`` (azimuth ``φ_j = −2πj/W``, docs/format.md §2) is formed while the radar faces
``φ_j``, i.e. at its own time within the rotation, and its ranges are measured from the **beam
origin**:

* ``rotation_centre`` (the default, docs/format.md §2): rotating-array beamforming aligns every chirp to
  the rotation centre, so ranges are measured from the centre — the pose's translation at the
  column's time;
* ``rotation_circle``: a radar whose ranges are measured from the antenna, which sits at
  ``r (cos φ_j, sin φ_j, 0)`` in the radar frame at the column's time.

With ``column_time`` the pose of column ``j`` is the trajectory at the column's time (SLERP): from
the frame's rotation cycle ``[start, end]`` (``radar/cycle_ns``) it is
``start + (j + 0.5)/W · (end − start)``; without a cycle, ``t + ((j + 0.5)/W − 0.5)/rotation_hz``
with ``t`` the frame stamp (the middle of the rotation). Without ``column_time`` every column
shares the frame's pose.

Ground truth is traced with this model (:mod:`holodata.groundtruth`), and evaluation un-mirrors
with it (:mod:`holodata.evaluate`): :func:`frame_beams` gives each beam's origin and direction in
the radar frame of the frame's own pose, so range images turn into points in one frame per radar
frame. Numeric core: arrays in, arrays out, no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .conventions import RADAR_ROTATION_HZ, Grid

ORIGIN_TYPES = ("rotation_centre", "rotation_circle")


@dataclass(frozen=True)
class OriginModel:
    """Beam-origin model of a radar (module docstring). ``rotation_radius`` m (0 = the rotation
    centre, > 0 = on the rotation circle), ``column_time`` (each column at its own time within the
    rotation), ``rotation_hz`` (for column times when a frame has no rotation cycle)."""

    rotation_radius: float = 0.0
    column_time: bool = True
    rotation_hz: float = RADAR_ROTATION_HZ

    def __post_init__(self) -> None:
        if not (self.rotation_radius >= 0 and np.isfinite(self.rotation_radius)):
            raise ValueError(f"rotation radius must be >= 0 m, got {self.rotation_radius}")
        if not self.rotation_hz > 0:
            raise ValueError(f"rotation rate must be > 0 Hz, got {self.rotation_hz}")

    @property
    def type(self) -> str:
        return "rotation_circle" if self.rotation_radius > 0 else "rotation_centre"

    def to_attrs(self) -> dict:
        return {"type": self.type, "rotation_radius_m": float(self.rotation_radius),
                "column_time": bool(self.column_time), "rotation_hz": float(self.rotation_hz),
                "column_times": ("start + (j + 0.5)/W * (end - start) of radar/cycle_ns; without it "
                                 "t + ((j + 0.5)/W - 0.5)/rotation_hz (t = middle of the rotation)")
                if self.column_time else None}

    @classmethod
    def from_attrs(cls, attrs: dict) -> OriginModel:
        """Inverse of :meth:`to_attrs` (extra keys ignored; a ``rotation_centre`` type has radius 0)."""
        kind = attrs.get("type", "rotation_centre")
        if kind not in ORIGIN_TYPES:
            raise ValueError(f"unknown beam-origin type {kind!r} (known: {', '.join(ORIGIN_TYPES)})")
        r = float(attrs.get("rotation_radius_m", 0.0)) if kind == "rotation_circle" else 0.0
        return cls(r, bool(attrs.get("column_time", True)), float(attrs.get("rotation_hz", RADAR_ROTATION_HZ)))

    def describe(self) -> str:
        """One line for ``info`` and reports, e.g. "rotation centre, per-column time"."""
        where = "rotation centre" if self.rotation_radius == 0 else f"rotation circle r = {self.rotation_radius:g} m"
        return f"{where}, {'per-column time' if self.column_time else 'one pose per frame'}"


def local_origins(grid: Grid, origin: OriginModel) -> np.ndarray:
    """(W, 3) float64 beam origin of each column in the radar frame at that column's time (m)."""
    o = np.zeros((grid.W, 3))
    if origin.rotation_radius > 0:
        az = grid.azimuths()
        o[:, 0] = origin.rotation_radius * np.cos(az)
        o[:, 1] = origin.rotation_radius * np.sin(az)
    return o


def column_times(t_ns: int, grid: Grid, origin: OriginModel, cycle_ns=None) -> np.ndarray:
    """(W,) int64 ns: when column j was formed. ``cycle_ns`` (start, end) of the rotation gives
    ``start + (j + 0.5)/W · (end − start)``; without it the frame stamp ``t_ns`` is the middle of
    the rotation: ``t + ((j + 0.5)/W − 0.5)/rotation_hz``."""
    frac = (np.arange(grid.W) + 0.5) / grid.W
    if cycle_ns is not None:
        a, b = (int(v) for v in cycle_ns)
        if b > a:
            return a + np.round(frac * (b - a)).astype(np.int64)
    return int(t_ns) + np.round((frac - 0.5) / origin.rotation_hz * 1e9).astype(np.int64)


def column_poses(traj, k: int, grid: Grid, origin: OriginModel, cycle_ns=None) -> np.ndarray | None:
    """(W, 4, 4) T_world_radar of each column of frame ``k`` of ``traj`` (a
    :class:`holodata.trajectory.Trajectory`), or None without ``column_time`` (every column at the
    frame's pose)."""
    if not origin.column_time:
        return None
    return traj.interpolate(column_times(int(traj.timestamp_ns[k]), grid, origin, cycle_ns))


def beam_rays(grid: Grid, pose: np.ndarray, origin: OriginModel = OriginModel(),
              column_poses: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World-frame beam origins and unit directions (H*W, 3) float64 of one frame: ``pose`` (4,4)
    T_world_radar, or ``column_poses`` (W,4,4) one pose per column (column_time)."""
    dirs = grid.directions()  # (H,W,3) radar frame
    H, W = grid.H, grid.W
    local_o = local_origins(grid, origin)
    if column_poses is None:
        R, t = pose[:3, :3], pose[:3, 3]
        d = dirs.reshape(-1, 3) @ R.T
        o = np.broadcast_to(local_o @ R.T + t, (H, W, 3)).reshape(-1, 3)
        return np.ascontiguousarray(o), d
    R, t = column_poses[:, :3, :3], column_poses[:, :3, 3]  # (W,3,3), (W,3)
    d = np.einsum("wij,hwj->hwi", R, dirs).reshape(-1, 3)
    o = np.broadcast_to(np.einsum("wij,wj->wi", R, local_o) + t, (H, W, 3)).reshape(-1, 3)
    return np.ascontiguousarray(o), d


def frame_beams(grid: Grid, pose: np.ndarray, origin: OriginModel = OriginModel(),
                column_poses: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Beam origins and unit directions (H, W, 3) float64 of one frame in the radar frame of
    ``pose`` (T_world_radar of the frame): the beams of :func:`beam_rays` moved by ``pose⁻¹``.
    With one pose per frame the origins are :func:`local_origins` and the directions the grid's."""
    if column_poses is None:
        o = np.broadcast_to(local_origins(grid, origin)[None], (grid.H, grid.W, 3)).copy()
        return o, grid.directions()
    rel = np.linalg.inv(pose)[None] @ column_poses  # (W,4,4) T_radar_column
    o, d = beam_rays(grid, np.eye(4), origin, rel)
    return o.reshape(grid.H, grid.W, 3), d.reshape(grid.H, grid.W, 3)


def recorded_origin_model(scene_attrs: dict) -> OriginModel | None:
    """The beam-origin model a scene's recording states (``sensors.radar.beam_origin``, written by
    ingest), or None when it states none (datasets ingested before it was recorded)."""
    rec = ((scene_attrs.get("sensors") or {}).get("radar") or {}).get("beam_origin")
    return OriginModel.from_attrs(rec) if rec else None


def scene_origin_model(scene_attrs: dict, override: OriginModel | None = None) -> tuple[OriginModel, str]:
    """The model raytrace-gt traces a scene with, and where it came from: ``override`` ("flags"),
    else the recording's (:func:`recorded_origin_model`, "recording"), else docs/format.md §2's default
    ("default": the rotation centre with per-column times)."""
    if override is not None:
        return override, "flags"
    rec = recorded_origin_model(scene_attrs)
    return (rec, "recording") if rec is not None else (OriginModel(), "default")


def gt_origin_model(scene_attrs: dict) -> OriginModel | None:
    """The model a scene's ground truth was traced with (``gt.origin_model``), or None without gt."""
    rec = (scene_attrs.get("gt") or {}).get("origin_model")
    return OriginModel.from_attrs(rec) if rec else None


def origin_summary(scene_attrs: dict) -> dict | None:
    """For ``holodata info``: the radar's stated beam-origin model and the one its GT was traced
    with (one-line descriptions), and ``note`` when they differ (GT traced with another model keeps
    working: evaluation follows the GT's model; retrace to follow the radar). None when the scene
    has neither."""
    rec, gt = recorded_origin_model(scene_attrs), gt_origin_model(scene_attrs)
    if rec is None and gt is None:
        return None
    radar = rec or OriginModel()
    out = {"radar": radar.describe() + ("" if rec else " (not recorded: the default of docs/format.md §2)"),
           "gt": gt.describe() if gt else None, "note": None}
    if gt is not None and gt != radar:
        out["note"] = ("ground truth traced with another beam-origin model than the radar's; evaluation follows "
                       "the ground truth's (rerun holodata raytrace-gt into a new dataset to follow the radar)")
    return out


__all__ = ["OriginModel", "ORIGIN_TYPES", "local_origins", "column_times", "column_poses", "beam_rays",
           "frame_beams", "recorded_origin_model", "scene_origin_model", "gt_origin_model", "origin_summary"]
