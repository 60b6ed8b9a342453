"""Vectorised ``sensor_msgs/PointCloud2`` decoding for any field layout.

Each field is read as a strided numpy view straight over the message bytes (no per-point Python,
no structured dtype — so padding, unaligned offsets, overlapping or repeated fields, row padding
(``row_step > width*point_step``) and big-endian data all work). Invalid points — a non-finite
coordinate, or exactly (0, 0, 0), the "no return" of Ouster/Velodyne drivers — are dropped unless
``keep_invalid``; :attr:`Cloud.index` keeps the flat (row-major) index of every kept point, so an
organised cloud maps back onto its ``(height, width)`` grid.

Per-point time (for deskewing) is found by field name and normalised to int64 nanoseconds
relative to the header stamp:

- split ``time_sec``/``time_nsec`` (Luminar; also ``timestamp_sec``/``_nsec``, ``t_sec``/``t_nsec``):
  absolute, ``sec*1e9 + nsec - stamp``;
- ``t``, ``time``, ``timestamp``, ``time_stamp``, ``offset_time``, ``ts``, ``time_offset``: by value
  — floats > 1e17 absolute ns, floats > 1e8 absolute seconds (Hesai, RoboSense), other floats
  relative seconds (Velodyne ``time``); integers > 1e17 absolute ns, other integers relative ns
  (Ouster ``t``, Livox ``offset_time``). Relative fields are returned as they are (their zero is
  the driver's scan start, which is usually the stamp); :attr:`Cloud.time_reference` says which.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .base import DecodeError

# sensor_msgs/PointField datatypes
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
TIME_FIELDS = ("t", "time", "timestamp", "time_stamp", "offset_time", "ts", "time_offset", "stamp")
SPLIT_TIME_FIELDS = (("time_sec", "time_nsec"), ("timestamp_sec", "timestamp_nsec"), ("t_sec", "t_nsec"),
                     ("sec", "nsec"))


@dataclass
class Cloud:
    """A decoded cloud. ``xyz`` (N, 3) float32 metres in the header frame; ``fields`` name -> (N,)
    (or (N, count)) arrays of the kept points; ``time_ns`` (N,) int64 per-point time (see module
    docstring) or None; ``index`` (N,) int64 flat index of each kept point in the ``shape`` grid."""

    xyz: np.ndarray
    stamp_ns: int
    frame_id: str
    shape: tuple[int, int]
    index: np.ndarray
    fields: dict = field(default_factory=dict)
    time_ns: np.ndarray | None = None
    time_field: str | None = None
    time_reference: str | None = None   # "stamp" (absolute times made relative) | "scan" (driver-relative)
    n_raw: int = 0

    @property
    def organised(self) -> bool:
        return self.shape[0] > 1

    def grid(self, values: np.ndarray, fill=np.nan) -> np.ndarray:
        """Scatter per-point ``values`` (N, ...) back onto the (height, width, ...) grid."""
        out = np.full((self.shape[0] * self.shape[1],) + values.shape[1:], fill,
                      dtype=np.result_type(values.dtype, np.asarray(fill).dtype))
        out[self.index] = values
        return out.reshape(self.shape + values.shape[1:])


def _stamp(msg) -> int:
    st = msg.header.stamp
    sec = getattr(st, "sec", None)
    nsec = getattr(st, "nanosec", None)
    if nsec is None:
        nsec = getattr(st, "nsec", 0)
    return int(sec) * 1_000_000_000 + int(nsec)


def field_layout(msg) -> dict[str, tuple[int, np.dtype, int]]:
    """{name: (offset, dtype with the message's byte order, count)}; the first of repeated names wins."""
    order = ">" if msg.is_bigendian else "<"
    out: dict[str, tuple[int, np.dtype, int]] = {}
    for f in msg.fields:
        code = DATATYPES.get(int(f.datatype))
        if code is None or f.name in out:
            continue
        out[f.name] = (int(f.offset), np.dtype(order + code), max(1, int(f.count)))
    return out


def _view(data: np.ndarray, h: int, w: int, row_step: int, point_step: int, off: int, dt: np.dtype,
          count: int = 1) -> np.ndarray:
    shape = (h, w) + ((count,) if count > 1 else ())
    strides = (row_step, point_step) + ((dt.itemsize,) if count > 1 else ())
    return np.ndarray(shape=shape, dtype=dt, buffer=data, offset=off, strides=strides)


def _checked(msg, topic: str):
    """(h, w, point_step, row_step, data, layout) after the layout and payload checks."""
    where = f"topic {topic}: " if topic else ""
    h, w = int(msg.height), int(msg.width)
    ps, rs = int(msg.point_step), int(msg.row_step)
    data = msg.data
    if not isinstance(data, np.ndarray):
        data = np.frombuffer(bytes(data), np.uint8)
    layout = field_layout(msg)
    if h * w == 0:
        return h, w, ps, rs, data, layout
    missing = [c for c in "xyz" if c not in layout]
    if missing:
        raise DecodeError(f"{where}PointCloud2 has no {'/'.join(missing)} field (fields: "
                          f"{', '.join(layout) or 'none'})")
    for name, (off, dt, cnt) in layout.items():
        if off < 0 or off + dt.itemsize * cnt > ps:
            raise DecodeError(f"{where}PointCloud2 field {name!r} (offset {off}, {cnt}x{dt.itemsize} B) lies outside "
                              f"point_step {ps}")
    if rs == 0 and h == 1:
        rs = w * ps
    if rs < w * ps:
        raise DecodeError(f"{where}PointCloud2 row_step {rs} < width {w} x point_step {ps}")
    need = rs * (h - 1) + w * ps
    if data.size < need:
        raise DecodeError(f"{where}PointCloud2 payload is {data.size} bytes, {h}x{w} points of {ps} B need {need} "
                          f"(truncated message)")
    return h, w, ps, rs, data, layout


def check_pointcloud2(msg, topic: str = "") -> tuple[int, int]:
    """Raise :class:`DecodeError` if the cloud cannot be decoded; else its (height, width)."""
    h, w, *_ = _checked(msg, topic)
    return h, w


def decode_pointcloud2(msg, topic: str = "", fields: tuple[str, ...] | None = None, keep_invalid: bool = False,
                       time: bool = True) -> Cloud:
    """Decode a PointCloud2 message (rosbags object, ROS 1 or 2). ``fields``: extra field names to
    return (None = every field but x/y/z and the time fields). Raises :class:`DecodeError` naming
    ``topic`` for missing x/y/z, fields outside ``point_step`` or a truncated payload."""
    h, w, ps, rs, data, layout = _checked(msg, topic)
    stamp = _stamp(msg)
    frame_id = str(msg.header.frame_id)
    if h * w == 0:
        return Cloud(np.zeros((0, 3), np.float32), stamp, frame_id, (h, w), np.zeros(0, np.int64), n_raw=0)
    if rs == 0 and h == 1:
        rs = w * ps

    ox, dx, _ = layout["x"]
    oy, dy, _ = layout["y"]
    oz, dz, _ = layout["z"]
    if dx == dy == dz and oy == ox + dx.itemsize and oz == oy + dx.itemsize:
        xyz = _view(data, h, w, rs, ps, ox, dx, 3).reshape(h * w, 3)
        xyz = xyz.astype(np.float32)          # one strided copy (+ byte swap / widening)
    else:
        xyz = np.empty((h * w, 3), np.float32)
        for k, (o, d) in enumerate(((ox, dx), (oy, dy), (oz, dz))):
            xyz[:, k] = _view(data, h, w, rs, ps, o, d).reshape(-1)
    n_raw = h * w
    if keep_invalid:
        index = np.arange(n_raw, dtype=np.int64)
        pts = xyz
    else:
        good = np.isfinite(xyz).all(axis=1) & xyz.any(axis=1)
        if good.all():
            index, pts = np.arange(n_raw, dtype=np.int64), xyz
        else:
            index = np.flatnonzero(good)
            pts = xyz[index]
    out = Cloud(pts, stamp, frame_id, (h, w), index, n_raw=n_raw)

    def take(name):
        o, d, c = layout[name]
        v = _view(data, h, w, rs, ps, o, d, c).reshape((n_raw,) + ((c,) if c > 1 else ()))
        return v[index].astype(d.newbyteorder("="), copy=False) if len(index) != n_raw else v.astype(d.newbyteorder("="))

    used = {"x", "y", "z"}
    if time:
        t = _time_field(layout, take, stamp)
        if t is not None:
            out.time_ns, out.time_field, out.time_reference = t
            used.update(out.time_field.split("+"))
    names = [n for n in layout if n not in used] if fields is None else [n for n in fields if n in layout]
    for n in names:
        out.fields[n] = take(n)
    return out


def _time_field(layout, take, stamp: int):
    for s, ns in SPLIT_TIME_FIELDS:
        if s in layout and ns in layout:
            t = take(s).astype(np.int64) * 1_000_000_000 + take(ns).astype(np.int64)
            return t - stamp, f"{s}+{ns}", "stamp"
    for name in TIME_FIELDS:
        if name not in layout or layout[name][2] != 1:
            continue
        v = take(name)
        if v.size == 0:
            return np.zeros(0, np.int64), name, "scan"
        mx = float(np.nanmax(np.abs(v.astype(np.float64))))
        if v.dtype.kind == "f":
            if mx > 1e17:
                return v.astype(np.int64) - stamp, name, "stamp"
            if mx > 1e8:
                sec = np.floor(v.astype(np.float64))
                ns = np.rint((v.astype(np.float64) - sec) * 1e9).astype(np.int64)
                return (sec.astype(np.int64) * 1_000_000_000 + ns) - stamp, name, "stamp"
            return np.rint(v.astype(np.float64) * 1e9).astype(np.int64), name, "scan"
        if mx > 1e17:
            return v.astype(np.int64) - stamp, name, "stamp"
        return v.astype(np.int64), name, "scan"
    return None
