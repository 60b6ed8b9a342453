"""Recording writers (rosbags): ROS 2 bag with MCAP storage (default), ROS 2 bag with sqlite3
storage, ROS 1 bag — plus builders for the standard messages holodata synthesises.

Every connection is added with the typestore that knows holodata's own types
(:func:`holodata.messages.typestore_for`), so the message definitions (holodata_msgs/msg/RadarHeatmap
included) are embedded in the file: MCAP schemas / rosbag2 metadata, ROS 1 connection headers.
Writers are deterministic (no wall-clock data), so equal inputs give byte-identical files.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..messages import typestore_for

FORMATS = ("mcap", "rosbag2", "rosbag1")


@dataclass(frozen=True)
class RawRotation:
    """One rotation's raw FMCW samples as a ``holodata_msgs/msg/RadarRawRotation`` carries them
    (:meth:`BagWriter.radar_raw_rotation`): ``chirps`` (n_before + n_rotation + n_after, V, S) complex,
    the rotation's ``n_rotation`` chirps with the ``n_before`` before and ``n_after`` after them that
    its first and last beams need; the cycle's start and end (ns, the radar's clock); the platform's
    motion over the cycle: travel per chirp (m) and heading (rad, radar frame at the cycle start)."""

    chirps: np.ndarray
    n_before: int
    n_rotation: int
    n_after: int
    cycle_start_ns: int
    cycle_end_ns: int
    travel_per_chirp: float = 0.0
    heading: float = 0.0

_TF_MSG_ROS1 = "geometry_msgs/TransformStamped[] transforms\n"


def _typestore(ros_version: int):
    store = typestore_for(ros_version)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:  # ROS 1 Noetic store lacks tf2_msgs
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg(_TF_MSG_ROS1, "tf2_msgs/msg/TFMessage"))
    return store


def _qos(latched: bool):
    """What ``ros2 bag record`` stores: reliable keep-last; transient-local for latched topics."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    inf = QosTime(0x7FFFFFFF, 0xFFFFFFFF)
    return Qos(QosHistory.KEEP_LAST, 1 if latched else 10, QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE, inf, inf,
               QosLiveliness.AUTOMATIC, inf, False)


def recording_path(out_dir: Path, fmt: str, name: str = "recording") -> Path:
    """Where :class:`BagWriter` puts a recording: a rosbag2 directory (``<name>/``, holding
    ``<name>.mcap`` or ``<name>.db3`` and ``metadata.yaml``) or a ROS 1 ``<name>.bag``."""
    return Path(out_dir) / (f"{name}.bag" if fmt == "rosbag1" else name)


