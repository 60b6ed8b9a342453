"""Ouster-like spinning LiDAR: organised scans with Ouster's ROS driver point layout.

Beam ``i`` has elevation ``beam_altitude_angles[i]`` (unequal, as in real metadata) and an
azimuth offset ``beam_azimuth_angles[i]`` (degrees); measurement column ``j`` fires at
``t_j = scan_start + j * period / W`` with encoder azimuth ``-2π j / W`` (clockwise seen from
above, column 0 along +x). Rays start ``lidar_origin_to_beam_origin_mm`` off the axis. Points are
in the sensor frame at each column's time (no de-skew, like the driver). No return: x = y = z =
range = 0 (``t``, ``ring``, ``ambient`` still set), ``is_dense`` False.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

# Ouster ROS driver (ouster-ros) point layout, point_step 48
OUSTER_DTYPE = np.dtype({
    "names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
    "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
    "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32],
    "itemsize": 48,
})
# sensor_msgs/PointField datatypes
POINTFIELD_TYPES = {"<f4": 7, "<u4": 6, "<u2": 4, "<f8": 8, "<i4": 5, "|u1": 2}


@dataclass(frozen=True)
class LidarConfig:
    rows: int = 64
    cols: int = 1024
    rate_hz: float = 10.0
    vertical_fov_deg: float = 33.2
    beam_origin_mm: float = 15.806
    min_range_m: float = 0.3
    max_range_m: float = 120.0
    dropout: float = 0.005
    range_noise_m: float = 0.012      # base 1-sigma range noise; grows with range and darkness
    frame_id: str = "os_sensor"

    def describe(self) -> dict:
        return asdict(self)


def beam_angles(cfg: LidarConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Unequal beam elevations (deg, descending) and azimuth offsets (deg), like Ouster metadata."""
    half = cfg.vertical_fov_deg / 2
    alt = np.linspace(half, -half, cfg.rows) + rng.normal(0.0, 0.06, cfg.rows)
    alt = np.sort(alt)[::-1]
    pattern = np.array([4.23, 1.41, -1.41, -4.23])  # four staggered firing columns, as in OS-1 metadata
    az = pattern[np.arange(cfg.rows) % 4] + rng.normal(0.0, 0.01, cfg.rows)
    return np.round(alt, 3), np.round(az, 3)


def ouster_metadata(cfg: LidarConfig, alt: np.ndarray, az: np.ndarray, serial: str) -> dict:
    """Sensor metadata JSON in the shape of Ouster's (legacy) metadata file."""
    shift = np.rint(-az / 360.0 * cfg.cols).astype(int)
    shift -= shift.min()
    return {
        "prod_line": f"OS-1-{cfg.rows}-SYNTH",
        "prod_sn": serial,
        "build_rev": "holodata-synth",
        "lidar_mode": f"{cfg.cols}x{int(round(cfg.rate_hz))}",
        "beam_altitude_angles": alt.tolist(),
        "beam_azimuth_angles": az.tolist(),
        "lidar_origin_to_beam_origin_mm": cfg.beam_origin_mm,
        "lidar_to_sensor_transform": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
        "data_format": {"columns_per_frame": cfg.cols, "pixels_per_column": cfg.rows,
                        "column_window": [0, cfg.cols - 1], "pixel_shift_by_row": shift.tolist()},
        "note": "destaggered organised cloud: row = beam, column = measurement id",
    }


