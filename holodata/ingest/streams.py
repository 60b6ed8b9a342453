"""Stream decoders: one class per kind of sensor message (point clouds, Ouster scans and packets,
depth images, stereo pairs; the radar's in :mod:`.radar_streams`) turning recording messages into
frame payloads."""
from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np

from ..errors import HolodataError, RecordingError
from ..readers.base import DecodeError, RawMessage, Recording


@dataclass
class Item:
    index: int           # item number within the stream (stable across passes)
    stamp: int           # ns
    payload: object = None


class _Stream:
    role = ""

    def __init__(self, rec: Recording, topic: str, time: str):
        self.rec, self.topic, self.time = rec, topic, time
        self.n = 0
        self.failed: list[str] = []
        self.checked: set[int] = set()   # items whose message passed every check in the index pass
        self._converting = -1             # the item being converted

    @property
    def topics(self) -> list[str]:
        return [self.topic]

    def stamp(self, raw: RawMessage) -> int:
        return raw.log_ns if self.time == "log" else self.rec.stamp_ns(raw)

    def reset(self) -> None:
        self.n = 0

    def _next(self) -> int:
        i = self.n
        self.n += 1
        return i

    def feed(self, raw: RawMessage, decode: bool, check: bool = False, want=None) -> list[Item]:
        """Items completed by ``raw``. ``decode``: attach payloads (only for indices in ``want``);
        ``check``: decode and validate without keeping the payload (index pass of the frame sensor).
        Undecodable messages still consume their index so both passes agree; they raise DecodeError
        with the item index in ``err.item``."""
        i = self._next()
        st = self.stamp(raw)
        if not decode and not check:
            return [Item(i, st)]
        if decode and want is not None and i not in want:
            return [Item(i, st)]
        try:
            self._converting = i
            payload = self.convert(raw, keep=decode)
        except HolodataError as err:
            err.item = i
            raise
        except Exception as err:  # noqa: BLE001 - damaged bytes deserialise into garbage of any shape
            # the Python exception (kept as the cause, for --debug) says nothing to the user
            bad = DecodeError(f"topic {self.topic}: {raw.msgtype.rsplit('/', 1)[-1]} message at {raw.log_ns} ns "
                              f"does not decode: its fields do not form a valid message (damaged bytes?)")
            bad.item = i
            raise bad from err
        if check and not decode:
            self.checked.add(i)
        return [Item(i, st, payload if decode else None)]

    def flush(self, decode: bool, want=None) -> list[Item]:
        return []

    def convert(self, raw: RawMessage, keep: bool):
        raise NotImplementedError

    layout: dict | None = None
    _layout_tries = 0

    def try_layout(self, raw: RawMessage) -> None:
        """Learn {grid: (H, W) | None, time: bool, frame_id} from one message (index pass)."""
        if self.layout is not None or raw.topic != self.topic or self._layout_tries > 20:
            return
        self._layout_tries += 1
        try:
            p = self.convert(raw, keep=True)
        except Exception:  # noqa: BLE001 - a damaged message teaches nothing about the layout
            return
        self.layout = {"grid": None if p.grid is None else tuple(p.grid.shape), "time": p.time_ns is not None,
                       "frame_id": p.frame_id}


@dataclass
class Scan:
    """A decoded LiDAR scan or camera frame: points (N,3) float32 sensor frame; optional per-point
    time (N,) int64 ns; optional grid (Hl, Wl) float32 range (NaN none)."""

    points: np.ndarray
    time_ns: np.ndarray | None = None
    grid: np.ndarray | None = None
    frame_id: str = ""


def _norm3(xyz: np.ndarray) -> np.ndarray:
    """(N,) float32 Euclidean norms of (N, 3) float32 points: the same bits as
    ``np.linalg.norm(xyz, axis=1)`` ((x² + y²) + z² in float32, then sqrt), at a fraction of its cost
    (docs/design/performance.md)."""
    if xyz.dtype != np.float32 or xyz.ndim != 2 or xyz.shape[1] != 3:
        return np.linalg.norm(xyz, axis=1).astype(np.float32)
    s = xyz[:, 0] * xyz[:, 0]
    s += xyz[:, 1] * xyz[:, 1]
    s += xyz[:, 2] * xyz[:, 2]
    return np.sqrt(s, out=s)


