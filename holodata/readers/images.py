"""``sensor_msgs/Image`` (depth) + ``sensor_msgs/CameraInfo`` -> points.

Depth encodings: ``16UC1`` / ``mono16`` millimetres, ``32FC1`` metres; 0, NaN and inf are "no
depth". Row padding (``step`` > width x pixel size) and ``is_bigendian`` are honoured. A payload
shorter than ``step x height`` raises :class:`DecodeError` naming the topic (real bags carry such
truncated images). Points come out in the camera's optical frame (REP-103 camera convention:
x right, y down, z forward), unprojected with the pinhole ``K`` of the CameraInfo (distortion is
ignored: depth images published by stereo/RGB-D drivers are rectified).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import DecodeError

# encoding -> (numpy dtype code, channels)
ENCODINGS = {
    "mono8": ("u1", 1), "8UC1": ("u1", 1), "mono16": ("u2", 1), "16UC1": ("u2", 1), "16SC1": ("i2", 1),
    "32FC1": ("f4", 1), "64FC1": ("f8", 1), "32SC1": ("i4", 1),
    "rgb8": ("u1", 3), "bgr8": ("u1", 3), "8UC3": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4),
    "8UC4": ("u1", 4), "rgb16": ("u2", 3), "bgr16": ("u2", 3), "rgba16": ("u2", 4), "bgra16": ("u2", 4),
    "16UC3": ("u2", 3), "32FC3": ("f4", 3), "yuv422": ("u1", 2), "uyvy": ("u1", 2), "yuyv": ("u1", 2),
}
# depth encodings -> scale to metres
DEPTH_SCALE = {"16UC1": 1e-3, "mono16": 1e-3, "32FC1": 1.0, "64FC1": 1.0}


def is_depth_encoding(encoding: str) -> bool:
    return encoding in DEPTH_SCALE


def image_array(msg, topic: str = "") -> np.ndarray:
    """(H, W) or (H, W, C) array of an Image in its own encoding (native byte order)."""
    where = f"topic {topic}: " if topic else ""
    enc = str(msg.encoding)
    if enc not in ENCODINGS:
        raise DecodeError(f"{where}Image encoding {enc!r} is not supported")
    code, ch = ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    dt = np.dtype((">" if msg.is_bigendian else "<") + code)
    px = dt.itemsize * ch
    data = msg.data
    if not isinstance(data, np.ndarray):
        data = np.frombuffer(bytes(data), np.uint8)
    if step < w * px:
        raise DecodeError(f"{where}Image step {step} < width {w} x {px} B ({enc})")
    need = step * h
    if data.size < need:
        raise DecodeError(f"{where}Image payload is {data.size} bytes, step {step} x height {h} needs {need} "
                          f"(truncated message)")
    shape = (h, w) + ((ch,) if ch > 1 else ())
    strides = (step, px) + ((dt.itemsize,) if ch > 1 else ())
    return np.ndarray(shape, dt, buffer=data, strides=strides).astype(dt.newbyteorder("="))


def depth_image(msg, topic: str = "") -> np.ndarray:
    """(H, W) float32 metres, NaN = no depth."""
    enc = str(msg.encoding)
    if enc not in DEPTH_SCALE:
        raise DecodeError(f"{'topic ' + topic + ': ' if topic else ''}Image encoding {enc!r} is not a depth "
                          f"encoding (16UC1/mono16 mm, 32FC1 m)")
    a = image_array(msg, topic).astype(np.float32)
    if DEPTH_SCALE[enc] != 1.0:
        a *= np.float32(DEPTH_SCALE[enc])
    a[~np.isfinite(a) | (a <= 0)] = np.nan
    return a


@dataclass
class CameraModel:
    """Pinhole intrinsics: ``K`` (3, 3) float64 pixels; ``width``/``height`` pixels."""

    K: np.ndarray
    width: int
    height: int
    frame_id: str = ""
    distortion_model: str = ""
    D: tuple = ()

    def to_attrs(self) -> dict:
        return {"K": self.K.tolist(), "width": self.width, "height": self.height, "frame_id": self.frame_id,
                "distortion_model": self.distortion_model, "D": list(self.D)}


def camera_model(msg, topic: str = "") -> CameraModel:
    """From a CameraInfo (ROS 1 ``K`` or ROS 2 ``k``)."""
    K = getattr(msg, "k", None)
    if K is None:
        K = getattr(msg, "K", None)
    D = getattr(msg, "d", None)
    if D is None:
        D = getattr(msg, "D", ())
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise DecodeError(f"{'topic ' + topic + ': ' if topic else ''}CameraInfo has no focal length (K = {K.ravel().tolist()})")
    return CameraModel(K, int(msg.width), int(msg.height), str(msg.header.frame_id), str(msg.distortion_model),
                       tuple(float(x) for x in np.asarray(D).ravel()))


# REP-103 camera link (x forward, y left, z up) -> optical (z forward, x right, y down): p_link = R p_opt
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def pinhole_residual(xyz: np.ndarray, rows: np.ndarray, cols: np.ndarray, K: np.ndarray) -> float:
    """RMS (pixels) of projecting optical-frame points ``xyz`` (N,3) through ``K`` (3,3) against the
    pixels (``rows``, ``cols``) (N,) they came from."""
    z = xyz[:, 2]
    u = K[0, 0] * xyz[:, 0] / z + K[0, 2]
    v = K[1, 1] * xyz[:, 1] / z + K[1, 2]
    return float(np.sqrt(np.mean((u - cols) ** 2 + (v - rows) ** 2)))


def fit_pinhole(xyz: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Intrinsics of an organised camera cloud: its rows and columns are the pixels a pinhole camera
    projected the points ``xyz`` (N,3, the cloud's frame) from. Tries the cloud in an optical frame
    (z forward) and in a REP-103 link frame (x forward; ZED / RealSense ``camera_link`` clouds); for
    each, ``col = fx·x/z + cx`` and ``row = fy·y/z + cy`` by linear least squares. Returns (K (3,3),
    R (3,3) with p_optical = R · p_cloud, RMS pixels) of the better fit, None when < 50 points lie in
    front of the camera."""
    best = None
    for R in (np.eye(3), R_LINK_OPTICAL.T):
        q = np.asarray(xyz, np.float64) @ R.T
        ok = q[:, 2] > 1e-3
        if ok.sum() < 50:
            continue
        a, b = q[ok, 0] / q[ok, 2], q[ok, 1] / q[ok, 2]
        (fx, cx), *_ = np.linalg.lstsq(np.column_stack([a, np.ones_like(a)]), cols[ok].astype(np.float64), rcond=None)
        (fy, cy), *_ = np.linalg.lstsq(np.column_stack([b, np.ones_like(b)]), rows[ok].astype(np.float64), rcond=None)
        if fx <= 0 or fy <= 0:
            continue
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        rms = pinhole_residual(q[ok], rows[ok], cols[ok], K)
        if best is None or rms < best[2]:
            best = (K, R, rms)
    return best


