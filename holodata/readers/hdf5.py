"""HDF5 recordings (h5py) in holodata's documented layout — for labs that export their own
pipelines to HDF5 instead of bags. Every group is optional, but at least radar or LiDAR must exist:

    /radar/heatmap        (T, R, H, W) float16|float32 linear amplitude [frame, range, elevation, azimuth]
        attrs: range_resolution_m (default 0.0375), elevation_max_deg / elevation_min_deg (45 / -45),
               rotation_radius_m (0.105), frame_id ("radar"),
               range_origin: "rotation_centre" (default: rotating-array beamforming) | "antenna",
               scaling: "linear" (default) | "log10(a+1e-3)/3" (PanoRadar's; undone on read)
    /radar/timestamp_ns   (T,) int64, strictly increasing (frame time, e.g. mid-cycle)
    /radar/cycle_ns       (T, 2) int64 [start, end] (optional; default timestamp -/+ half the median period)
    /lidar/points         (N, 3) float32 sensor frame, all scans concatenated
    /lidar/offsets        (S+1,) int64: scan i = points[offsets[i]:offsets[i+1]]
    /lidar/timestamp_ns   (S,) int64
    /lidar/point_time_ns  (N,) int64 per-point time relative to the scan stamp (optional)
        attrs of /lidar: frame_id ("lidar")
    /camera/points, /camera/offsets, /camera/timestamp_ns   like /lidar (optional; attrs frame_id "camera")

Messages are read lazily, one frame/scan slice at a time (streaming, flat memory). A file that
h5py cannot open, or groups that break the layout (shapes, missing timestamps), give a one-line
RecordingError naming the dataset path in the file. So does a dataset whose shape declares more
bytes than the file stores for it (:func:`.sizes.declared_size`; a compressed dataset: more than
:func:`.sizes.inflated_room` of its stored bytes), checked before any of it is read: an HDF5 dataset
that was never written reads as its fill value, whatever size it declares. Datasets stored outside
the file (external or virtual layouts) store nothing in it and are refused alike.
"""
from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ..conventions import DEFAULT_ELEV_DEG, DEFAULT_RANGE_RESOLUTION_M
from ..dataset.layout import RADAR_CYCLE_NS, RADAR_HEATMAP  # the file names its arrays as the dataset does
from ..errors import RecordingError
from .base import POINTS_TYPE, RADAR_MSG, Header, PointsMsg, RadarHeatmapMsg, RawMessage, Recording, TopicInfo, rate_of
from .sizes import declared_size, inflated_room


def _h5py():
    try:
        import h5py
    except ImportError as err:
        raise RecordingError("reading .h5 recordings needs h5py (pip install h5py)") from err
    return h5py