class CloudStream(_Stream):
    """PointCloud2 (LiDAR or camera)."""

    def __init__(self, rec, topic, time, role):
        super().__init__(rec, topic, time)
        self.role = role
        self.time_field = None
        self.time_reference = None
        self.organised = None

    def convert(self, raw, keep):
        from ..readers.pointcloud2 import check_pointcloud2, decode_pointcloud2

        msg = self.rec.decode(raw)
        if not keep:
            check_pointcloud2(msg, self.topic)
            return None
        c = decode_pointcloud2(msg, self.topic, fields=(), time=self.role == "lidar")
        if self.time_field is None and c.time_field:
            self.time_field, self.time_reference = c.time_field, c.time_reference
        grid = None
        if c.organised and self.role == "lidar":
            grid = c.grid(_norm3(c.xyz))
        return Scan(c.xyz, c.time_ns, grid, c.frame_id)


class CameraCloudStream(CloudStream):
    """A camera's organised PointCloud2 (RealSense ``depth/color/points``, ZED ``point_cloud``): its
    rows and columns are the depth image's pixels. :meth:`load_model` finds the intrinsics (the
    CameraInfo of the cloud's frame when the recording has one that fits the points, else fitted
    to the cloud, :func:`holodata.readers.images.fit_pinhole`) and the rotation into the optical
    frame; points are stored in the optical frame, as a depth image's are, so ``register`` recovers
    the pixels. An unorganised cloud keeps no model (and its points as published)."""

    MAX_RMS_PX = 0.5

    def __init__(self, rec, topic, time, info_topic: str | None = None):
        super().__init__(rec, topic, time, "camera")
        self.info_topic = info_topic
        self.model = None
        self.R_opt = None           # (3,3) p_optical = R_opt @ p_cloud
        self.model_source = None

    def load_model(self) -> str | None:
        """Fit the model from the first cloud with points; returns a note when none fits."""
        from ..readers.images import camera_model, fit_pinhole, pinhole_residual
        from ..readers.pointcloud2 import decode_pointcloud2

        for i, raw in enumerate(self.rec.raw_messages([self.topic])):
            if i >= 20:
                break
            try:
                c = decode_pointcloud2(self.rec.decode(raw), self.topic, fields=(), time=False)
            except HolodataError:
                continue
            if not c.organised:
                return None
            if len(c.xyz) < 50:
                continue
            rows, cols = np.divmod(c.index, c.shape[1])
            fit = fit_pinhole(c.xyz, rows, cols)
            if fit is None or fit[2] > self.MAX_RMS_PX:
                return (f"topic {self.topic}: organised camera cloud is not a pinhole image "
                        f"(fit {'none' if fit is None else f'{fit[2]:.2f} px'}); no intrinsics")
            K, R, rms = fit
            self.R_opt, self.model_source = R, f"fitted to the organised cloud (rms {rms:.3f} px)"
            if self.info_topic:
                for raw_i in self.rec.raw_messages([self.info_topic]):
                    try:
                        m = camera_model(self.rec.decode(raw_i), self.info_topic)
                    except HolodataError:
                        break
                    q = np.asarray(c.xyz, np.float64) @ R.T
                    if (m.height, m.width) == tuple(c.shape) and pinhole_residual(q, rows, cols, m.K) <= self.MAX_RMS_PX:
                        K, self.model_source = m.K, f"CameraInfo {self.info_topic}"
                    break
            from ..readers.images import CameraModel

            self.model = CameraModel(np.asarray(K, np.float64), int(c.shape[1]), int(c.shape[0]), c.frame_id,
                                     "none", ())
            return None
        return None

    def convert(self, raw, keep):
        sc = super().convert(raw, keep)
        if sc is not None and self.R_opt is not None and not np.array_equal(self.R_opt, np.eye(3)):
            sc = Scan((sc.points @ self.R_opt.T.astype(np.float32)).astype(np.float32), sc.time_ns, sc.grid, sc.frame_id)
        return sc