def depth_to_points(depth: np.ndarray, K: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Unproject a (H, W) metres depth image: (N, 3) float32 optical-frame points of the valid
    pixels (row-major) and their (N,) flat pixel indices. ``stride`` subsamples rows and columns."""
    H, W = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    d = depth[::stride, ::stride]
    v, u = np.nonzero(np.isfinite(d))
    z = d[v, u].astype(np.float32)
    u = u * stride
    v = v * stride
    x = ((u - cx) / fx).astype(np.float32) * z
    y = ((v - cy) / fy).astype(np.float32) * z
    return np.stack([x, y, z], axis=1), (v.astype(np.int64) * W + u)


# --------------------------------------------------------------------------------------------------
# stereo pairs -> depth (OpenCV semi-global matching), when a recording has no depth image

def gray_image(msg, topic: str = "") -> np.ndarray:
    """(H, W) uint8 of a mono8 / rgb8 / bgr8 / rgba8 / bgra8 Image."""
    a = image_array(msg, topic)
    enc = str(msg.encoding)
    if a.ndim == 2 and a.dtype == np.uint8:
        return a
    if a.ndim == 3 and a.dtype == np.uint8 and enc in ("rgb8", "bgr8", "rgba8", "bgra8", "8UC3", "8UC4"):
        w = np.array([0.299, 0.587, 0.114]) if enc.startswith("rgb") else np.array([0.114, 0.587, 0.299])
        return np.clip(a[..., :3].astype(np.float32) @ w.astype(np.float32), 0, 255).astype(np.uint8)
    raise DecodeError(f"{'topic ' + topic + ': ' if topic else ''}Image encoding {enc!r} cannot be used for stereo "
                      f"matching (mono8/rgb8/bgr8)")


def stereo_baseline(right_info_msg) -> float:
    """Baseline (m) of a rectified pair from the right CameraInfo projection: P[0,3] = -fx * B."""
    P = getattr(right_info_msg, "p", None)
    if P is None:
        P = right_info_msg.P
    P = np.asarray(P, np.float64).reshape(3, 4)
    if not P[0, 0] > 0 or P[0, 3] == 0:
        raise DecodeError("right CameraInfo has no stereo baseline (P[0,3] = -fx*baseline is 0)")
    return float(-P[0, 3] / P[0, 0])


def stereo_depth(left: np.ndarray, right: np.ndarray, fx: float, baseline_m: float, min_depth_m: float = 0.3,
                 block: int = 5) -> np.ndarray:
    """(H, W) float32 metres from a rectified (left, right) uint8 pair with OpenCV StereoSGBM:
    depth = fx * baseline / disparity; NaN where the matcher finds no disparity."""
    try:
        import cv2
    except ImportError as err:
        from ..errors import RecordingError

        raise RecordingError("stereo depth needs OpenCV (pip install opencv-python-headless)") from err
    max_disp = fx * abs(baseline_m) / min_depth_m
    n = int(min(256, max(16, 16 * np.ceil(max_disp / 16))))
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=n, blockSize=block, P1=8 * block * block,
                              P2=32 * block * block, uniquenessRatio=10, speckleWindowSize=50, speckleRange=2,
                              mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    disp = m.compute(np.ascontiguousarray(left), np.ascontiguousarray(right)).astype(np.float32) / 16.0
    depth = np.full(disp.shape, np.nan, np.float32)
    ok = disp > 0
    depth[ok] = np.float32(fx * abs(baseline_m)) / disp[ok]
    return depth