class Hdf5Recording(Recording):
    kind = "hdf5"

    def __init__(self, path: Path):
        super().__init__(path)
        h5py = _h5py()
        try:
            self.f = h5py.File(self.path, "r")
        except OSError as err:
            raise RecordingError(f"{self.path}: not a readable HDF5 file ({' '.join(str(err).split())[:120]})") from err
        self.files = [self.path]
        self.attrs = {"format": "holodata HDF5 layout"}
        self.streams: dict[str, dict] = {}
        try:
            self._check()
        except BaseException:
            self.f.close()
            raise

    def _need(self, name: str):
        if name not in self.f:
            raise RecordingError(f"{self.path}: {name} is missing (see holodata.readers.hdf5 for the layout)")
        return self._dataset(name)

    def _dataset(self, name: str):
        """Dataset ``name`` once the bytes its shape declares (whole, and per chunk: HDF5 reads a
        chunk whole) are checked against the bytes the file stores for it, before any is read."""
        ds = self.f[name]
        if not isinstance(ds, _h5py().Dataset):
            raise RecordingError(f"{self.path}: {name} is a group, not a dataset (see holodata.readers.hdf5 for the layout)")
        item = ds.dtype.itemsize
        need = max(int(np.prod(ds.shape, dtype=object)), int(np.prod(ds.chunks, dtype=object)) if ds.chunks else 0) * item
        stored = int(ds.id.get_storage_size())
        if ds.id.get_create_plist().get_nfilters():      # compressed: the believed ratio
            room, held = inflated_room(stored), f"its {stored} stored (filtered) bytes can hold at most"
        else:
            room, held = stored, "the file stores for it"
        declared_size(self.path, f"{name} {tuple(ds.shape)} {ds.dtype}", need, room, held)
        return ds

    def _stamps(self, name: str, n: int) -> np.ndarray:
        ds = self._need(name)
        if ds.shape != (n,):
            raise RecordingError(f"{self.path}: {name} has shape {ds.shape}, expected ({n},)")
        return np.asarray(ds[...], dtype=np.int64)

    def _check(self) -> None:
        f = self.f
        if RADAR_HEATMAP in f:
            hm = self._dataset(RADAR_HEATMAP)
            if hm.ndim != 4 or hm.dtype.kind != "f":
                raise RecordingError(f"{self.path}: radar/heatmap must be (T, R, H, W) float, got {hm.shape} {hm.dtype}")
            ts = self._stamps("radar/timestamp_ns", hm.shape[0])
            if RADAR_CYCLE_NS in f:
                c = self._dataset(RADAR_CYCLE_NS)
                if c.shape != (hm.shape[0], 2):
                    raise RecordingError(f"{self.path}: radar/cycle_ns has shape {c.shape}, expected ({hm.shape[0]}, 2)")
                cyc = np.asarray(c[...], np.int64)
            else:
                half = int(np.median(np.diff(ts)) // 2) if len(ts) > 1 else 250_000_000
                cyc = np.stack([ts - half, ts + half], 1)
            a = dict(hm.attrs)
            scaling = str(a.get("scaling", "linear"))
            if scaling not in ("linear", "log10(a+1e-3)/3"):
                raise RecordingError(f"{self.path}: radar/heatmap scaling {scaling!r} is not linear or log10(a+1e-3)/3")
            self.attrs["radar_scaling"] = scaling + ("; undone on read" if scaling != "linear" else "")
            self.streams["/radar/heatmap"] = {"type": RADAR_MSG, "ts": ts, "cycle": cyc, "attrs": a}
        for role in ("lidar", "camera"):
            if f"{role}/points" not in f:
                continue
            pts = self._dataset(f"{role}/points")
            if pts.ndim != 2 or pts.shape[1] != 3:
                raise RecordingError(f"{self.path}: {role}/points must be (N, 3), got {pts.shape}")
            if f"{role}/point_time_ns" in f:
                self._dataset(f"{role}/point_time_ns")      # read per scan later: its size checked now
            off = np.asarray(self._need(f"{role}/offsets")[...], np.int64)
            if off.ndim != 1 or len(off) < 1 or off[0] != 0 or off[-1] != pts.shape[0] or np.any(np.diff(off) < 0):
                raise RecordingError(f"{self.path}: {role}/offsets must start at 0, never decrease and end at "
                                     f"len({role}/points) = {pts.shape[0]}")
            ts = self._stamps(f"{role}/timestamp_ns", len(off) - 1)
            frame_id = str(f[role].attrs.get("frame_id", role))
            self.streams[f"/{role}/points"] = {"type": POINTS_TYPE, "ts": ts, "off": off, "role": role,
                                               "frame_id": frame_id}
        if not self.streams:
            raise RecordingError(f"{self.path}: HDF5 file has neither radar/heatmap nor lidar/points nor camera/points "
                                 f"(see holodata.readers.hdf5 for the layout)")

    def _topics(self) -> list[TopicInfo]:
        out = []
        for topic, s in sorted(self.streams.items()):
            ts = s["ts"]
            lo, hi = (int(ts.min()), int(ts.max())) if len(ts) else (None, None)
            frame = s.get("frame_id") or str(s.get("attrs", {}).get("frame_id", "radar"))
            out.append(TopicInfo(topic, s["type"], len(ts), rate_of(len(ts), lo, hi), frame, "hdf5", True, "", lo, hi))
        return out

    def _radar(self, i: int) -> RadarHeatmapMsg:
        s = self.streams["/radar/heatmap"]
        a = s["attrs"]
        hm = np.asarray(self.f[RADAR_HEATMAP][i])
        if str(a.get("scaling", "linear")) != "linear":
            hm = np.maximum(np.power(10.0, 3.0 * hm.astype(np.float64)) - 1e-3, 0.0).astype(np.float32)
        enc = "float16" if hm.dtype == np.float16 else "float32"
        hm = np.ascontiguousarray(hm, "<f2" if enc == "float16" else "<f4")
        R, H, W = hm.shape
        return RadarHeatmapMsg(Header(int(s["ts"][i]), str(a.get("frame_id", "radar"))), int(s["cycle"][i, 0]),
                               int(s["cycle"][i, 1]), R, H, W, float(a.get("range_resolution_m", DEFAULT_RANGE_RESOLUTION_M)),
                               float(np.deg2rad(a.get("elevation_max_deg", DEFAULT_ELEV_DEG[0]))),
                               float(np.deg2rad(a.get("elevation_min_deg", DEFAULT_ELEV_DEG[1]))),
                               float(a.get("rotation_radius_m", 0.105)), enc, hm.reshape(-1).view(np.uint8),
                               str(a.get("range_origin", "rotation_centre")))

    def _points(self, topic: str, i: int) -> PointsMsg:
        s = self.streams[topic]
        lo, hi = int(s["off"][i]), int(s["off"][i + 1])
        role = s["role"]
        xyz = np.asarray(self.f[f"{role}/points"][lo:hi], dtype=np.float32)
        t = None
        if f"{role}/point_time_ns" in self.f:
            t = np.asarray(self.f[f"{role}/point_time_ns"][lo:hi], dtype=np.int64)
        return PointsMsg(xyz, t, s["frame_id"])

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        want = None if topics is None else set(topics)
        items = []
        for topic, s in self.streams.items():
            if want is None or topic in want:
                items += [(int(t), topic, i) for i, t in enumerate(s["ts"])]
        items.sort()
        for t, topic, i in items:
            ty = self.streams[topic]["type"]
            yield RawMessage(topic, ty, t, None, "hdf5", (topic, i))

    def decode(self, raw: RawMessage):
        topic, i = raw.obj
        return self._radar(i) if topic == "/radar/heatmap" else self._points(topic, i)

    def close(self) -> None:
        with contextlib.suppress(Exception):   # any failure: h5py's own, on a file that is gone; nothing to keep
            self.f.close()
