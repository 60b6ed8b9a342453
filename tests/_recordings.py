"""Tiny recordings for the reader/ingest tests, written with rosbags' own writers (not holodata's).

``write_recording(path, fmt)`` writes radar heatmaps (holodata_msgs/msg/RadarHeatmap) at 2 Hz, an
organised Ouster-layout LiDAR PointCloud2 at 10 Hz, a 16UC1 depth image + CameraInfo at 5 Hz and
TF (static base->radar/lidar/camera, dynamic odom->base), and returns what it wrote.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from _paths import FIXTURES as FIXTURES  # re-exported: the reader and ingest tests import it from here
from scipy.spatial.transform import Rotation

from holodata.messages import typestore_for

LIDAR_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "t", "ring"],
                        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2"],
                        "offsets": [0, 4, 8, 16, 20, 24], "itemsize": 32})
PF_TYPES = {"<f4": 7, "<u4": 6, "<u2": 4, "<f8": 8, "|u1": 2, ">f4": 7, ">u4": 6, "<i2": 3}
T0 = 1_700_000_000_000_000_000


def store_for(fmt: str):
    st = typestore_for(1 if fmt == "rosbag1" else 2)
    if "tf2_msgs/msg/TFMessage" not in st.fielddefs:
        from rosbags.typesys import get_types_from_msg

        st.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", "tf2_msgs/msg/TFMessage"))
    return st


def header(T, fmt, stamp_ns, frame):
    st = T["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
    if fmt == "rosbag1":
        return T["std_msgs/msg/Header"](seq=0, stamp=st, frame_id=frame)
    return T["std_msgs/msg/Header"](stamp=st, frame_id=frame)


def cloud_msg(T, fmt, stamp_ns, frame, pts: np.ndarray, dense=False, bigendian=False, row_step=None, data=None):
    """PointCloud2 from a (h, w) or (n,) structured array; ``data`` overrides the payload bytes."""
    pts = np.ascontiguousarray(pts)
    h, w = pts.shape if pts.ndim == 2 else (1, pts.shape[0])
    fields = [T["sensor_msgs/msg/PointField"](name=n, offset=int(pts.dtype.fields[n][1]),
                                              datatype=PF_TYPES[pts.dtype.fields[n][0].str], count=1)
              for n in pts.dtype.names]
    raw = np.frombuffer(pts.tobytes(), np.uint8) if data is None else np.frombuffer(data, np.uint8)
    return T["sensor_msgs/msg/PointCloud2"](
        header=header(T, fmt, stamp_ns, frame), height=h, width=w, fields=fields, is_bigendian=bigendian,
        point_step=pts.dtype.itemsize, row_step=row_step or pts.dtype.itemsize * w, data=raw, is_dense=dense)


def image_msg(T, fmt, stamp_ns, frame, arr: np.ndarray, encoding: str, data=None):
    a = np.ascontiguousarray(arr)
    step = a.dtype.itemsize * a.shape[1]
    raw = np.frombuffer(a.tobytes(), np.uint8) if data is None else np.frombuffer(data, np.uint8)
    return T["sensor_msgs/msg/Image"](header=header(T, fmt, stamp_ns, frame), height=a.shape[0], width=a.shape[1],
                                      encoding=encoding, is_bigendian=0, step=step, data=raw)


def camera_info_msg(T, fmt, stamp_ns, frame, K, w, h):
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    P = np.zeros((3, 4))
    P[:3, :3] = K
    kw = {"d": np.zeros(5), "k": np.asarray(K, float).ravel(), "r": np.eye(3).ravel(), "p": P.ravel()}
    if fmt == "rosbag1":
        kw = {k.upper(): v for k, v in kw.items()}
    return T["sensor_msgs/msg/CameraInfo"](header=header(T, fmt, stamp_ns, frame), height=h, width=w,
                                           distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **kw)


def tf_msg(T, fmt, items):
    out = []
    for stamp, parent, child, M in items:
        q = Rotation.from_matrix(M[:3, :3]).as_quat()
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(M[0, 3]), y=float(M[1, 3]), z=float(M[2, 3])),
            rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
        out.append(T["geometry_msgs/msg/TransformStamped"](header=header(T, fmt, stamp, parent), child_frame_id=child,
                                                           transform=tr))
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


def radar_msg(T, fmt, stamp_ns, hm: np.ndarray, cycle, encoding="float16", frame="radar"):
    R, H, W = hm.shape
    return T["holodata_msgs/msg/RadarHeatmap"](
        header=header(T, fmt, stamp_ns, frame), cycle_start_ns=int(cycle[0]), cycle_end_ns=int(cycle[1]),
        n_range=R, n_elevation=H, n_azimuth=W, range_resolution=0.0375, elevation_max=float(np.deg2rad(45.0)),
        elevation_min=float(np.deg2rad(-45.0)), rotation_radius=0.105, range_origin="rotation_centre", encoding=encoding,
        data=np.frombuffer(hm.astype("<f2" if encoding == "float16" else "<f4").tobytes(), np.uint8))


class Writer:
    """rosbags writer for ``fmt`` in ("mcap", "sqlite3", "rosbag1")."""

    def __init__(self, path: Path, fmt: str):
        self.fmt, self.path = fmt, Path(path)
        self.store = store_for(fmt)
        self.T = self.store.types
        if fmt == "rosbag1":
            from rosbags.rosbag1 import Writer as W1

            self.w = W1(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as W2

            self.w = W2(self.path, version=9, storage_plugin=StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3)
        self.w.open()
        self.conns = {}

    def add(self, topic, msgtype):
        self.conns[topic] = (self.w.add_connection(topic, msgtype, typestore=self.store), msgtype)

    def write(self, topic, t_ns, msg):
        conn, ty = self.conns[topic]
        data = self.store.serialize_ros1(msg, ty) if self.fmt == "rosbag1" else self.store.serialize_cdr(msg, ty)
        self.w.write(conn, int(t_ns), data)

    def close(self):
        self.w.close()


def lidar_scan(k: int, rows=8, cols=32, seed=0) -> np.ndarray:
    """Organised scan: a cylinder of radius 2 + k*0.01 m; every 7th pixel no return (zeros)."""
    rng = np.random.default_rng([seed, k])
    a = np.zeros((rows, cols), LIDAR_DTYPE)
    az = -2 * np.pi * np.arange(cols) / cols
    el = np.deg2rad(np.linspace(15, -15, rows))[:, None]
    r = 2.0 + 0.01 * k + 0.001 * rng.standard_normal((rows, cols))
    a["x"] = r * np.cos(el) * np.cos(az)
    a["y"] = r * np.cos(el) * np.sin(az)
    a["z"] = r * np.sin(el)
    a["intensity"] = rng.uniform(0, 100, (rows, cols))
    a["t"] = (np.arange(cols) * (100_000_000 // cols))[None, :]
    a["ring"] = np.arange(rows)[:, None]
    miss = (np.arange(rows * cols).reshape(rows, cols) % 7) == 3
    for f in ("x", "y", "z"):
        a[f][miss] = 0.0
    return a


def write_recording(path: Path, fmt: str = "mcap", n_radar: int = 4, radar=True, lidar=True, camera=True, tf=True,
                    radar_shape=(8, 4, 16), encoding="float16", lidar_shape=(8, 32), depth_shape=(6, 8)) -> dict:
    """Radar 2 Hz (stamp = mid-cycle), LiDAR 10 Hz, depth 5 Hz, odom TF 20 Hz; returns the truth."""
    w = Writer(path, fmt)
    T = w.T
    period = 500_000_000
    span = n_radar * period
    truth = {"radar": [], "lidar": [], "camera": [], "heatmaps": [], "clouds": [], "depths": []}
    ev = []
    if radar:
        w.add("/radar/heatmap", "holodata_msgs/msg/RadarHeatmap")
        for k in range(n_radar):
            s = T0 + 100_000_000 + k * period
            ev.append((s + period + 30_000_000, "radar", k, s + period // 2, (s, s + period)))
    if lidar:
        w.add("/os/points", "sensor_msgs/msg/PointCloud2")
        for k in range(int(span / 100e6) + 2):
            t = T0 + 70_000_000 + k * 100_000_000
            ev.append((t + 2_000_000, "lidar", k, t, None))
    if camera:
        w.add("/cam/depth/image_raw", "sensor_msgs/msg/Image")
        w.add("/cam/depth/camera_info", "sensor_msgs/msg/CameraInfo")
        for k in range(int(span / 200e6) + 1):
            t = T0 + 345_000_000 + k * 200_000_000
            ev.append((t + 20_000_000, "camera", k, t, None))
    if tf:
        w.add("/tf_static", "tf2_msgs/msg/TFMessage")
        w.add("/tf", "tf2_msgs/msg/TFMessage")
        ev.append((T0, "static", 0, T0, None))
        for k in range(int(span / 50e6) + 6):
            t = T0 + k * 50_000_000
            ev.append((t + 1_000_000, "odom", k, t, None))
    ev.sort(key=lambda e: (e[0], e[1]))
    K = np.array([[5.0, 0, 3.5], [0, 5.0, 2.5], [0, 0, 1]])
    T_base_radar = np.eye(4)
    T_base_radar[:3, 3] = [0.1, 0.0, 0.4]
    T_base_lidar = np.eye(4)
    T_base_lidar[:3, 3] = [0.0, 0.0, 0.8]
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = Rotation.from_euler("zyx", [-90, 0, -90], degrees=True).as_matrix()
    T_base_cam[:3, 3] = [0.2, 0.0, 0.3]
    truth.update(K=K, T_base_radar=T_base_radar, T_base_lidar=T_base_lidar, T_base_cam=T_base_cam)

    def odom(t):  # robot drives along x at 0.4 m/s
        M = np.eye(4)
        M[0, 3] = 0.4 * (t - T0) / 1e9
        return M

    truth["odom"] = odom
    for log, kind, k, stamp, extra in ev:
        if kind == "radar":
            rng = np.random.default_rng(k)
            hm = rng.uniform(0, 1, radar_shape).astype(np.float16 if encoding == "float16" else np.float32)
            w.write("/radar/heatmap", log, radar_msg(T, fmt, stamp, hm, extra, encoding))
            truth["radar"].append(stamp)
            truth["heatmaps"].append(hm)
        elif kind == "lidar":
            a = lidar_scan(k, *lidar_shape)
            w.write("/os/points", log, cloud_msg(T, fmt, stamp, "os_sensor", a))
            truth["lidar"].append(stamp)
            truth["clouds"].append(a)
        elif kind == "camera":
            d = np.full(depth_shape, 1500 + 10 * k, np.uint16)
            d[0, 0] = 0
            w.write("/cam/depth/image_raw", log, image_msg(T, fmt, stamp, "cam_optical", d, "16UC1"))
            w.write("/cam/depth/camera_info", log, camera_info_msg(T, fmt, stamp, "cam_optical", K, depth_shape[1],
                                                                   depth_shape[0]))
            truth["camera"].append(stamp)
            truth["depths"].append(d)
        elif kind == "static":
            w.write("/tf_static", log, tf_msg(T, fmt, [(stamp, "base_link", "radar", T_base_radar),
                                                       (stamp, "base_link", "os_sensor", T_base_lidar),
                                                       (stamp, "base_link", "cam_optical", T_base_cam),
                                                       (stamp, "map", "odom", np.eye(4))]))
        elif kind == "odom":
            w.write("/tf", log, tf_msg(T, fmt, [(stamp, "odom", "base_link", odom(stamp))]))
    w.close()
    return truth