class GridStream(_Stream):
    """Organised scans the recording decodes itself: Ouster pcap scans, range images (npy/HDF5)."""

    role = "lidar"
    time_field = None
    time_reference = None

    def stamp(self, raw):
        return raw.log_ns

    def convert(self, raw, keep):
        obj = self.rec.decode(raw)
        return _grid_to_scan(obj) if keep else None

    def try_layout(self, raw):
        if self.layout is None and raw.topic == self.topic:
            obj = self.rec.decode(raw)
            self.layout = {"grid": tuple(obj.range_m.shape), "time": hasattr(obj, "pixel_times_ns"),
                           "frame_id": _frame_name(obj)}


class OusterScanStream(GridStream):
    """Ouster pcap scans (the recording yields decoded scans)."""

    time_field = "ouster column timestamps"
    time_reference = "sensor clock, first valid column"


def _grid_to_scan(s) -> Scan:
    valid = np.isfinite(s.range_m)
    t = s.pixel_times_ns()[valid].astype(np.int64) if hasattr(s, "pixel_times_ns") else None
    return Scan(np.asarray(s.xyz)[valid].astype(np.float32), t, np.asarray(s.range_m, np.float32), _frame_name(s))


def _frame_name(obj) -> str:
    """The sensor frame of a decoded scan (Ouster scans carry a frame *counter*: the SDK's sensor frame)."""
    f = getattr(obj, "frame_id", None)
    return f if isinstance(f, str) and f else "os_sensor"


def _ouster_to_scan(s) -> Scan:
    return _grid_to_scan(s)


class PointsStream(_Stream):
    """Plain point clouds the recording decodes itself (HDF5)."""

    def __init__(self, rec, topic, time, role):
        super().__init__(rec, topic, time)
        self.role = role
        self.time_field = None
        self.time_reference = None

    def stamp(self, raw):
        return raw.log_ns

    def convert(self, raw, keep):
        obj = self.rec.decode(raw)
        if not keep:
            return None
        xyz = np.asarray(obj.xyz, np.float32)
        good = np.isfinite(xyz).all(1) & xyz.any(1)
        t = None if obj.time_ns is None else np.asarray(obj.time_ns, np.int64)[good]
        if t is not None and self.time_field is None:
            self.time_field, self.time_reference = "point_time_ns", "scan stamp"
        return Scan(xyz[good], t, None, obj.frame_id)


class OusterPacketStream(_Stream):
    """ouster_ros/PacketMsg lidar packets assembled into scans with the SDK."""

    role = "lidar"
    time_field = "ouster column timestamps"
    time_reference = "sensor clock, first valid column"

    def __init__(self, rec, topic, time, metadata_text: str):
        super().__init__(rec, topic, time)
        self.metadata_text = metadata_text
        self.asm = None
        self._decode = False

    def reset(self):
        super().reset()
        self.asm = None

    def _assembler(self, decode: bool):
        from ..readers.ouster import PacketAssembler

        if self.asm is None or self._decode != decode:
            self.asm = PacketAssembler(self.metadata_text, with_xyz=decode)
            self._decode = decode
        return self.asm

    def _item(self, scan, decode, want) -> Item:
        i = self._next()
        keep = decode and (want is None or i in want)
        return Item(i, scan.timestamp_ns, _ouster_to_scan(scan) if keep else None)

    def feed(self, raw, decode, check=False, want=None):
        asm = self._assembler(decode)
        msg = self.rec.decode(raw)
        scan = asm.add(msg.buf, raw.log_ns)
        return [] if scan is None else [self._item(scan, decode, want)]

    def flush(self, decode, want=None):
        if self.asm is None:
            return []
        scan = self.asm.flush()
        return [] if scan is None else [self._item(scan, decode, want)]

    def try_layout(self, raw):
        if self.layout is None and self.asm is not None:
            m = self.asm.meta
            self.layout = {"grid": (m.H, m.W), "time": True, "frame_id": "os_sensor"}


