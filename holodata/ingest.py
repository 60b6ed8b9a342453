"""``holodata ingest``: recordings -> dataset scenes (DESIGN §3), streaming and resumable.

Per recording (one scene each):

1. **Topic mapping** (:func:`map_topics`): radar = ``*/RadarHeatmap`` messages; LiDAR = a
   ``PointCloud2`` whose topic/frame does not look like a camera, Ouster pcap scans, or
   ``ouster_ros/PacketMsg`` packets + the driver's metadata ``String``; camera = a depth ``Image``
   (16UC1 mm / 32FC1 m) + its ``CameraInfo``, else a camera-looking ``PointCloud2``; TF =
   ``/tf`` and ``/tf_static``. A YAML file (``--topics``, see ``examples/topics.yaml``) overrides
   any role (``null`` switches a role off) and the options ``time``, ``world_frame``,
   ``base_frame``, ``camera_stride``.
2. **Index pass**: every message of the mapped topics is read undecoded; stamps come from the
   header bytes (``time: header``, default; 0 stamps fall back to the log time) or the log time
   (``time: log``). Messages of the sensor that defines the frames are decoded and checked here,
   so a frame exists only for a message that decodes.
3. **Sync**: frames are radar rotation cycles (radar header stamp), or LiDAR scans when there is
   no radar (``frame_sensor`` says which). Each frame takes the LiDAR scan and camera frame
   nearest in time within a tolerance (``--tolerance MS``; default per sensor: half its median period,
   at least 50 ms, so a sensor that kept publishing fills every frame); frames with none get an empty cloud and
   ``<sensor>/timestamp_ns`` = 0. Unmatched and failed messages are counted and reported.
4. **Write pass**: only the matched messages are decoded; shards are written as soon as all their
   frames have arrived (memory is a few shards, flat in recording size). Rerunning the same command
   resumes: finished shards are skipped (their messages are not decoded), a finished scene is
   skipped entirely.

Arrays: ``time/timestamp_ns``; ``radar/heatmap`` (T, R, H, W) as recorded (float16|float32 linear
amplitude), ``radar/cycle_ns`` (T, 2) [start, end]; ``lidar/points`` ragged (sensor frame; for
organised clouds the valid pixels of ``lidar/range`` in row-major order), ``lidar/point_time_ns``
ragged (per-point time relative to the scan stamp, when the cloud has a time field), ``lidar/range``
(T, Hl, Wl) float32 m, NaN = no return (organised clouds as published; Ouster scans destaggered),
``lidar/timestamp_ns``; ``camera/points`` ragged (sensor frame: optical frame for depth images),
``camera/timestamp_ns``; ``pose/T_world_radar`` when TF connects the radar frame to the world frame
at every frame time; ``tf/T_world_lidar`` when TF connects the LiDAR frame to a world frame (NaN
where TF does not cover a frame's scan: slam anchors its map to it). Scene attributes: ``frame_sensor``, ``source`` {recording, files, bytes,
sha256 (written with ``ingest.complete``), reader, truncated, problems}, ``extrinsics`` (T_base_sensor from static TF), ``sensors`` (topics,
frames, intrinsics, Ouster metadata), ``ingest`` (mapping, tolerance, counts, drops, warnings).

Truncated recordings (recorder crash, file cut short): the readable prefix is ingested and the
scene is marked ``source.truncated = true`` with the reason; ``ingest`` warns. Recordings with no
radar, point cloud, depth or Ouster topic (camera-only, IMU-only, strings, non-ROS MCAP) are
rejected with a one-line reason.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .conventions import Grid, RangeBins
from .dataset.validate import frames_not_finite_nonneg
from .errors import DatasetError, HolodataError, InputError, RecordingError
from .readers import open_recording, synth_output_folder
from .readers.base import POINTS_TYPE, RANGE_IMAGE_TYPE, DecodeError, RawMessage, Recording, TopicInfo

RADAR_SUFFIX = "/RadarHeatmap"
PC2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
CAMINFO = "sensor_msgs/msg/CameraInfo"
STRING = "std_msgs/msg/String"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
OUSTER_SCAN = "ouster/LidarScan"
OUSTER_PACKETS = ("ouster_ros/msg/PacketMsg", "ouster_sensor_msgs/msg/PacketMsg")  # ouster-ros < / >= 0.10
CAMERA_WORDS = ("camera", "cam", "zed", "realsense", "rgbd", "depth", "stereo", "optical", "kinect", "oak",
                "d435", "d455", "image")
ROLES = ("radar", "lidar", "lidar_metadata", "camera", "camera_info", "camera_right", "camera_info_right", "tf",
         "tf_static")
OPTIONS = ("time", "world_frame", "base_frame", "camera_stride")
DEFAULT_TOLERANCE_MS = 50.0
SHARD_TARGET_BYTES = 32 << 20
# Codec of the bulk arrays (radar/heatmap, lidar/range, lidar|camera/points, lidar/point_time_ns)
# unless --codec says otherwise; the small ones (time stamps, cycles, poses) keep the dataset's
# (zstd). Blosc lz4 + byte shuffle encodes ~1-2 GB/s on one core here against ~0.3-0.45 GB/s for
# zstd clevel 3, for ~5-10% larger output on float heatmaps and point clouds (benchmarks/ingest.py).
BULK_CODEC = "lz4"


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or err.__class__.__name__


# ==================================================================================================
# topic mapping

@dataclass
class TopicMap:
    """Which topic plays which role (None = not used) plus options."""

    radar: str | None = None
    lidar: str | None = None
    lidar_metadata: str | None = None
    camera: str | None = None
    camera_info: str | None = None
    camera_right: str | None = None
    camera_info_right: str | None = None
    tf: list[str] = field(default_factory=list)
    tf_static: list[str] = field(default_factory=list)
    time: str = "header"
    world_frame: str | None = None
    base_frame: str | None = None
    camera_stride: int = 1

    def to_dict(self) -> dict:
        return dict(vars(self))


def load_topics_file(path) -> dict:
    """The YAML mapping of ``--topics`` (see ``examples/topics.yaml``); InputError on bad content."""
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except OSError as err:
        raise InputError(f"{p}: cannot read topics file ({err.strerror})") from err
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        what = getattr(err, "problem", None) or _one_line(err)
        raise InputError(f"{p}: not valid YAML{where}: {what}") from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"{p}: topics file must be a mapping of role: topic")
    bad = [k for k in data if k not in ROLES + OPTIONS]
    if bad:
        raise InputError(f"{p}: unknown key(s) {', '.join(map(str, bad))} (roles: {', '.join(ROLES)}; "
                         f"options: {', '.join(OPTIONS)})")
    if data.get("time", "header") not in ("header", "log"):
        raise InputError(f"{p}: time must be 'header' or 'log', got {data.get('time')!r}")
    for k in ("tf", "tf_static"):
        if isinstance(data.get(k), str):
            data[k] = [data[k]]
    return data


def _camera_like(*names: str | None) -> bool:
    low = " ".join(n.lower() for n in names if n)
    return any(w in low for w in CAMERA_WORDS)


def _looks_static(name: str) -> bool:
    return "static" in name


def map_topics(rec: Recording, override: dict | None = None, topics: list[TopicInfo] | None = None
               ) -> tuple[TopicMap, list[str]]:
    """Guess the topic roles of ``rec`` (see module docstring), apply ``override``; returns the map
    and notes (one line each) about topics that look like sensors but are not used."""
    infos = topics if topics is not None else rec.topics(frame_ids=True)
    by = {t.name: t for t in infos}
    notes: list[str] = []
    m = TopicMap()
    usable = [t for t in infos if t.count > 0 and t.decodable]
    for t in infos:
        if t.count > 0 and not t.decodable:
            notes.append(f"topic {t.name}: {t.msgtype} x{t.count} skipped ({t.note or 'not decodable'})")
    radar = sorted((t for t in usable if t.msgtype.endswith(RADAR_SUFFIX)), key=lambda t: (-t.count, t.name))
    if radar:
        m.radar = radar[0].name
        notes += [f"topic {t.name}: second radar topic, not used" for t in radar[1:]]
    # LiDAR
    ouster = [t for t in usable if t.msgtype in (OUSTER_SCAN, RANGE_IMAGE_TYPE)]
    plain = [t for t in usable if t.msgtype == POINTS_TYPE]
    packets = [t for t in usable if t.msgtype in OUSTER_PACKETS and "imu" not in t.name.lower()]
    clouds = [t for t in usable if t.msgtype == PC2] + plain
    lidar_clouds = sorted((t for t in clouds if not _camera_like(t.name, t.frame_id)), key=lambda t: (-t.count, t.name))
    cam_clouds = sorted((t for t in clouds if _camera_like(t.name, t.frame_id)), key=lambda t: (-t.count, t.name))
    if ouster:
        m.lidar = ouster[0].name
    elif lidar_clouds:
        m.lidar = lidar_clouds[0].name
        notes += [f"topic {t.name}: another point cloud, not used (name it in --topics to choose)"
                  for t in lidar_clouds[1:]]
    elif packets:
        meta = [t for t in infos if t.msgtype == STRING and "metadata" in t.name.lower() and t.count > 0]
        if meta:
            m.lidar, m.lidar_metadata = packets[0].name, meta[0].name
        else:
            notes.append(f"topic {packets[0].name}: Ouster packets without a metadata String topic; not used")
    # camera: a depth image with camera info, else a camera point cloud
    images = [t for t in usable if t.msgtype == IMAGE]
    infos_ci = [t for t in usable if t.msgtype == CAMINFO]
    depth, not_depth = [], {}
    for t in images:
        ok, why = _probe_depth(rec, t.name)
        if ok:
            depth.append(t)
        else:
            not_depth[t.name] = why
    if depth:
        depth.sort(key=lambda t: (0 if "depth" in t.name.lower() else 1, -t.count, t.name))
        m.camera = depth[0].name
        m.camera_info = _camera_info_for(depth[0], infos_ci)
        if m.camera_info is None:
            notes.append(f"topic {m.camera}: depth image without a CameraInfo topic; not used")
            m.camera = None
    if m.camera is None and cam_clouds:
        m.camera = cam_clouds[0].name
        m.camera_info = _camera_info_for(cam_clouds[0], infos_ci)   # (used when it fits the cloud's pixels)
    if m.camera is None:  # only images: a rectified stereo pair (left/right + CameraInfo) gives depth
        for t in sorted(images, key=lambda t: t.name):
            right = t.name.replace("left", "right")
            if "left" in t.name and right != t.name and right in by and by[right].msgtype == IMAGE \
                    and "truncated" not in not_depth.get(t.name, "") + not_depth.get(right, ""):
                li, ri = _camera_info_for(t, infos_ci), _camera_info_for(by[right], infos_ci)
                if li and ri and li != ri:
                    m.camera, m.camera_info, m.camera_right, m.camera_info_right = t.name, li, right, ri
                    not_depth.pop(t.name, None)
                    not_depth.pop(right, None)
                    break
    notes += list(not_depth.values())
    for t in usable:
        if t.msgtype in TF_TYPES:
            (m.tf_static if _looks_static(t.name) else m.tf).append(t.name)
    if override:
        _apply_override(m, override, by, rec)
    used = {v for r in ROLES for v in ([getattr(m, r)] if isinstance(getattr(m, r), str) else getattr(m, r) or [])}
    notes = [n for n in notes if not any(f"topic {t}:" in n for t in used)]
    return m, notes


def _probe_depth(rec: Recording, topic: str) -> tuple[bool, str]:
    """(is a usable depth image topic, why not) from its first message."""
    from .readers.images import depth_image, image_array, is_depth_encoding

    try:
        raw = next(iter(rec.raw_messages([topic])))
        msg = rec.decode(raw)
        if not is_depth_encoding(str(msg.encoding)):
            image_array(msg, topic)  # a truncated payload is reported as such
            return False, f"topic {topic}: Image {msg.encoding} is not a depth image (16UC1/32FC1); not used"
        depth_image(msg, topic)
    except StopIteration:
        return False, f"topic {topic}: no messages"
    except HolodataError as err:
        return False, f"{_one_line(err)}; topic skipped"
    return True, ""


def _camera_info_for(img: TopicInfo, infos: list[TopicInfo]) -> str | None:
    if not infos:
        return None
    ns = img.name.rsplit("/", 1)[0]
    same_ns = [t for t in infos if t.name.rsplit("/", 1)[0] == ns]
    same_frame = [t for t in infos if img.frame_id and t.frame_id == img.frame_id]
    for group in (same_ns, same_frame, infos):
        if group:
            return sorted(group, key=lambda t: t.name)[0].name
    return None


def _apply_override(m: TopicMap, ov: dict, by: dict[str, TopicInfo], rec: Recording) -> None:
    for k, v in ov.items():
        if k in ("tf", "tf_static"):
            v = [] if v is None else list(v)
            for name in v:
                _check_topic(name, by, rec)
            setattr(m, k, v)
        elif k in ROLES:
            if v is not None:
                _check_topic(str(v), by, rec)
            setattr(m, k, None if v is None else str(v))
        elif k == "camera_stride":
            if not isinstance(v, int) or v < 1:
                raise InputError(f"topics file: camera_stride must be an integer >= 1, got {v!r}")
            m.camera_stride = v
        else:
            setattr(m, k, v)
    if m.lidar and by[m.lidar].msgtype in OUSTER_PACKETS and not m.lidar_metadata:
        raise InputError(f"topics file: lidar {m.lidar} carries Ouster packets; name the metadata String topic "
                         f"as lidar_metadata")
    if m.camera and by[m.camera].msgtype == IMAGE and not m.camera_info:
        raise InputError(f"topics file: camera {m.camera} is an Image; name its CameraInfo topic as camera_info")
    if m.camera_right and not m.camera_info_right:
        raise InputError(f"topics file: camera_right {m.camera_right} needs its CameraInfo as camera_info_right")


def _check_topic(name: str, by: dict[str, TopicInfo], rec: Recording) -> None:
    if name not in by:
        have = ", ".join(sorted(by)[:12])
        raise InputError(f"topics file: {name} is not a topic of {rec.path} (have: {have}{' ...' if len(by) > 12 else ''})")


# ==================================================================================================
# streams: one per sensor role; ``feed`` turns raw messages into items (one per scan / frame)

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
            payload = self.convert(raw, keep=decode)
        except HolodataError as err:
            err.item = i
            raise
        except Exception as err:  # noqa: BLE001 - damaged bytes deserialise into garbage of any shape
            bad = DecodeError(f"topic {self.topic}: message at {raw.log_ns} ns does not decode "
                              f"({err.__class__.__name__}: {' '.join(str(err).split())[:100]}; damaged message?)")
            bad.item = i
            raise bad from err
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


def radar_beam_origin(msg, topic: str = "radar"):
    """The beam-origin model (:class:`holodata.beams.OriginModel`) a RadarHeatmap message states:
    ``range_origin`` "rotation_centre" (or empty, as in recordings older than the field) → ranges
    from the rotation centre; "antenna" → from the rotation circle of ``rotation_radius``. Columns
    are formed at their own times within ``cycle_start_ns``..``cycle_end_ns`` either way."""
    from .beams import OriginModel
    from .messages import RANGE_ORIGINS

    ro = str(getattr(msg, "range_origin", "") or "rotation_centre")
    if ro not in RANGE_ORIGINS:
        raise DecodeError(f"topic {topic}: RadarHeatmap range_origin {ro!r} is not one of {', '.join(RANGE_ORIGINS)}")
    return OriginModel(float(msg.rotation_radius) if ro == "antenna" else 0.0, column_time=True)


@dataclass
class RadarFrame:
    heatmap: np.ndarray      # (R, H, W) float16|float32
    cycle: tuple[int, int]
    iq: object = None        # readers of raw samples: the RawRotation (stored with --keep-iq)


class RadarStream(_Stream):
    role = "radar"

    def __init__(self, rec, topic, time):
        super().__init__(rec, topic, time)
        self.shape = None
        self.dtype = None
        self.first = None     # first decoded message (for grid / attrs)

    def convert(self, raw, keep):
        msg = self.rec.decode(raw)
        enc = str(msg.encoding)
        dt = {"float16": np.dtype("<f2"), "float32": np.dtype("<f4")}.get(enc)
        if dt is None:
            raise DecodeError(f"topic {self.topic}: RadarHeatmap encoding {enc!r} is not float16/float32")
        shape = (int(msg.n_range), int(msg.n_elevation), int(msg.n_azimuth))
        n = int(np.prod(shape)) * dt.itemsize
        data = msg.data
        size = data.size if isinstance(data, np.ndarray) else len(data)
        if size != n:
            raise DecodeError(f"topic {self.topic}: RadarHeatmap payload is {size} bytes, {shape} {enc} needs {n}")
        if self.first is None:
            radar_beam_origin(msg, self.topic)  # an unknown range_origin stops here, naming the topic
            self.first = msg
            self.shape, self.dtype = shape, dt
        elif shape != self.shape:
            raise DecodeError(f"topic {self.topic}: RadarHeatmap shape {shape} differs from the first message's "
                              f"{self.shape}")
        buf = data if isinstance(data, np.ndarray) else np.frombuffer(bytes(data), np.uint8)
        hm = buf.view(dt).reshape(shape)
        # the layout's value rule (validate's): a heatmap with NaN/inf or negative amplitudes is a
        # damaged message, dropped here (counted) rather than written into a dataset validate rejects
        if len(frames_not_finite_nonneg(hm[None])):
            raise DecodeError(f"topic {self.topic}: RadarHeatmap at {raw.log_ns} ns holds NaN/inf or negative "
                              f"amplitudes (damaged message)")
        if not keep:
            return None
        return RadarFrame(hm, (int(msg.cycle_start_ns), int(msg.cycle_end_ns)), getattr(msg, "iq", None))


@dataclass
class Scan:
    """A decoded LiDAR scan or camera frame: points (N,3) float32 sensor frame; optional per-point
    time (N,) int64 ns; optional grid (Hl, Wl) float32 range (NaN none)."""

    points: np.ndarray
    time_ns: np.ndarray | None = None
    grid: np.ndarray | None = None
    frame_id: str = ""


class CloudStream(_Stream):
    """PointCloud2 (LiDAR or camera)."""

    def __init__(self, rec, topic, time, role):
        super().__init__(rec, topic, time)
        self.role = role
        self.time_field = None
        self.time_reference = None
        self.organised = None

    def convert(self, raw, keep):
        from .readers.pointcloud2 import check_pointcloud2, decode_pointcloud2

        msg = self.rec.decode(raw)
        if not keep:
            check_pointcloud2(msg, self.topic)
            return None
        c = decode_pointcloud2(msg, self.topic, fields=(), time=self.role == "lidar")
        if self.time_field is None and c.time_field:
            self.time_field, self.time_reference = c.time_field, c.time_reference
        grid = None
        if c.organised and self.role == "lidar":
            r = np.linalg.norm(c.xyz, axis=1).astype(np.float32)
            grid = c.grid(r)
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
        from .readers.images import camera_model, fit_pinhole, pinhole_residual
        from .readers.pointcloud2 import decode_pointcloud2

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
            from .readers.images import CameraModel

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
        from .readers.ouster import PacketAssembler

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
        from .readers.images import camera_model

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
            from .readers.images import camera_model

            raw, self._info_raw = self._info_raw, None
            try:
                self.model = camera_model(self.rec.decode(raw), self.info_topic)
            except HolodataError:
                pass

    def convert(self, raw, keep):
        from .readers.images import depth_image, depth_to_points

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
        from .readers.images import stereo_baseline

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
        from .readers.images import depth_to_points, gray_image, stereo_depth

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


# ==================================================================================================
# planning: mapping, index pass, sync

@dataclass
class Plan:
    rec: Recording
    scene_id: str
    tmap: TopicMap
    notes: list[str]
    frame_sensor: str
    streams: dict           # role -> stream
    frame_stamps: np.ndarray  # (T,) int64
    frame_items: np.ndarray   # (T,) item index of the frame sensor
    match: dict               # role -> (T,) item index or -1
    match_stamp: dict         # role -> (T,) stamp or 0
    counts: dict
    dropped: dict
    warnings: list[str]
    grid: Grid | None = None
    range_bins: RangeBins | None = None
    tf: object = None
    probe: dict = field(default_factory=dict)
    sha256: list = field(default_factory=list)
    sha_future: object = None
    index_seconds: float = 0.0
    tolerance_ns: dict = field(default_factory=dict)
    keep_iq: bool = False     # also store the raw radar samples (readers of raw radar only)


def _reject_reason(rec: Recording, infos: list[TopicInfo], tmap: TopicMap, notes: list[str]) -> str:
    with_msgs = [t for t in infos if t.count]
    summary = ", ".join(f"{t.name} {t.msgtype.split('/')[-1]} x{t.count}" for t in with_msgs[:5])
    if len(with_msgs) > 5:
        summary += f", ... ({len(with_msgs)} topics)"
    types = {t.msgtype for t in with_msgs}
    if tmap.camera:
        return (f"{rec.path}: camera-only recording (camera {tmap.camera}, no radar or LiDAR topic); holodata frames "
                f"are radar rotations or LiDAR scans, so there is nothing to ingest")
    if any(ty.endswith("/Imu") for ty in types) and not types & {PC2, IMAGE}:
        return (f"{rec.path}: IMU/odometry-only recording ({summary}); ingest needs a radar, point cloud, depth "
                f"image or Ouster topic")
    missing = [t for t in with_msgs if not t.decodable and "--msg-dir" in t.note]
    if missing:
        names = ", ".join(f"{t.name} ({t.msgtype})" for t in missing[:3])
        return (f"{rec.path}: no usable sensor topic; {len(missing)} topic(s) have no message definition ({names}"
                f"{' ...' if len(missing) > 3 else ''}): pass --msg-dir with their .msg files")
    if with_msgs and all(not t.decodable for t in with_msgs):
        why = next((t.note for t in with_msgs if t.note), "")
        return f"{rec.path}: no decodable topic ({why}); nothing to ingest"
    extra = f"; {notes[0]}" if notes else ""
    return (f"{rec.path}: no radar, point cloud, depth image or Ouster topic ({summary or 'no messages'}){extra}; "
            f"nothing to ingest")


def _scene_id(path: Path) -> str:
    """Scene id from a recording's file or folder name; a synth recording (``OUT/recording``
    beside ``OUT/truth/``) or a synth output folder is named after ``OUT``."""
    p = synth_output_folder(path) or Path(path)
    name = p.name if p.is_dir() else p.stem
    sid = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "scene"
    return sid


def file_sha256(paths: list[Path]) -> list[str]:
    out = []
    for p in paths:
        h = hashlib.sha256()
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(4 << 20), b""):
                h.update(block)
        out.append(h.hexdigest())
    return out


def _tolerance_ns(tolerance_ms: float | None, stamps: np.ndarray) -> int:
    """``tolerance_ms`` if given; else auto: half the sensor's median period, at least 50 ms (every
    frame then gets the nearest message of a sensor that kept publishing)."""
    if tolerance_ms is not None:
        return int(round(tolerance_ms * 1e6))
    auto = int(round(DEFAULT_TOLERANCE_MS * 1e6))
    if len(stamps) > 1:
        d = np.diff(np.sort(stamps))
        d = d[d > 0]
        if len(d):
            auto = max(auto, int(np.median(d)) // 2 + 1)
    return auto


def _nearest(frame_t: np.ndarray, item_t: np.ndarray, tol_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """For each frame time the index (into item_t, sorted) of the nearest item within tol, else -1;
    and the offset item - frame (0 where none)."""
    idx = np.full(len(frame_t), -1, np.int64)
    off = np.zeros(len(frame_t), np.int64)
    if len(item_t) == 0 or len(frame_t) == 0:
        return idx, off
    j = np.searchsorted(item_t, frame_t)
    lo = np.clip(j - 1, 0, len(item_t) - 1)
    hi = np.clip(j, 0, len(item_t) - 1)
    d_lo = np.abs(item_t[lo] - frame_t)
    d_hi = np.abs(item_t[hi] - frame_t)
    best = np.where(d_hi < d_lo, hi, lo)
    d = np.abs(item_t[best] - frame_t)
    ok = d <= tol_ns
    idx[ok] = best[ok]
    off[ok] = (item_t[best] - frame_t)[ok]
    return idx, off


def plan_recording(path, topics: dict | None = None, scene_id: str | None = None, msg_dir=None,
                   tolerance_ms: float | None = None, meta=None, quiet: bool = True, beamform=None,
                   keep_iq: bool = False) -> Plan:
    """Open, map, index and sync one recording (nothing written). RecordingError if unusable.
    ``beamform``: :class:`~holodata.radar.beamform.BeamformParams` for recordings of raw radar samples;
    ``keep_iq``: also store those samples (``radar/iq``, for ``holodata beamform``)."""
    from .progress import track

    from concurrent.futures import ThreadPoolExecutor

    _limit_malloc_arenas()
    rec = open_recording(path, msg_dir=msg_dir, meta=meta, beamform=beamform)
    pool = ThreadPoolExecutor(1)   # checksums overlap the index pass (hashlib releases the GIL)
    sha = pool.submit(file_sha256, rec.files)
    pool.shutdown(wait=False)
    try:
        plan = _plan(rec, topics, scene_id, tolerance_ms, quiet, track)
    except BaseException:
        sha.cancel()
        rec.close()
        raise
    plan.sha_future = sha
    if keep_iq and hasattr(rec, "iq_shape") and "radar" in plan.streams:
        plan.keep_iq = True
    elif keep_iq:
        plan.warnings.append(f"{rec.path}: no raw radar samples in this recording; --keep-iq has nothing to keep")
    return plan


def _plan(rec, topics, scene_id, tolerance_ms, quiet, track) -> Plan:
    infos = rec.topics(frame_ids=True)
    tmap, notes = map_topics(rec, topics, infos)
    by = {t.name: t for t in infos}
    warnings: list[str] = list(rec.problems)
    if not tmap.radar and not tmap.lidar:
        raise RecordingError(_reject_reason(rec, infos, tmap, notes))
    streams: dict[str, _Stream] = {}
    if tmap.radar:
        streams["radar"] = RadarStream(rec, tmap.radar, tmap.time)
    if tmap.lidar:
        ty = by[tmap.lidar].msgtype
        if ty == OUSTER_SCAN:
            streams["lidar"] = OusterScanStream(rec, tmap.lidar, tmap.time)
        elif ty == RANGE_IMAGE_TYPE:
            streams["lidar"] = GridStream(rec, tmap.lidar, tmap.time)
        elif ty == POINTS_TYPE:
            streams["lidar"] = PointsStream(rec, tmap.lidar, tmap.time, "lidar")
        elif ty in OUSTER_PACKETS:
            text = _first_string(rec, tmap.lidar_metadata)
            try:
                from .readers.ouster import load_info

                load_info(text)
            except HolodataError as err:
                raise RecordingError(f"{rec.path}: Ouster packets on {tmap.lidar} cannot be decoded: "
                                     f"{_one_line(err)}") from err
            streams["lidar"] = OusterPacketStream(rec, tmap.lidar, tmap.time, text)
        elif ty == PC2:
            streams["lidar"] = CloudStream(rec, tmap.lidar, tmap.time, "lidar")
        else:
            raise InputError(f"topics file: lidar {tmap.lidar} is a {ty}, not PointCloud2 / Ouster")
    if tmap.camera:
        ty = by[tmap.camera].msgtype
        if ty == IMAGE and tmap.camera_right:
            st = StereoStream(rec, tmap.camera, tmap.time, tmap.camera_info, tmap.camera_stride, tmap.camera_right,
                              tmap.camera_info_right)
            try:
                st.load_first_info()
                streams["camera"] = st
            except HolodataError as err:
                warnings.append(f"{_one_line(err)}; camera not used")
        elif ty == IMAGE:
            st = DepthStream(rec, tmap.camera, tmap.time, tmap.camera_info, tmap.camera_stride)
            try:
                st.load_first_info()
                streams["camera"] = st
            except HolodataError as err:
                warnings.append(f"{_one_line(err)}; camera not used")
        elif ty == PC2:
            st = CameraCloudStream(rec, tmap.camera, tmap.time, tmap.camera_info)
            note = st.load_model()
            if note:
                warnings.append(note)
            streams["camera"] = st
        elif ty == POINTS_TYPE:
            streams["camera"] = PointsStream(rec, tmap.camera, tmap.time, "camera")
        else:
            raise InputError(f"topics file: camera {tmap.camera} is a {ty}, not Image / PointCloud2")
    frame_sensor = "radar" if "radar" in streams else "lidar"
    if frame_sensor == "lidar" and "lidar" not in streams:
        raise RecordingError(_reject_reason(rec, infos, tmap, notes))
    # ---- index pass (TF read along: static + dynamic buffer)
    from .readers.tf import TransformBuffer

    tf = TransformBuffer()
    tf_static = set(tmap.tf_static)
    tf_topics = set(tmap.tf) | tf_static
    tf_bad = 0
    stamps: dict[str, list[tuple[int, int]]] = {r: [] for r in streams}
    failed: dict[str, dict[int, str]] = {r: {} for r in streams}
    by_topic = {}
    for role, st in streams.items():
        for tp in st.topics:
            by_topic[tp] = st
    topics_read = list(by_topic) + sorted(tf_topics - set(by_topic))
    total = sum(by[t].count for t in topics_read if t in by)
    heads = _head_topics(streams)
    index_iter = rec.raw_messages(topics_read, with_xyz=False) if rec.kind == "ouster-pcap" \
        else rec.raw_heads(topics_read, heads)
    t_index = time.perf_counter()
    for raw in track(index_iter, total, f"ingest {scene_id or rec.path.name}: index", quiet, unit="messages"):
        if raw.topic in tf_topics:
            try:
                tf.add_message(rec.decode(raw), static=raw.topic in tf_static)
            except (HolodataError, AttributeError, ValueError):
                tf_bad += 1
            if raw.topic not in by_topic:
                continue
        st = by_topic[raw.topic]
        try:
            items = st.feed(raw, decode=False, check=(st.role == frame_sensor))
        except HolodataError as err:
            failed[st.role][getattr(err, "item", -1)] = _one_line(err)
            continue
        if st.role != "radar" and st.layout is None:
            st.try_layout(raw)
        stamps[st.role] += [(it.index, it.stamp) for it in items]
    if tf_bad:
        warnings.append(f"{tf_bad} TF messages do not decode; skipped")
    t_index = time.perf_counter() - t_index
    for role, st in streams.items():
        stamps[role] += [(it.index, it.stamp) for it in st.flush(decode=False)]

    counts = {r: len(v) + len(failed[r]) for r, v in stamps.items()}
    dropped: dict[str, dict] = {r: {} for r in streams}
    for role, f in failed.items():
        if f:
            dropped[role]["undecodable"] = len(f)
            first = next(iter(f.values()))
            warnings.append(f"{len(f)} of {counts[role]} {role} messages on {streams[role].topic} do not decode "
                            f"(first: {first}); skipped")
    # ---- frames
    fr = np.array(sorted(stamps[frame_sensor], key=lambda x: (x[1], x[0])), np.int64).reshape(-1, 2)
    if len(fr) == 0:
        reason = next(iter(failed[frame_sensor].values()), "no messages")
        raise RecordingError(f"{rec.path}: no usable {frame_sensor} message on {streams[frame_sensor].topic} "
                             f"({reason})")
    keep = np.r_[True, fr[1:, 1] > fr[:-1, 1]]
    if not keep.all():
        dropped[frame_sensor]["duplicate_stamp"] = int((~keep).sum())
        warnings.append(f"{int((~keep).sum())} {frame_sensor} messages repeat an earlier stamp; dropped")
    fr = fr[keep]
    frame_items, frame_stamps = fr[:, 0], fr[:, 1]
    match, match_stamp, tolerance = {}, {}, {}
    for role in streams:
        if role == frame_sensor:
            continue
        arr = np.array(sorted(stamps[role], key=lambda x: (x[1], x[0])), np.int64).reshape(-1, 2)
        tol = _tolerance_ns(tolerance_ms, arr[:, 1])
        tolerance[role] = tol
        j, off = _nearest(frame_stamps, arr[:, 1], tol)
        match[role] = np.where(j >= 0, arr[np.clip(j, 0, None), 0] if len(arr) else -1, -1)
        match_stamp[role] = np.where(j >= 0, arr[np.clip(j, 0, None), 1] if len(arr) else 0, 0)
        used = len(set(match[role][match[role] >= 0].tolist()))
        unmatched_frames = int((j < 0).sum())
        dropped[role]["not_near_a_frame"] = len(arr) - used
        if unmatched_frames:
            dropped[role]["frames_without"] = unmatched_frames
            warnings.append(f"{unmatched_frames} of {len(frame_stamps)} frames have no {role} message within "
                            f"{tol / 1e6:g} ms")
    plan = Plan(rec, scene_id or _scene_id(rec.path), tmap, notes, frame_sensor, streams, frame_stamps, frame_items,
                match, match_stamp, counts, dropped, warnings, tf=tf, index_seconds=t_index, tolerance_ns=tolerance)
    if "radar" in streams:
        plan.grid, plan.range_bins = _grid_of(rec, streams["radar"])
    plan.probe = {r: st.layout for r, st in streams.items() if r != "radar" and st.layout is not None}
    return plan


def _head_topics(streams: dict) -> set[str]:
    """Topics whose messages both passes may read header-only (``Recording.raw_heads``): one
    message = one item, stamped from its header; ``Recording.decode`` reads the rest of a message
    that is decoded after all (the frame sensor's check, a matched scan or image, a layout probe).
    Unmatched LiDAR scans and camera images are then never read whole."""
    return {st.topic for st in streams.values() if type(st) in (RadarStream, CloudStream, DepthStream)}


def _first_string(rec: Recording, topic: str | None) -> str:
    if not topic:
        raise RecordingError(f"{rec.path}: Ouster packets need the sensor metadata (a String topic)")
    for raw in rec.raw_messages([topic]):
        try:
            return str(rec.decode(raw).data)
        except HolodataError:
            continue
    raise RecordingError(f"{rec.path}: metadata topic {topic} has no readable String message")


# ==================================================================================================
# writing

class _Background:
    """Shard writes (Blosc compression, sha256, file put) on ``workers`` threads, overlapping the
    main thread's reading and decoding (Blosc, hashlib and file writes release the GIL). Shard
    data queued or in flight is bounded by ``budget`` bytes (a larger shard waits until nothing
    else is in flight), so memory stays flat whatever the recording size. Jobs with the same
    ``key`` (one ragged array: shards append in order) run in submit order: each waits for its
    predecessor, which was submitted, and so dequeued, earlier (FIFO), so the wait cannot
    deadlock. Errors surface on the next submit or on :meth:`join`; :meth:`close` always waits for
    the writes in progress."""

    def __init__(self, workers: int = 2, budget: int = SHARD_TARGET_BYTES + (SHARD_TARGET_BYTES >> 1)):
        import threading
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(workers, thread_name_prefix="holodata-ingest-writer")
        self.cond = threading.Condition()
        self.budget, self.inflight = int(budget), 0
        self.futures: list = []
        self.last: dict = {}
        self.seconds = 0.0    # busy time summed over the workers

    def _run(self, fn, prev, nbytes: int) -> None:
        try:
            if prev is not None:
                prev.result()
            t = time.perf_counter()
            fn()
            with self.cond:
                self.seconds += time.perf_counter() - t
        finally:
            with self.cond:
                self.inflight -= nbytes
                self.cond.notify_all()

    def _raise(self) -> None:
        pending = []
        for f in self.futures:
            if f.done():
                f.result()
            else:
                pending.append(f)
        self.futures = pending

    def submit(self, fn, key=None, nbytes: int = 0) -> None:
        self._raise()
        with self.cond:
            while self.inflight and self.inflight + nbytes > self.budget:
                self.cond.wait()
            self.inflight += nbytes
        fut = self.pool.submit(self._run, fn, self.last.get(key) if key is not None else None, nbytes)
        if key is not None:
            self.last[key] = fut
        self.futures.append(fut)

    def join(self) -> None:
        for f in self.futures:
            f.result()
        self.futures = []

    def close(self) -> None:
        self.pool.shutdown(wait=True)


class _Out:
    """Buffers one array's frames and writes each shard once all its frames are in."""

    def __init__(self, writer, ragged: bool, default, expected: set[int], bg: _Background | None = None):
        self.bg = bg
        self.w, self.ragged, self.default = writer, ragged, default
        self.expected = expected
        self.buf: dict[int, object] = {}
        self.done = {k for k in range(writer.n_shards) if writer.is_done(k)}   # resumed: finished shards
        self.k = 0
        self.written = 0
        self.seconds = 0.0

    def shard_done(self, frame: int) -> bool:
        return frame // self.w.shard_frames in self.done

    def put(self, frame: int, data) -> None:
        if not self.shard_done(frame):
            self.buf[frame] = data

    def fail(self, frame: int) -> None:
        self.expected.discard(frame)

    def flush(self, final: bool = False) -> None:
        while self.k < self.w.n_shards:
            sl = self.w.frames(self.k)
            if self.k in self.done:
                self.k += 1
                continue
            frames = range(sl.start, sl.stop)
            if not final and any(f in self.expected and f not in self.buf for f in frames):
                return
            data = [self.buf.pop(f) if f in self.buf else self.default() for f in frames]
            # bound now: the job may run after this loop has moved on (frame arrays take the list: no stack copy)
            job = lambda k=self.k, w=self.w, data=data: w.write_shard(k, data)   # noqa: E731
            if self.bg is not None:
                self.bg.submit(job, key=id(self) if self.ragged else None,
                               nbytes=sum(getattr(a, "nbytes", 0) for a in data))
            else:
                t = time.perf_counter()
                job()
                self.seconds += time.perf_counter() - t
            self.done.add(self.k)
            self.written += 1
            self.k += 1


def _shard_frames(per_frame_bytes: int, default: int) -> int:
    return int(max(1, min(default, SHARD_TARGET_BYTES // max(1, per_frame_bytes))))


def _limit_malloc_arenas(n: int = 1) -> None:
    """glibc gives each thread that allocates under contention its own malloc arena (up to 8 per
    core); the writer threads free many ~1-2 MB buffers (message payloads, Blosc chunks) that then
    fragment those arenas, so peak RSS crept up with recording length (4x recording: +20%,
    benchmarks/ingest.py). One arena for the threads started from here on: +5-10%. No-op off glibc."""
    global _ARENAS_LIMITED
    if _ARENAS_LIMITED:
        return
    _ARENAS_LIMITED = True
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-8, int(n))   # M_ARENA_MAX
    except (OSError, AttributeError, TypeError):
        pass


_ARENAS_LIMITED = False


def write_plan(plan: Plan, ds, quiet: bool = True, codec: str | None = None) -> dict:
    """Pass 2: decode the matched messages and write scene ``plan.scene_id`` into writer ``ds``."""
    _limit_malloc_arenas()
    bg = _Background()
    try:
        return _write_plan(plan, ds, quiet, codec, bg)
    finally:
        bg.close()   # also on errors/interrupts: the shard write in progress finishes before we return


def _write_plan(plan: Plan, ds, quiet: bool, codec: str | None, bg: _Background) -> dict:
    from .progress import track

    rec, T = plan.rec, len(plan.frame_stamps)
    fs = plan.frame_sensor

    def sha256() -> list[str]:
        """The recording files' sha256, hashed on a thread since plan_recording: waited for only
        when a resumed scene must be compared, else at the end (overlapping the write pass)."""
        if not plan.sha256:
            plan.sha256 = plan.sha_future.result() if plan.sha_future is not None else file_sha256(rec.files)
        return plan.sha256

    sizes = []
    for f in rec.files:
        try:
            sizes.append(Path(f).stat().st_size)
        except OSError:
            sizes.append(None)
    # sha256 goes in with the final attributes (ingest.complete); "bytes" tells an interrupted run's
    # scene from another recording's before then
    source = {"recording": str(rec.path), "files": [str(f) for f in rec.files], "bytes": sizes,
              "reader": rec.kind, "truncated": bool(rec.truncated), **(getattr(rec, "attrs", None) or {}),
              **({"problems": rec.problems[:20]} if rec.problems else {})}
    # what the frames and their contents depend on: a resumed run must agree
    fingerprint = hashlib.sha256(json.dumps(
        {"topics": plan.tmap.to_dict(), "tolerance_ns": plan.tolerance_ns, "frames": plan.frame_stamps.tolist(),
         "match": {r: v.tolist() for r, v in plan.match.items()}}, sort_keys=True).encode()).hexdigest()
    existing = ds.scene_ids()
    if plan.scene_id in existing:
        cur = ds.scene(plan.scene_id).attrs
        src = cur.get("source") if isinstance(cur.get("source"), dict) else {}
        have = src.get("sha256")
        if (have and have != sha256()) or (not have and src.get("bytes") not in (None, sizes)):
            raise DatasetError(f"{ds.url}: scene {plan.scene_id!r} was ingested from another recording "
                               f"({(cur.get('source') or {}).get('recording')}); choose another --scene-id")
        prev = (cur.get("ingest") or {}).get("fingerprint")
        if prev and prev != fingerprint:
            raise DatasetError(f"{ds.url}: scene {plan.scene_id!r} was started with other topics/tolerance; rerun with "
                               f"the same options or choose another --scene-id")
        if (cur.get("ingest") or {}).get("complete"):
            return {"scene": plan.scene_id, "frames": T, "skipped": "already ingested"}
    attrs = {"frame_sensor": fs, "source": source, "sensors": _sensor_attrs(plan),
             "extrinsics": _extrinsics(plan),
             "ingest": {"complete": False, "topics": plan.tmap.to_dict(), "fingerprint": fingerprint}}
    sc = ds.scene(plan.scene_id, n_frames=T, attrs=attrs)
    S = ds.shard_frames
    outs: dict[str, _Out] = {}
    arrays = []

    bulk = codec or BULK_CODEC

    def frame_arr(name, shape, dtype, dims, units, codec=codec, **kw):
        arrays.append(name)
        return sc.frame_array(name, per_frame_shape=shape, dtype=dtype, dims=dims, units=units, codec=codec, **kw)

    # small arrays known now
    ts = frame_arr("time/timestamp_ns", (), "int64", ["frame"], "ns")
    for k in range(ts.n_shards):
        ts.write_shard(k, plan.frame_stamps[ts.frames(k)])
    # per-role expected frames
    exp: dict[str, dict[int, list[int]]] = {}     # role -> item index -> frames
    for role in plan.streams:
        items = plan.frame_items if role == fs else plan.match[role]
        d: dict[int, list[int]] = {}
        for f, i in enumerate(items.tolist()):
            if i >= 0:
                d.setdefault(i, []).append(f)
        exp[role] = d
    if "radar" in plan.streams:
        rs = plan.streams["radar"]
        shape = rs.shape
        fb = int(np.prod(shape)) * rs.dtype.itemsize
        hm = frame_arr("radar/heatmap", shape, rs.dtype.newbyteorder("="), ["frame", "range", "elevation", "azimuth"],
                       "1", shard_frames=_shard_frames(fb, S), fill_value=float("nan"), codec=bulk,
                       attrs={"amplitude": "linear", "topic": rs.topic})
        outs["radar/heatmap"] = _Out(hm, False, lambda: np.full(shape, np.nan, rs.dtype), set(range(T)), bg)
        cyc = frame_arr("radar/cycle_ns", (2,), "int64", ["frame", "start_end"], "ns")
        outs["radar/cycle_ns"] = _Out(cyc, False, lambda: np.zeros(2, np.int64), set(range(T)), bg)
        if plan.keep_iq:
            _iq_outputs(plan, sc, frame_arr, outs, T, S, bg)
            arrays.append("radar/iq_static")
    for role in ("lidar", "camera"):
        if role not in plan.streams:
            continue
        frames_with = {f for fl in exp[role].values() for f in fl}
        pts = sc.ragged_array(f"{role}/points", width=3, dtype="float32", units="m", codec=bulk)
        arrays.append(f"{role}/points")
        outs[f"{role}/points"] = _Out(pts, True, lambda: np.zeros((0, 3), np.float32), set(frames_with), bg)
        pr = plan.probe.get(role) or {}
        if role == "lidar" and pr.get("time"):
            pt = sc.ragged_array("lidar/point_time_ns", width=1, dtype="int64", units="ns", dims=["point", "time"],
                                 codec=bulk)
            arrays.append("lidar/point_time_ns")
            outs["lidar/point_time_ns"] = _Out(pt, True, lambda: np.zeros((0, 1), np.int64), set(frames_with), bg)
        if role == "lidar" and pr.get("grid"):
            gshape = tuple(pr["grid"])
            lr = frame_arr("lidar/range", gshape, "float32", ["frame", "beam", "column"], "m",
                           shard_frames=_shard_frames(4 * int(np.prod(gshape)), S), codec=bulk)
            outs["lidar/range"] = _Out(lr, False, lambda: np.full(gshape, np.nan, np.float32), set(frames_with), bg)
    # which items to decode: frames of unfinished shards only (resume)
    want: dict[str, set[int]] = {}
    for role, d in exp.items():
        names = [n for n in outs if n.startswith(role + "/")]
        w = set()
        for i, fl in d.items():
            if any(not outs[n].shard_done(f) for n in names for f in fl):
                w.add(i)
        want[role] = w
    stamp_out = [role for role in plan.streams if role != "radar"]
    decoded = {r: 0 for r in plan.streams}
    n_points = {r: 0 for r in plan.streams}
    failed = {r: 0 for r in plan.streams}
    fail_msg: dict[str, str] = {}
    grid_bad = 0

    def deliver(role, item):
        nonlocal grid_bad
        frames = exp[role].get(item.index)
        if not frames:
            return
        p = item.payload
        for f in frames:
            if role == "radar":
                outs["radar/heatmap"].put(f, p.heatmap)
                outs["radar/cycle_ns"].put(f, np.asarray(p.cycle, np.int64))
                if "radar/iq" in outs:
                    _put_iq(outs, f, p.iq)
            else:
                outs[f"{role}/points"].put(f, p.points)
                n_points[role] += len(p.points)
                if f"{role}/point_time_ns" in outs:
                    t = p.time_ns if p.time_ns is not None else np.zeros(len(p.points), np.int64)
                    outs[f"{role}/point_time_ns"].put(f, np.asarray(t, np.int64).reshape(-1, 1))
                if f"{role}/range" in outs:
                    g = outs[f"{role}/range"]
                    if p.grid is not None and p.grid.shape == g.w.shape[1:]:
                        g.put(f, p.grid)
                    else:
                        grid_bad += 1
                        g.fail(f)

    def failed_item(role, idx, err):
        failed[role] += 1
        fail_msg.setdefault(role, _one_line(err))
        for f in exp[role].get(idx, []):
            for n, o in outs.items():
                if n.startswith(role + "/"):
                    o.fail(f)

    by_topic = {tp: st for st in plan.streams.values() for tp in st.topics}
    for st in plan.streams.values():
        st.reset()
    total = sum(t.count for t in rec.topics(frame_ids=False) if t.name in by_topic)
    t_pass = time.perf_counter()
    t_decode = 0.0
    heads = _head_topics(plan.streams)
    for raw in track(rec.raw_heads(list(by_topic), heads), total, f"ingest {plan.scene_id}: write", quiet,
                     unit="messages"):
        st = by_topic[raw.topic]
        t = time.perf_counter()
        try:
            items = st.feed(raw, decode=True, want=want[st.role])
        except HolodataError as err:
            failed_item(st.role, getattr(err, "item", -1), err)
            continue
        finally:
            t_decode += time.perf_counter() - t
        fresh = False
        for it in items:
            if it.payload is not None:
                decoded[st.role] += 1
                deliver(st.role, it)
                fresh = True
        if fresh:
            for o in outs.values():
                o.flush()
    for role, st in plan.streams.items():
        for it in st.flush(decode=True, want=want[role]):
            if it.payload is not None:
                decoded[role] += 1
                deliver(role, it)
    for o in outs.values():
        o.flush(final=True)
    bg.join()
    timings = {"index_pass_s": round(plan.index_seconds, 4), "write_pass_s": round(time.perf_counter() - t_pass, 4),
               "decode_s": round(t_decode, 4), "store_s": round(bg.seconds + sum(o.seconds for o in outs.values()), 4)}
    if failed.get(fs):
        raise RecordingError(f"{rec.path}: {failed[fs]} {fs} messages decoded in the index pass but not in the "
                             f"write pass ({fail_msg.get(fs)})")
    # per-frame stamps of the other sensors: the matched message's stamp, 0 = none (or it failed)
    for role in stamp_out:
        if role == fs:
            vals = plan.frame_stamps
        else:
            ok = np.zeros(T, bool)
            ok[sorted(outs[f"{role}/points"].expected)] = True
            vals = np.where(ok, plan.match_stamp[role], 0)
        w = frame_arr(f"{role}/timestamp_ns", (), "int64", ["frame"], "ns")
        for k in range(w.n_shards):
            w.write_shard(k, vals[w.frames(k)])
    warnings = list(plan.warnings)
    for role, n in failed.items():
        if n and role != "radar":
            plan.dropped[role]["failed_in_write_pass"] = n
            warnings.append(f"{n} {role} messages on {plan.streams[role].topic} did not decode ({fail_msg[role]}); "
                            f"their frames have no {role} data")
    for role in ("lidar", "camera"):
        if decoded.get(role) and not n_points[role]:
            warnings.append(f"all {decoded[role]} decoded {role} messages on {plan.streams[role].topic} hold no valid "
                            f"point (non-finite or (0, 0, 0)); {role}/points is empty")
    if grid_bad:
        warnings.append(f"{grid_bad} LiDAR scans do not fit the {outs['lidar/range'].w.shape[1:]} grid; "
                        f"their lidar/range frames are NaN")
    # poses
    pose_note = _write_poses(plan, sc, frame_arr)
    if pose_note:
        warnings.append(pose_note)
    tf_note = _write_lidar_tf(plan, frame_arr)
    if tf_note:
        warnings.append(tf_note)
    sync = {}
    for role in plan.match:
        ok = plan.match[role] >= 0
        off = (plan.match_stamp[role] - plan.frame_stamps)[ok]
        sync[role] = {"matched_frames": int(ok.sum()), "tolerance_ns": int(plan.tolerance_ns.get(role, 0)),
                      "offset_ns_median": int(np.median(off)) if len(off) else None,
                      "offset_ns_max_abs": int(np.abs(off).max()) if len(off) else None}
    sc.set_attrs({"source": {**source, "sha256": sha256()},
                  "ingest": {"complete": True, "fingerprint": fingerprint, "topics": plan.tmap.to_dict(),
                             "time_source": plan.tmap.time,
                             "counts": plan.counts, "decoded": decoded, "dropped": plan.dropped, "sync": sync,
                             "notes": plan.notes[:20], "warnings": warnings[:50]}})
    return {"scene": plan.scene_id, "recording": str(rec.path), "frames": T, "frame_sensor": fs,
            "arrays": sorted(set(arrays)), "counts": plan.counts, "decoded": decoded, "dropped": plan.dropped,
            "sync": sync, "truncated": bool(rec.truncated), "warnings": warnings, "notes": plan.notes,
            "timings": timings}


def _iq_outputs(plan: Plan, sc, frame_arr, outs: dict, T: int, S: int, bg) -> None:
    """``radar/iq`` (T, L, V, S) complex64: each rotation's raw chirp frames, the neighbouring ones its
    beams use first and last (``radar/iq_span`` (T, 3) int32 = before, rotation, after; zero-padded
    to L); ``radar/iq_motion`` (T, 2) float64: travel per chirp (m) and heading (rad) it was imaged
    with; ``radar/iq_static`` (V, S) complex64: the trajectory's static reflection, subtracted before
    imaging. ``holodata beamform`` re-images them (:mod:`holodata.beamforming`)."""
    L, V, Sm = plan.rec.iq_shape()
    sc.write_array("radar/iq_static", np.asarray(plan.rec.static_refl(), np.complex64), ["antenna", "sample"])
    iq = frame_arr("radar/iq", (L, V, Sm), "complex64", ["frame", "chirp", "antenna", "sample"], "1",
                   shard_frames=_shard_frames(8 * L * V * Sm, S), fill_value=0, codec=BULK_CODEC,
                   attrs={"scale": "unit (the recording's int16 scale divided out)",
                          "layout": "chirp frames [before | rotation | after] as radar/iq_span says, then zeros"})
    span = frame_arr("radar/iq_span", (3,), "int32", ["frame", "before_rotation_after"], "chirp frames")
    mot = frame_arr("radar/iq_motion", (2,), "float64", ["frame", "ds0_heading"], "m, rad",
                    attrs={"columns": "travel per chirp (m), heading counter-clockwise from beam 0 (rad)"})
    outs["radar/iq"] = _Out(iq, False, lambda: np.zeros((L, V, Sm), np.complex64), set(range(T)), bg)
    outs["radar/iq_span"] = _Out(span, False, lambda: np.zeros(3, np.int32), set(range(T)), bg)
    outs["radar/iq_motion"] = _Out(mot, False, lambda: np.zeros(2, np.float64), set(range(T)), bg)


def _put_iq(outs: dict, f: int, raw) -> None:
    L = outs["radar/iq"].w.shape[1]
    parts = (raw.before, raw.rotation, raw.after)
    n = [int(len(p)) for p in parts]
    if sum(n) > L:
        raise DecodeError(f"rotation {f}: {sum(n)} chirp frames exceed the {L} radar/iq was made for")
    cube = np.zeros(outs["radar/iq"].w.shape[1:], np.complex64)
    cube[:sum(n)] = np.concatenate(parts, axis=0)
    outs["radar/iq"].put(f, cube)
    outs["radar/iq_span"].put(f, np.asarray(n, np.int32))
    outs["radar/iq_motion"].put(f, np.asarray(raw.motion, np.float64))


def _write_poses(plan: Plan, sc, frame_arr) -> str | None:
    tf = plan.tf
    if "radar" not in plan.streams or tf is None or not tf.frames:
        return None
    radar_frame = str(plan.streams["radar"].first.header.frame_id).lstrip("/")
    world = plan.tmap.world_frame or _world_frame(tf, radar_frame)
    if world is None:
        return f"TF does not connect radar frame {radar_frame!r} to a world frame; no pose/T_world_radar"
    res = tf.lookup_many(world, radar_frame, plan.frame_stamps)
    if res is None:
        return f"TF does not connect radar frame {radar_frame!r} to {world!r}; no pose/T_world_radar"
    poses, ok = res
    if not ok.all():
        return (f"TF covers only {int(ok.sum())} of {len(ok)} radar frames ({world} -> {radar_frame}); "
                f"no pose/T_world_radar")
    w = frame_arr("pose/T_world_radar", (4, 4), "float64", ["frame", "row", "col"], "m",
                  attrs={"world_frame": world, "sensor_frame": radar_frame, "source": "tf"})
    for k in range(w.n_shards):
        w.write_shard(k, poses[w.frames(k)])
    return None


def _write_lidar_tf(plan: Plan, frame_arr) -> str | None:
    """``tf/T_world_lidar`` (T,4,4): TF's pose of the LiDAR frame in the world frame at each frame's
    scan stamp, NaN where the frame has no scan or TF does not cover it (drivers start at different
    times). slam anchors its map to it (the first covered scan), so slam's world is TF's world and a
    camera TF pose in that world is a guess register can use."""
    tf = plan.tf
    if "lidar" not in plan.streams or tf is None or not tf.frames:
        return None
    frame = _sensor_frame(plan, "lidar")
    if not frame:
        return None
    from .readers.tf import BASE_FRAMES

    world = plan.tmap.world_frame or _world_frame(tf, frame)
    if world is None or world == frame or (world in BASE_FRAMES and not plan.tmap.world_frame):
        return None     # (the robot's own base frame is no world: no odometry/localisation in TF)
    stamps = plan.frame_stamps if plan.frame_sensor == "lidar" else np.where(
        plan.match["lidar"] >= 0, plan.match_stamp["lidar"], 0)
    res = tf.lookup_many(world, frame, stamps)
    if res is None:
        return f"TF does not connect LiDAR frame {frame!r} to {world!r}; no tf/T_world_lidar"
    poses, ok = res
    ok &= np.asarray(stamps) > 0
    poses = np.where(ok[:, None, None], poses, np.nan)
    w = frame_arr("tf/T_world_lidar", (4, 4), "float64", ["frame", "row", "col"], "m", fill_value=float("nan"),
                  attrs={"world_frame": world, "sensor_frame": frame, "source": "tf",
                         "covered_frames": int(ok.sum()), "time": "the frame's LiDAR scan stamp"})
    for k in range(w.n_shards):
        w.write_shard(k, poses[w.frames(k)])
    if not ok.any():
        return f"TF ({world} -> {frame}) covers none of the LiDAR scans; tf/T_world_lidar is NaN"
    return None


def _world_frame(tf, frame: str) -> str | None:
    """``map``/``world``/``odom`` if TF connects it to ``frame``, else the root of ``frame``'s tree
    when a moving (non-static) transform leads from it to ``frame`` — a tree of static transforms only
    is the rig's own (``base_link → radar``), not a world the sensor moves in."""
    from .readers.tf import WORLD_FRAMES

    for cand in WORLD_FRAMES:
        if cand in tf.frames and tf._path(cand, frame, False) is not None:
            return cand
    root = tf.root(frame)
    return None if root == frame or tf._path(root, frame, True) is not None else root


def _sensor_frame(plan: Plan, role: str) -> str | None:
    st = plan.streams.get(role)
    if st is None:
        return None
    if role == "radar":
        return str(st.first.header.frame_id).lstrip("/")
    pr = plan.probe.get(role) or {}
    return (pr.get("frame_id") or "").lstrip("/") or None


def _extrinsics(plan: Plan) -> dict:
    tf = plan.tf
    if tf is None or not tf.frames:
        return {}
    from .readers.tf import BASE_FRAMES, find_frame

    base = plan.tmap.base_frame or find_frame(tf.frames, BASE_FRAMES)
    out = {}
    if base is None:
        return out
    for role in ("radar", "lidar", "camera"):
        fr = _sensor_frame(plan, role)
        if not fr:
            continue
        T = tf.lookup(base, fr, None, static_only=True)
        if T is not None:
            out[role] = T.tolist()
    return out


def _sensor_attrs(plan: Plan) -> dict:
    out: dict = {}
    tf = plan.tf
    for role, st in plan.streams.items():
        d = {"topic": st.topic, "frame_id": _sensor_frame(plan, role)}
        if role == "radar":
            m = st.first
            d.update({"type": m.__class__.__name__ if not hasattr(m, "__msgtype__") else m.__msgtype__,
                      "encoding": str(m.encoding), "shape": list(st.shape),
                      "rotation_radius_m": float(m.rotation_radius), "range_resolution_m": float(m.range_resolution),
                      "elevation_max_rad": float(m.elevation_max), "elevation_min_rad": float(m.elevation_min),
                      "beam_origin": radar_beam_origin(m, st.topic).to_attrs()})
        if isinstance(st, (OusterScanStream, OusterPacketStream)):
            meta = st.rec.meta if isinstance(st, OusterScanStream) else None
            if meta is None:
                from .readers.ouster import load_info, sensor_meta

                info, text = load_info(st.metadata_text)
                meta = sensor_meta(info, text)
            d["ouster"] = meta.to_attrs()
            d["ouster_metadata_json"] = meta.json_text
            d["range_definition"] = "Ouster RANGE channel (beam origin), destaggered"
        elif role == "lidar":
            pr = plan.probe.get("lidar") or {}
            d["organised_grid"] = list(pr["grid"]) if pr.get("grid") else None
            if pr.get("grid"):
                d["range_definition"] = ("norm of xyz (sensor origin), grid as published" if isinstance(st, CloudStream)
                                         else "range image as stored in the recording (m)")
            if getattr(st, "time_field", None):
                d["time_field"] = st.time_field
                d["time_reference"] = st.time_reference
        if isinstance(st, StereoStream):
            d["stereo"] = {"right_topic": st.right_topic, "right_camera_info_topic": st.right_info_topic,
                           "baseline_m": st.baseline, "matcher": "OpenCV StereoSGBM (3-way), block 5",
                           "depth": "fx * baseline / disparity"}
        if isinstance(st, DepthStream):
            d["camera_info_topic"] = st.info_topic
            d["intrinsics"] = st.model.to_attrs()
            d["stride"] = st.stride
            d["points_frame"] = "optical (x right, y down, z forward)"
        T_frame_points = np.eye(4)
        if isinstance(st, CameraCloudStream) and st.model is not None:
            d["camera_info_topic"] = st.info_topic
            d["intrinsics"] = {**st.model.to_attrs(), "source": st.model_source}
            d["points_frame"] = ("optical (x right, y down, z forward)" + (
                "" if np.array_equal(st.R_opt, np.eye(3)) else f", rotated from the cloud's frame {d['frame_id']!r}"))
            T_frame_points[:3, :3] = st.R_opt.T      # the points' optical axes in the cloud's frame
        fr = d.get("frame_id")
        if tf is not None and fr and tf.frames:
            from .readers.tf import WORLD_FRAMES, find_frame

            world = plan.tmap.world_frame or find_frame(tf.frames, WORLD_FRAMES)
            if world:
                T = tf.lookup(world, fr, None, static_only=True)
                if T is not None:
                    d[f"T_{world}_sensor"] = (T @ T_frame_points).tolist()   # the frame camera/points are in
        out[role] = d
    return out


# ==================================================================================================
# entry points

def ingest(recordings, out, topics=None, scene_ids=None, msg_dir=None, tolerance_ms: float | None = None,
           quiet: bool = True, meta=None, codec: str | None = None, shard_frames: int | None = None,
           client=None, beamform=None, keep_iq: bool = False) -> dict:
    """Ingest ``recordings`` (paths) into the dataset at ``out`` (created or resumed), one scene
    each. ``topics``: dict or YAML path (see :func:`load_topics_file`). Returns the summary
    {dataset, scenes: [...], failed: [{recording, error}], ok}; a recording that fails is reported
    there and the others are still ingested. Raises RecordingError when none could be ingested.
    ``client`` (a ``distributed.Client``): one Dask task per recording (:mod:`holodata.distributed`);
    the recordings must be readable at the same paths on the workers. ``beamform``:
    :class:`~holodata.radar.beamform.BeamformParams` for recordings of raw radar samples (PanoRadar raw
    trajectories), default 64 x 512 beams, all range bins; ``keep_iq``: store their raw samples too
    (``radar/iq``), so that ``holodata beamform`` can re-image them with other parameters."""
    recordings = [Path(r) for r in recordings]
    if not recordings:
        raise InputError("no recording given")
    if isinstance(topics, (str, Path)):
        topics = load_topics_file(topics)
    if scene_ids is not None:
        scene_ids = list(scene_ids)
        if len(scene_ids) != len(recordings):
            raise InputError(f"{len(scene_ids)} --scene-id for {len(recordings)} recordings (give one per recording)")
    if tolerance_ms is not None and tolerance_ms <= 0:
        raise InputError(f"--tolerance must be > 0 ms, got {tolerance_ms}")
    failed: list[dict] = []
    from .dataset import create_dataset, open_dataset

    try:
        existing = open_dataset(out)
        # a LiDAR-only dataset has no radar grid yet: the first radar recording gives it one
        grid, rb = (existing.grid, existing.range_bins) if existing.meta.get("grid_source") != "default" else (None, None)
    except HolodataError:
        existing, grid, rb = None, None, None
    todo = []
    if existing is None and (len(recordings) > 1 or client is not None):
        # cheap pre-pass: each radar recording's grid (the dataset has one grid for all scenes)
        for i, r in enumerate(recordings):
            try:
                todo.append((i, r, radar_grid(r, topics, msg_dir, meta, beamform)))
            except (HolodataError, OSError) as err:
                failed.append({"recording": str(r), "error": _one_line(err)})
        if not todo:
            raise RecordingError(_failures(failed))
        grids = {g for _, _, g in todo if g is not None}
        if len(grids) > 1:
            raise RecordingError(f"recordings have different radar grids ({sorted(str(g[0].to_attrs()) for g in grids)}); "
                                 f"ingest them into separate datasets")
        grid, rb = next(iter(grids)) if grids else (None, None)
    else:
        todo = [(i, r, None) for i, r in enumerate(recordings)]
    ids = [scene_ids[i] if scene_ids else _scene_id(r) for i, r, _ in todo]
    ids = [f"{sid}_{k}" if ids.count(sid) > 1 else sid for k, sid in enumerate(ids)]  # same names: suffix
    try:
        from . import __version__ as version
    except ImportError:  # pragma: no cover
        version = "?"
    ds = None
    scenes = []
    if client is not None:  # the dataset exists before the workers write their scenes into it
        create_dataset(out, grid=grid, range_bins=rb, created_by="holodata ingest",
                       provenance={"tool": "holodata ingest", "version": version},
                       **({"shard_frames": shard_frames} if shard_frames else {}))
        opts = {"topics": topics, "msg_dir": msg_dir, "tolerance_ms": tolerance_ms, "meta": meta, "codec": codec,
                "beamform": beamform, "keep_iq": keep_iq}
        scenes, more = ingest_dask(client, todo, ids, out, grid, rb, opts, quiet=quiet)
        failed += more
        todo = []
        if not scenes and existing is None:   # created for the workers, nothing landed: leave no empty dataset
            from .dataset.store import Store

            Store(out).delete_tree("")
    for (i, r, _), sid in zip(todo, ids):
        p = None
        try:
            p = plan_recording(r, topics, sid, msg_dir, tolerance_ms, meta, quiet, beamform, keep_iq)
            if p.grid is not None and grid is None:   # the first radar recording sets the dataset's grid
                grid, rb, ds = p.grid, p.range_bins, None
            else:
                check_grid(r, p, grid, rb)
            if ds is None:   # created only once something is ingestable: a failed run leaves no empty dataset
                kw = {"shard_frames": shard_frames} if shard_frames else {}
                ds = create_dataset(out, grid=grid, range_bins=rb, created_by="holodata ingest",
                                    provenance={"tool": "holodata ingest", "version": version}, **kw)
            scenes.append(write_plan(p, ds, quiet=quiet, codec=codec))   # sha256: waited for at its end
        except (HolodataError, OSError) as err:
            failed.append({"recording": str(r), "error": _one_line(err)})
        finally:
            if p is not None:
                p.rec.close()
    if not scenes:
        raise RecordingError(_failures(failed))
    return {"dataset": str(out), "scenes": scenes, "failed": failed, "ok": not failed}


def _failures(failed: list[dict]) -> str:
    if len(failed) == 1:
        return failed[0]["error"]
    return f"none of {len(failed)} recordings can be ingested: " + "; ".join(f["error"] for f in failed)


def radar_grid(path, topics=None, msg_dir=None, meta=None, beamform=None) -> tuple[Grid, RangeBins] | None:
    """The radar grid of a recording (from its first decodable radar message), None without radar."""
    rec = open_recording(path, msg_dir=msg_dir, meta=meta, beamform=beamform)
    try:
        infos = rec.topics(frame_ids=False)
        if not any(t.msgtype.endswith(RADAR_SUFFIX) and t.count for t in infos) and not (topics or {}).get("radar"):
            return None
        tmap, _ = map_topics(rec, topics, rec.topics(frame_ids=True))
        if not tmap.radar:
            return None
        st = RadarStream(rec, tmap.radar, tmap.time)
        last = None
        for n, raw in enumerate(rec.raw_messages([tmap.radar])):
            try:
                st.convert(raw, keep=False)
                return _grid_of(rec, st)
            except HolodataError as err:
                last = err
            if n >= 20:
                break
        raise RecordingError(f"{rec.path}: no decodable radar message on {tmap.radar} ({_one_line(last) if last else 'none'})")
    finally:
        rec.close()


def _grid_of(rec, st: RadarStream) -> tuple[Grid, RangeBins]:
    msg = st.first
    R, H, W = st.shape
    emax, emin = math.degrees(float(msg.elevation_max)), math.degrees(float(msg.elevation_min))
    try:
        return Grid(H, W, round(emax, 5), round(emin, 5)), RangeBins(R, round(float(msg.range_resolution), 7))
    except ValueError as err:
        raise RecordingError(f"{rec.path}: radar topic {st.topic} has an unusable grid ({err})") from err


def list_recording(path, msg_dir=None, meta=None, topics=None, beamform=None) -> dict:
    """What ``ingest --list`` prints: reader, files, duration, topics (name, type, count, rate,
    frame id) and the role ingest would give each (with ``topics``: dict or YAML path overrides)."""
    if isinstance(topics, (str, Path)):
        topics = load_topics_file(topics)
    rec = open_recording(path, msg_dir=msg_dir, meta=meta, beamform=beamform)
    try:
        infos = rec.topics(frame_ids=True)
        try:
            tmap, notes = map_topics(rec, topics, infos)
        except HolodataError as err:
            tmap, notes = TopicMap(), [_one_line(err)]
        roles = {}
        for r in ROLES:
            v = getattr(tmap, r)
            for name in ([v] if isinstance(v, str) else v or []):
                roles[name] = r
        lo, hi = rec.duration_ns()
        size = sum(f.stat().st_size for f in rec.files if f.exists())
        usable = bool(tmap.radar or tmap.lidar)
        reason = None if usable else _reject_reason(rec, infos, tmap, notes)
        lidar_type = next((t.msgtype for t in infos if t.name == tmap.lidar), None) if tmap.lidar else None
        if usable and lidar_type is not None:
            from .readers.ouster import SDK_TYPES, sdk_missing

            reason = sdk_missing() if lidar_type in SDK_TYPES else None   # ingest would stop there
            usable = reason is None
        return {"recording": str(rec.path), "reader": rec.kind, "files": [str(f) for f in rec.files], "bytes": size,
                "start_ns": lo, "end_ns": hi, "duration_s": None if lo is None else (hi - lo) / 1e9,
                "messages": sum(t.count for t in infos), "truncated": bool(rec.truncated),
                "problems": list(rec.problems), "notes": notes, "ingestable": usable, "reason": reason,
                "topics": [{**t.to_dict(), "role": roles.get(t.name)} for t in infos]}
    finally:
        rec.close()


def format_listing(info: dict) -> str:
    """``ros2 bag info``-like text of :func:`list_recording`'s result."""
    mb = info["bytes"] / 1e6
    lines = [f"Files:     {', '.join(Path(f).name for f in info['files'])} ({mb:.1f} MB)",
             f"Reader:    {info['reader']}" + ("  (TRUNCATED: readable part only)" if info["truncated"] else "")]
    if info["duration_s"] is not None:
        lines.append(f"Duration:  {info['duration_s']:.3f} s   Start: {info['start_ns']} ns   End: {info['end_ns']} ns")
    lines.append(f"Messages:  {info['messages']}")
    lines.append(f"Topics:    {len(info['topics'])}")
    w = max([len(t["name"]) for t in info["topics"]] + [5])
    wt = max([len(t["type"]) for t in info["topics"]] + [4])
    for t in info["topics"]:
        rate = f"{t['rate_hz']:.2f} Hz" if t["rate_hz"] else "-"
        extra = []
        if t.get("frame_id"):
            extra.append(f"frame {t['frame_id']}")
        if t.get("role"):
            extra.append(f"[{t['role']}]")
        if not t["decodable"]:
            extra.append(f"({t.get('note') or 'not decodable'})")
        lines.append(f"  {t['name']:<{w}}  {t['type']:<{wt}}  {t['count']:>7}  {rate:>11}  {' '.join(extra)}".rstrip())
    for p in info["problems"]:
        lines.append(f"warning: {p}")
    for n in info["notes"]:
        lines.append(f"note: {n}")
    lines.append("Ingest:    " + ("yes" if info["ingestable"] else f"no — {info['reason']}"))
    return "\n".join(lines)


def check_grid(recording, plan: Plan, grid, range_bins) -> None:
    """RecordingError unless the radar recording's grid and range bins (``plan``) are the dataset's
    (``grid``, ``range_bins``); a recording without radar fits any dataset."""
    if plan.grid is not None and (plan.grid, plan.range_bins) != (grid, range_bins):
        raise RecordingError(f"{recording}: radar grid {plan.grid}, {plan.range_bins} differs from the dataset's "
                             f"{grid}, {range_bins}")


# -- Dask task (holodata.distributed runs it): one per recording -----------------------------------------
def _ingest_task(path: str, scene_id: str, out: str, grid, range_bins, opts: dict) -> dict:
    """Worker side: plan and write one recording as scene ``scene_id`` of dataset ``out`` (which
    exists). Returns {"scene": summary} or {"failed": {recording, error}}."""
    from .dataset import create_dataset
    from .distributed import tune_malloc

    tune_malloc()
    p = None
    try:
        p = plan_recording(Path(path), opts["topics"], scene_id, opts["msg_dir"], opts["tolerance_ms"],
                           opts["meta"], True, opts.get("beamform"), opts.get("keep_iq", False))
        check_grid(path, p, grid, range_bins)
        ds = create_dataset(out, grid=grid, range_bins=range_bins)
        return {"scene": write_plan(p, ds, quiet=True, codec=opts["codec"])}
    except (HolodataError, OSError) as err:
        return {"failed": {"recording": str(path), "error": _one_line(err)}}
    finally:
        if p is not None:
            p.rec.close()


def ingest_dask(client, todo: list, ids: list[str], out: str, grid, range_bins, opts: dict, quiet: bool = True
                ) -> tuple[list[dict], list[dict]]:
    """One Dask task per recording ``todo`` [(index, path, _)] → scenes ``ids`` of the existing
    dataset ``out``. Returns (scene summaries, failures) in recording order."""
    from .distributed import run_tasks, worker_path

    token = uuid.uuid4().hex[:8]
    opts = {**opts, **{k: worker_path(opts[k]) for k in ("msg_dir", "meta") if opts.get(k)}}
    calls = [(worker_path(r), sid, worker_path(out), grid, range_bins, opts) for (_, r, _), sid in zip(todo, ids)]
    keys = [f"ingest-{sid}-{token}" for sid in ids]
    res = run_tasks(client, _ingest_task, calls, keys, description="ingest", quiet=quiet)
    return [r["scene"] for r in res if "scene" in r], [r["failed"] for r in res if "failed" in r]