class LidarModel:
    def __init__(self, cfg: LidarConfig, alt_deg: np.ndarray, az_deg: np.ndarray, face_material, face_class,
                 materials, human_material: int, ceiling_class: int):
        self.cfg = cfg
        W = cfg.cols
        enc = -2 * np.pi * np.arange(W) / W
        th = np.deg2rad(alt_deg)[:, None]
        ph = enc[None, :] - np.deg2rad(az_deg)[:, None]
        self.dirs = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.broadcast_to(np.sin(th), ph.shape)], -1)
        n = cfg.beam_origin_mm / 1000.0
        self.offsets = n * np.stack([np.cos(ph), np.sin(ph), np.zeros_like(ph)], -1)  # (H,W,3)
        self.refl = np.array([m.lidar_reflectivity for m in materials])
        self.face_material = np.asarray(face_material, np.int64)
        self.face_class = np.asarray(face_class, np.int64)
        self.human_material = human_material
        self.ceiling_class = ceiling_class

    def column_times_ns(self) -> np.ndarray:
        period = 1e9 / self.cfg.rate_hz
        return np.round(np.arange(self.cfg.cols) * period / self.cfg.cols).astype(np.int64)

    def scan(self, scene, T_cols: np.ndarray, human, rng: np.random.Generator,
             face_instance: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
        """One scan: ``T_cols`` (W,4,4) T_world_lidar per column; ``human`` (hv, hf) or None.

        Returns the (rows, cols) OUSTER_DTYPE array and stats (``human_hits``: returns on the human).
        With ``face_instance`` (F,) uint16 (instance id per face of ``human``), stats also hold
        ``instance``: (rows, cols) uint16, the id of the person each *returned* pixel hit, 0 elsewhere.
        """
        cfg = self.cfg
        H, W = cfg.rows, cfg.cols
        R = T_cols[:, :3, :3]                                  # (W,3,3)
        o_loc = self.offsets                                     # (H,W,3)
        d_w = np.einsum("wij,hwj->hwi", R, self.dirs)
        o_w = np.einsum("wij,hwj->hwi", R, o_loc) + T_cols[None, :, :3, 3]
        hit = scene.cast(o_w.reshape(-1, 3), d_w.reshape(-1, 3), dynamic=human)
        t = hit.t.astype(np.float64).reshape(H, W)
        dyn = hit.hit_dynamic.reshape(H, W)
        face = hit.face.reshape(H, W)
        cosi = np.abs(np.einsum("ij,ij->i", hit.normal.astype(np.float64), d_w.reshape(-1, 3))).reshape(H, W)
        valid = np.isfinite(t) & (t >= cfg.min_range_m) & (t <= cfg.max_range_m)
        fidx = np.where(valid & ~dyn, face, 0)
        mat = np.where(dyn, self.human_material, self.face_material[fidx])
        rho = self.refl[mat]
        cls = np.where(dyn, -1, self.face_class[fidx])
        signal = 4000.0 * rho * np.maximum(cosi, 0.02) / np.maximum(t, 0.5) ** 2
        # dark or grazing surfaces lose returns (glass, < 2 % reflectivity·cos)
        weak = rho * cosi < 0.015
        drop = rng.random((H, W)) < cfg.dropout
        valid &= ~weak & ~drop
        sigma = cfg.range_noise_m + 0.006 * np.minimum(t, 20.0) / 10.0 + 0.01 * (1.0 - rho)
        sigma = np.where(valid, np.minimum(sigma, 0.03), 0.0)
        r = np.where(valid, t + rng.normal(0.0, 1.0, (H, W)) * sigma, 0.0)
        out = np.zeros((H, W), OUSTER_DTYPE)
        # points in the sensor frame at the column time: beam offset + range * beam direction
        p = np.where(valid[..., None], self.offsets + r[..., None] * self.dirs, 0.0)
        out["x"], out["y"], out["z"] = p[..., 0], p[..., 1], p[..., 2]
        out["range"] = np.where(valid, np.rint(r * 1000.0), 0).astype(np.uint32)
        out["intensity"] = np.where(valid, signal * (1 + 0.05 * rng.normal(size=(H, W))), 0).astype(np.float32)
        out["reflectivity"] = np.where(valid, np.clip(rho * 255 * (1 + 0.03 * rng.normal(size=(H, W))), 0, 255),
                                       0).astype(np.uint16)
        amb = 40.0 + 600.0 * (cls == self.ceiling_class) * np.exp(-((np.arange(W) % 256 - 128) / 60.0) ** 2)[None, :]
        out["ambient"] = np.clip(rng.poisson(amb), 0, 65535).astype(np.uint16)
        out["t"] = self.column_times_ns()[None, :].astype(np.uint32)
        out["ring"] = np.arange(H, dtype=np.uint16)[:, None]
        stats = {"human_hits": int((valid & dyn).sum()), "returns": int(valid.sum())}
        if face_instance is not None:
            fi = np.asarray(face_instance, np.uint16)
            stats["instance"] = np.where(valid & dyn, fi[np.where(valid & dyn, face, 0)], 0).astype(np.uint16)
        return out, stats