class DepthStream(_Stream):
    """Depth Image + CameraInfo -> points in the optical frame."""

    role = "camera"

    def __init__(self, rec, topic, time, info_topic: str, stride: int = 1):
        super().__init__(rec, topic, time)
        self.info_topic = info_topic
        self.stride = stride
        self.model = None

    @property
    def topics(self):
        return [self.topic, self.info_topic]

    def load_first_info(self) -> None:
        from ..readers.images import camera_model

        for raw in self.rec.raw_messages([self.info_topic]):
            try:
                self.model = camera_model(self.rec.decode(raw), self.info_topic)
                return
            except HolodataError:
                continue
        raise RecordingError(f"{self.rec.path}: camera info topic {self.info_topic} has no usable CameraInfo")

    _info_raw = None   # latest CameraInfo not decoded yet (decoded when an image is converted)

    def feed(self, raw, decode, check=False, want=None):
        if raw.topic == self.info_topic:
            if decode:
                self._info_raw = raw
            return []
        return super().feed(raw, decode, check, want)

    def _update_model(self) -> None:
        if self._info_raw is not None:
            from ..readers.images import camera_model

            raw, self._info_raw = self._info_raw, None
            with contextlib.suppress(HolodataError):
                self.model = camera_model(self.rec.decode(raw), self.info_topic)

    def convert(self, raw, keep):
        from ..readers.images import depth_image, depth_to_points

        self._update_model()
        msg = self.rec.decode(raw)
        d = depth_image(msg, self.topic)
        if not keep:
            return None
        pts, _ = depth_to_points(d, self.model.K, self.stride)
        return Scan(pts, None, None, str(msg.header.frame_id))


class StereoStream(DepthStream):
    """Rectified left/right images (+ their CameraInfo) -> depth by OpenCV SGBM -> points in the left
    optical frame. Pairs are the left and right images with the same header stamp."""

    def __init__(self, rec, topic, time, info_topic, stride, right_topic, right_info_topic):
        super().__init__(rec, topic, time, info_topic, stride)
        self.right_topic, self.right_info_topic = right_topic, right_info_topic
        self.baseline = None
        self.pending: dict[int, dict] = {}
        self.unpaired = 0

    @property
    def topics(self):
        return [self.topic, self.right_topic, self.info_topic, self.right_info_topic]

    def reset(self):
        super().reset()
        self.pending.clear()
        self.unpaired = 0

    def load_first_info(self) -> None:
        from ..readers.images import stereo_baseline

        super().load_first_info()
        for raw in self.rec.raw_messages([self.right_info_topic]):
            try:
                self.baseline = stereo_baseline(self.rec.decode(raw))
                return
            except (HolodataError, AttributeError, ValueError):
                continue
        raise RecordingError(f"{self.rec.path}: right camera info {self.right_info_topic} gives no stereo baseline")

    def feed(self, raw, decode, check=False, want=None):
        if raw.topic in (self.info_topic, self.right_info_topic):
            if raw.topic == self.info_topic:
                return super().feed(raw, decode, check, want)
            return []
        st = self.stamp(raw)
        side = "l" if raw.topic == self.topic else "r"
        slot = self.pending.setdefault(st, {})
        slot[side] = raw
        if len(slot) < 2:
            if len(self.pending) > 64:   # bounded: drop the oldest unpaired images
                self.unpaired += 1
                self.pending.pop(min(self.pending))
            return []
        del self.pending[st]
        i = self._next()
        if not decode or (want is not None and i not in want):
            return [Item(i, st)]
        try:
            return [Item(i, st, self._pair(slot["l"], slot["r"]))]
        except HolodataError as err:
            err.item = i
            raise

    def _pair(self, left_raw, right_raw) -> Scan:
        from ..readers.images import depth_to_points, gray_image, stereo_depth

        self._update_model()
        lm = self.rec.decode(left_raw)
        L = gray_image(lm, self.topic)
        R = gray_image(self.rec.decode(right_raw), self.right_topic)
        if L.shape != R.shape:
            raise DecodeError(f"topics {self.topic}/{self.right_topic}: stereo images differ in size {L.shape} vs {R.shape}")
        d = stereo_depth(L, R, float(self.model.K[0, 0]), self.baseline)
        pts, _ = depth_to_points(d, self.model.K, self.stride)
        return Scan(pts, None, None, str(lm.header.frame_id))

    def try_layout(self, raw):
        if self.layout is None and raw.topic == self.topic:
            self.layout = {"grid": None, "time": False, "frame_id": self.rec.decoder.frame_id(raw) if self.rec.decoder
                           else ""}