class BagWriter:
    """``fmt``: "mcap" | "rosbag2" (sqlite3) | "rosbag1". Use as a context manager."""

    def __init__(self, path: str | Path, fmt: str = "mcap"):
        if fmt not in FORMATS:
            raise InputError(f"unknown recording format {fmt!r} (choose from {', '.join(FORMATS)})")
        self.fmt = fmt
        self.path = Path(path)
        self.ros_version = 1 if fmt == "rosbag1" else 2
        self.store = _typestore(self.ros_version)
        self.types = self.store.types
        self._seq: dict[str, int] = {}
        if fmt == "rosbag1":
            from rosbags.rosbag1 import Writer

            self.writer = Writer(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(self.path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.conns: dict[str, tuple] = {}

    @property
    def storage_file(self) -> Path:
        """The file holding the messages (.mcap, .db3 or .bag)."""
        if self.fmt == "rosbag1":
            return self.path
        return self.path / f"{self.path.name}.{'mcap' if self.fmt == 'mcap' else 'db3'}"

    def add(self, topic: str, msgtype: str, latched: bool = False) -> None:
        if self.fmt == "rosbag1":
            conn = self.writer.add_connection(topic, msgtype, typestore=self.store, latching=1 if latched else None)
        else:
            conn = self.writer.add_connection(topic, msgtype, typestore=self.store,
                                              offered_qos_profiles=[_qos(latched)])
        self.conns[topic] = (conn, msgtype)

    def write(self, topic: str, t_ns: int, msg) -> None:
        conn, msgtype = self.conns[topic]
        if self.ros_version == 1:
            data = self.store.serialize_ros1(msg, msgtype)
        else:
            data = self.store.serialize_cdr(msg, msgtype)
        self.writer.write(conn, int(t_ns), data)

    def close(self) -> None:
        self.writer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ message builders
    def header(self, topic: str, stamp_ns: int, frame_id: str):
        T = self.types
        stamp = T["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))
        if self.ros_version == 1:
            seq = self._seq.get(topic, 0)
            self._seq[topic] = seq + 1
            return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def point_cloud(self, topic: str, stamp_ns: int, frame_id: str, points: np.ndarray, dense: bool = False):
        """``points``: (h, w) or (n,) structured array; its dtype's fields/offsets become PointFields."""
        from .lidar import POINTFIELD_TYPES

        T = self.types
        pts = np.ascontiguousarray(points)
        h, w = (pts.shape if pts.ndim == 2 else (1, pts.shape[0]))
        fields = []
        for name in pts.dtype.names:
            dt, off = pts.dtype.fields[name][:2]
            fields.append(T["sensor_msgs/msg/PointField"](name=name, offset=int(off),
                                                          datatype=POINTFIELD_TYPES[dt.str], count=1))
        return T["sensor_msgs/msg/PointCloud2"](
            header=self.header(topic, stamp_ns, frame_id), height=int(h), width=int(w), fields=fields,
            is_bigendian=False, point_step=int(pts.dtype.itemsize), row_step=int(pts.dtype.itemsize * w),
            data=np.frombuffer(pts.tobytes(), dtype=np.uint8), is_dense=bool(dense))

    def image_32fc1(self, topic: str, stamp_ns: int, frame_id: str, depth: np.ndarray):
        d = np.ascontiguousarray(depth, dtype="<f4")
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(topic, stamp_ns, frame_id), height=int(d.shape[0]), width=int(d.shape[1]),
            encoding="32FC1", is_bigendian=0, step=int(4 * d.shape[1]), data=np.frombuffer(d.tobytes(), np.uint8))

    def image_16uc1(self, topic: str, stamp_ns: int, frame_id: str, depth_m: np.ndarray):
        """16UC1 depth image in millimetres (RealSense, Kinect): NaN / out of range -> 0 (no return)."""
        mm = np.where(np.isfinite(depth_m), np.rint(np.nan_to_num(depth_m) * 1000.0), 0.0)
        d = np.ascontiguousarray(np.clip(mm, 0, 65535), dtype="<u2")
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(topic, stamp_ns, frame_id), height=int(d.shape[0]), width=int(d.shape[1]),
            encoding="16UC1", is_bigendian=0, step=int(2 * d.shape[1]), data=np.frombuffer(d.tobytes(), np.uint8))

    def image_mono8(self, topic: str, stamp_ns: int, frame_id: str, img: np.ndarray):
        im = np.ascontiguousarray(img, dtype=np.uint8)
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(topic, stamp_ns, frame_id), height=int(im.shape[0]), width=int(im.shape[1]),
            encoding="mono8", is_bigendian=0, step=int(im.shape[1]), data=im.reshape(-1))

    def camera_info(self, topic: str, stamp_ns: int, frame_id: str, cfg, tx: float = 0.0):
        """Pinhole CameraInfo; ``tx`` = -fx·baseline for the right camera of a rectified pair."""
        T = self.types
        K = cfg.K()
        P = np.zeros((3, 4))
        P[:3, :3] = K
        P[0, 3] = tx
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        kw = dict(header=self.header(topic, stamp_ns, frame_id), height=cfg.height, width=cfg.width,
                  distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi)
        arrays = {"d": np.zeros(5), "k": K.ravel(), "r": np.eye(3).ravel(), "p": P.ravel()}
        for k, v in arrays.items():
            kw[k.upper() if self.ros_version == 1 else k] = v.astype(np.float64)
        return T["sensor_msgs/msg/CameraInfo"](**kw)

    def transform(self, topic: str, stamp_ns: int, parent: str, child: str, T4: np.ndarray):
        T = self.types
        q = Rotation.from_matrix(T4[:3, :3]).as_quat()
        tf = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(T4[0, 3]), y=float(T4[1, 3]), z=float(T4[2, 3])),
            rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
        return T["geometry_msgs/msg/TransformStamped"](header=self.header(topic, stamp_ns, parent),
                                                       child_frame_id=child, transform=tf)

    def tf_message(self, transforms: list):
        return self.types["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def string(self, text: str):
        return self.types["std_msgs/msg/String"](data=text)

    def radar_heatmap(self, topic: str, stamp_ns: int, frame_id: str, heatmap_bytes: bytes, shape, cfg,
                      cycle_start_ns: int, cycle_end_ns: int):
        from ..messages import RADAR_HEATMAP_TYPE

        g, rb = cfg.grid, cfg.range_bins
        return self.types[RADAR_HEATMAP_TYPE](
            header=self.header(topic, stamp_ns, frame_id), cycle_start_ns=int(cycle_start_ns),
            cycle_end_ns=int(cycle_end_ns), n_range=int(shape[0]), n_elevation=int(shape[1]),
            n_azimuth=int(shape[2]), range_resolution=float(rb.dr), elevation_max=float(np.deg2rad(g.elev_max_deg)),
            elevation_min=float(np.deg2rad(g.elev_min_deg)), rotation_radius=float(cfg.rotation_radius_m),
            range_origin="rotation_centre", encoding=cfg.encoding, data=np.frombuffer(heatmap_bytes, np.uint8))

    def radar_raw_rotation(self, topic: str, stamp_ns: int, frame_id: str, rotation: RawRotation, chirp):
        """A ``holodata_msgs/msg/RadarRawRotation`` (:mod:`holodata.messages`) of ``rotation``, ``chirp``
        a :class:`holodata.radar.chirp.ChirpConfig` (or anything with its chirp fields)."""
        from ..messages import RADAR_RAW_TYPE

        r = rotation
        data = np.ascontiguousarray(r.chirps, np.complex64).view(np.uint8).reshape(-1)
        return self.types[RADAR_RAW_TYPE](
            header=self.header(topic, stamp_ns, frame_id), cycle_start_ns=int(r.cycle_start_ns),
            cycle_end_ns=int(r.cycle_end_ns), start_frequency=float(chirp.start_frequency_hz),
            slope=float(chirp.slope_hz_per_s), sample_rate=float(chirp.sample_rate_hz), n_samples=int(chirp.n_samples),
            n_tx=int(chirp.n_tx), n_rx=int(chirp.n_rx), antenna_spacing=float(chirp.antenna_spacing_m),
            rotation_radius=float(chirp.rotation_radius_m), n_before=int(r.n_before), n_rotation=int(r.n_rotation),
            n_after=int(r.n_after), travel_per_chirp=float(r.travel_per_chirp), heading=float(r.heading),
            encoding="complex64", data=data)
