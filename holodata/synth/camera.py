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

    def scaled(self, width: int, height: int) -> "CameraConfig":
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

    def frame(self, scene, human, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        """Depth image (h, w) float32 m (NaN invalid) in the optical frame, and stats."""
        cfg = self.cfg
        d_loc = self.rays.reshape(-1, 3)
        norm = np.linalg.norm(d_loc, axis=1)
        d_w = (d_loc / norm[:, None]) @ self.T[:3, :3].T
        o_w = np.broadcast_to(self.T[:3, 3], d_w.shape)
        hit = scene.cast(o_w, d_w, dynamic=human)
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
