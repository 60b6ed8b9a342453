"""PanoRadar-style trajectory folders of per-frame ``.npy`` files (layout of PanoRadar's
``process_raw_data.py`` / ``data/dataset.py``):

    <trajectory>/rf_npy/00000.npy      (256, 64, 512) float32  log10(a + 1e-3) / 3
                                         [range bin, elevation, azimuth]
    <trajectory>/lidar_npy/00000.npy   (1, 64, 512) float32    range / 10 m; <= 0 failed
    (seg_npy/, glass_npy/, obj_json/ are listed, not read)

The log scaling is undone here and recorded in :attr:`NpyFolderRecording.attrs`: radar amplitude
``a = 10**(3 x) - 1e-3`` clipped at 0 (linear amplitude, docs/format.md §2), LiDAR ``range = 10 x`` m
with non-positive values NaN. The folders carry no timestamps: frame ``i`` is stamped ``i x 0.5 s``
(the 2 Hz rotation) from 0 plus half a cycle (mid-cycle stamps), marked as synthesised. Elevation rows are linspace(+45°, -45°,
64) as in
PanoRadar; LiDAR points are the range image along the same beam grid (:class:`~holodata.conventions.Grid`),
so they sit in the radar frame. Frames are paired by file name.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ..conventions import DEFAULT_RANGE_RESOLUTION_M, RADAR_ROTATION_HZ, RADAR_ROTATION_RADIUS_M, Grid
from ..errors import RecordingError
from .base import RADAR_MSG, RANGE_IMAGE_TYPE, Header, RadarHeatmapMsg, RangeImageMsg, RawMessage, Recording, TopicInfo, rate_of
from .sizes import check_npy

RF_TOPIC = "/panoradar/rf"
LIDAR_TOPIC = "/panoradar/lidar_range"
PERIOD_NS = int(round(1e9 / RADAR_ROTATION_HZ))


def undo_rf_log(x: np.ndarray) -> np.ndarray:
    """PanoRadar's ``log10(a + 1e-3) / 3`` back to linear amplitude (>= 0)."""
    return np.maximum(np.power(10.0, 3.0 * x.astype(np.float64)) - 1e-3, 0.0).astype(np.float32)


class NpyFolderRecording(Recording):
    kind = "npy-folder"

    def __init__(self, path: Path):
        super().__init__(path)
        rf_dir, li_dir = self.path / "rf_npy", self.path / "lidar_npy"
        if not rf_dir.is_dir() and not li_dir.is_dir():
            raise RecordingError(f"{self.path}: not a PanoRadar trajectory folder (no rf_npy/ or lidar_npy/ inside)")
        self.rf = sorted(rf_dir.glob("*.npy")) if rf_dir.is_dir() else []
        self.lidar = sorted(li_dir.glob("*.npy")) if li_dir.is_dir() else []
        if not self.rf and not self.lidar:
            raise RecordingError(f"{self.path}: rf_npy/ and lidar_npy/ hold no .npy files")
        names = sorted({p.stem for p in self.rf} | {p.stem for p in self.lidar})
        self.index = {n: i for i, n in enumerate(names)}
        self.files = self.rf + self.lidar
        self.attrs = {
            "format": "PanoRadar npy folder",
            "radar_scaling": "stored log10(a + 1e-3) / 3; undone: a = max(10**(3x) - 1e-3, 0) (linear amplitude)",
            "lidar_scaling": "stored range / 10 m; undone: range = 10x m, x <= 0 -> NaN",
            "timestamps": f"synthesised: frame i stamped (i + 0.5) x {PERIOD_NS / 1e9:g} s, mid-cycle (the folder has no times)",
            "range_resolution_note": "PanoRadar's code uses 0.003747 x 10 m per range bin; stored as "
                                     f"{DEFAULT_RANGE_RESOLUTION_M} m",
        }
        self.grid = None

    def _t(self, p: Path) -> int:
        """Start of the frame's (synthesised) rotation cycle."""
        return self.index[p.stem] * PERIOD_NS

    def _topics(self) -> list[TopicInfo]:
        out = []
        for topic, ty, files in ((LIDAR_TOPIC, RANGE_IMAGE_TYPE, self.lidar), (RF_TOPIC, RADAR_MSG, self.rf)):
            if files:
                lo, hi = self._t(files[0]) + PERIOD_NS // 2, self._t(files[-1]) + PERIOD_NS // 2
                out.append(TopicInfo(topic, ty, len(files), rate_of(len(files), lo, hi),
                                     "radar", "npy", True, f"{files[0].parent.name}/*.npy", lo, hi))
        return out

    def _load(self, p: Path, ndim: int) -> np.ndarray:
        check_npy(p)      # the shape its header declares against the bytes after it, before np.load reserves it
        try:
            a = np.load(p, allow_pickle=False)
        except (OSError, ValueError, EOFError) as err:
            raise RecordingError(f"{p}: not a readable .npy array ({' '.join(str(err).split())[:100]})") from err
        if a.ndim == ndim + 1 and a.shape[0] == 1:
            a = a[0]
        if a.ndim != ndim or a.dtype.kind != "f":
            raise RecordingError(f"{p}: expected a {ndim}-d float array, got {a.shape} {a.dtype}")
        return a

    def decode_rf(self, p: Path) -> RadarHeatmapMsg:
        x = self._load(p, 3)
        a = np.ascontiguousarray(undo_rf_log(x), "<f4")
        R, H, W = a.shape
        g = Grid(H, W)
        t = self._t(p)
        return RadarHeatmapMsg(Header(t + PERIOD_NS // 2, "radar"), t, t + PERIOD_NS, R, H, W,
                               DEFAULT_RANGE_RESOLUTION_M, float(np.deg2rad(g.elev_max_deg)),
                               float(np.deg2rad(g.elev_min_deg)), RADAR_ROTATION_RADIUS_M, "float32",
                               a.reshape(-1).view(np.uint8))

    def decode_lidar(self, p: Path) -> RangeImageMsg:
        x = self._load(p, 2)
        r = (x.astype(np.float32) * np.float32(10.0))
        r[~(r > 0)] = np.nan
        H, W = r.shape
        d = Grid(H, W).directions().astype(np.float32)
        xyz = np.where(np.isfinite(r)[..., None], d * np.nan_to_num(r)[..., None], 0.0).astype(np.float32)
        return RangeImageMsg(r, xyz, "radar")

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        want = None if topics is None else set(topics)
        items = []
        if want is None or RF_TOPIC in want:
            items += [(self._t(p), 1, RF_TOPIC, RADAR_MSG, p) for p in self.rf]
        if want is None or LIDAR_TOPIC in want:
            items += [(self._t(p), 0, LIDAR_TOPIC, RANGE_IMAGE_TYPE, p) for p in self.lidar]
        for t, _, topic, ty, p in sorted(items, key=lambda x: (x[0], x[1])):
            obj = _Lazy(self.decode_rf if topic == RF_TOPIC else self.decode_lidar, p)
            yield RawMessage(topic, ty, t + PERIOD_NS // 2, None, "npy", obj)   # both: mid-cycle

    def decode(self, raw: RawMessage):
        obj = raw.obj
        return obj() if isinstance(obj, _Lazy) else obj


class _Lazy:
    """Loads its file only when decoded (filter first, decode later)."""

    __slots__ = ("fn", "path")

    def __init__(self, fn, path):
        self.fn, self.path = fn, path

    def __call__(self):
        return self.fn(self.path)
