"""Stereo depth camera (ZED 2i-like, VGA mode) at a fixed pose that sees the hidden human.

Pinhole optical frame (z forward, x right, y down). Depth noise of a stereo matcher: disparity
noise ``sigma_disparity_px`` gives ``sigma_z = z² · sigma_d / (f · baseline)`` (grows with z²).
Invalid pixels (beyond the depth range, random holes) are NaN.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

# REP-103 camera link (x fwd, y left, z up) -> optical frame (z fwd, x right, y down)
T_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class CameraConfig:
    width: int = 672
    height: int = 376
    fx: float = 265.0
    fy: float = 265.0
    cx: float = 335.5
    cy: float = 187.5
    baseline_m: float = 0.12
    rate_hz: float = 5.0
    sigma_disparity_px: float = 0.12
    min_depth_m: float = 0.3
    max_depth_m: float = 15.0
    holes: float = 0.01
    frame_id: str = "zed2i_left_camera_optical_frame"
    cloud_frame_id: str = "zed2i_left_camera_frame"

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def describe(self) -> dict:
        d = asdict(self)
        d["K"] = self.K().tolist()
        return d

    def scaled(self, width: int, height: int) -> CameraConfig:
        s = width / self.width
        return CameraConfig(width, height, self.fx * s, self.fy * height / self.height, (width - 1) / 2,
                            (height - 1) / 2, self.baseline_m, self.rate_hz, self.sigma_disparity_px,
                            self.min_depth_m, self.max_depth_m, self.holes, self.frame_id, self.cloud_frame_id)


class CameraModel:
    def __init__(self, cfg: CameraConfig, T_world_optical: np.ndarray):
        self.cfg = cfg
        self.T = T_world_optical
        u, v = np.meshgrid(np.arange(cfg.width), np.arange(cfg.height))
        self.rays = np.stack([(u - cfg.cx) / cfg.fx, (v - cfg.cy) / cfg.fy, np.ones_like(u, float)], -1)  # z = 1
        self._fixed: tuple | None = None   # (scene, its FixedRays, ray lengths per unit depth): the static scene cast once

    def frame(self, scene, human, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        """Depth image (h, w) float32 m (NaN invalid) in the optical frame, and stats. The camera does
        not move: the static scene is cast once per ``scene`` and each frame casts only the pixels whose
        view may meet ``human`` (:class:`holodata.raytrace.FixedRays`; the same depths as a full cast)."""
        cfg = self.cfg
        if self._fixed is None or self._fixed[0] is not scene:
            d_loc = self.rays.reshape(-1, 3)
            norm = np.linalg.norm(d_loc, axis=1)
            d_w = (d_loc / norm[:, None]) @ self.T[:3, :3].T
            o_w = np.broadcast_to(self.T[:3, 3], d_w.shape)
            self._fixed = (scene, scene.fixed_rays(o_w, d_w), norm)
        _, fixed, norm = self._fixed
        hit = fixed.cast(human)
        t = hit.t.astype(np.float64)
        z = t / norm  # depth along the optical axis
        ok = np.isfinite(z) & (z >= cfg.min_depth_m) & (z <= cfg.max_depth_m)
        sigma = z ** 2 * cfg.sigma_disparity_px / (cfg.fx * cfg.baseline_m)
        zn = np.where(ok, z + rng.normal(0.0, 1.0, z.shape) * np.where(ok, sigma, 0.0), np.nan)
        ok &= rng.random(z.shape) >= cfg.holes
        zn = np.where(ok, zn, np.nan).astype(np.float32)
        return zn.reshape(cfg.height, cfg.width), {"human_pixels": int((ok & hit.hit_dynamic).sum())}

    def cloud(self, depth: np.ndarray) -> np.ndarray:
        """(h, w, 3) float32 points in the REP-103 camera link frame (NaN where depth is NaN)."""
        p_opt = self.rays * depth[..., None]
        return (p_opt @ T_LINK_OPTICAL[:3, :3].T).astype(np.float32)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_link (REP-103: x toward the target, z up-ish) for a camera at ``eye``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    x = target - eye
    x /= np.linalg.norm(x)
    y = np.cross(np.asarray(up, float), x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def value_noise(p: np.ndarray, scale: float, salt: int = 0) -> np.ndarray:
    """Smooth 3-D value noise in [0, 1] at points ``p`` (N,3) m with lattice spacing ``scale`` m
    (world-anchored, so both cameras of a stereo pair see the same texture)."""
    q = p / scale
    i = np.floor(q).astype(np.int64)
    f = q - i
    f = f * f * (3 - 2 * f)
    out = np.zeros(len(p))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                h = ((i[:, 0] + dx) * 73856093) ^ ((i[:, 1] + dy) * 19349663) ^ ((i[:, 2] + dz) * 83492791) ^ (salt * 2654435761)
                h = (h ^ (h >> 13)) * 1274126177
                v = ((h ^ (h >> 16)) & 0xFFFF) / 65535.0
                w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
                out += w * v
    return out


class StereoModel:
    """Rectified left/right mono8 images of a textured scene: the left camera is the depth camera's
    optical frame, the right one sits ``baseline_m`` along its +x; both share the intrinsics, so a
    block matcher (OpenCV StereoSGBM) recovers depth = fx·baseline / disparity."""

    def __init__(self, cfg: CameraConfig, T_world_optical: np.ndarray, albedo: np.ndarray, face_material: np.ndarray,
                 human_albedo: float):
        self.cfg = cfg
        self.T_left = T_world_optical
        self.T_right = T_world_optical.copy()
        self.T_right[:3, 3] += T_world_optical[:3, 0] * cfg.baseline_m
        self.rays = CameraModel(cfg, T_world_optical).rays.reshape(-1, 3)
        self.albedo = np.asarray(albedo, float)
        self.face_material = np.asarray(face_material, np.int64)
        self.human_albedo = float(human_albedo)

    def render(self, scene, human, T: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(h, w) uint8 image from the camera at T_world_optical ``T``."""
        cfg = self.cfg
        d = self.rays / np.linalg.norm(self.rays, axis=1, keepdims=True)
        dw = d @ T[:3, :3].T
        hit = scene.cast(np.broadcast_to(T[:3, 3], dw.shape), dw, dynamic=human)
        t = hit.t.astype(np.float64)
        ok = np.isfinite(t)
        p = T[:3, 3] + np.where(ok, t, 0.0)[:, None] * dw
        fz = np.where(ok & ~hit.hit_dynamic, hit.face, 0)
        alb = np.where(hit.hit_dynamic, self.human_albedo, self.albedo[self.face_material[fz]])
        tex = 0.45 * value_noise(p, 0.04, 1) + 0.35 * value_noise(p, 0.15, 2) + 0.2 * value_noise(p, 0.6, 3)
        shade = np.abs(np.einsum("ij,ij->i", hit.normal.astype(np.float64), dw))  # head-light
        light = 40.0 + 200.0 * alb * (0.3 + 0.7 * tex) * (0.4 + 0.6 * shade) / np.maximum(1.0, 0.25 * t)
        img = np.where(ok, light, 10.0) + rng.normal(0.0, 1.5, len(t))
        return np.clip(np.rint(img), 0, 255).astype(np.uint8).reshape(cfg.height, cfg.width)

    def pair(self, scene, human, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        return self.render(scene, human, self.T_left, rng), self.render(scene, human, self.T_right, rng)
