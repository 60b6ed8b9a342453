"""The hidden ``truth/`` folder written next to a synthetic recording.

Layout (all deterministic for a given seed)::

    truth/scene.json              corner, widths, materials, human, seed, sensor configs, clocks, stats
    truth/mesh.ply                true static mesh, per-face class (``comment class <id> <name>``)
    truth/mesh_face_material.npy  (F,) uint8 material index per face (table in scene.json)
    truth/extrinsics.json         T_base_radar, T_base_lidar, T_world_camera (link + optical), T_map_odom
    truth/trajectory_base.tum     true T_world_base_link at 100 Hz (true time)
    truth/trajectory_radar.tum    true T_world_radar per radar frame (line k = frame k), stamped with the
                                  frame's header stamp, pose at the true mid-cycle time
    truth/trajectory_lidar.tum    true T_world_lidar per LiDAR scan (header stamp; pose at scan start)
    truth/odometry.tum            the drifting T_odom_base published on /tf (for comparison)
    truth/radar_frames.csv        frame, header stamp, cycle start/end, true mid time, human centre, LOS→NLOS dB
    truth/human/<frame:06d>.ply   world-frame human mesh per radar frame (only with a human)
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..meshio import Mesh, write_ply
from ..trajectory import Trajectory, write_tum


def _round(obj):
    if isinstance(obj, float):
        return round(obj, 9)
    if isinstance(obj, dict):
        return {str(k): _round(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_round(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _round(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return round(float(obj), 9)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def write_json(path: Path, obj) -> None:
    Path(path).write_text(json.dumps(_round(obj), indent=2, sort_keys=True) + "\n")


def write_mesh(path: Path, vertices, faces, face_class=None, class_names=None) -> None:
    write_ply(path, Mesh(vertices, faces, face_class, dict(class_names or {})))


def write_trajectory(path: Path, t_ns: np.ndarray, poses: np.ndarray) -> None:
    write_tum(path, Trajectory(np.asarray(t_ns, np.int64), np.asarray(poses, np.float64)))


def write_frames_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        Path(path).write_text("")
        return
    keys = list(rows[0].keys())
    lines = [",".join(keys)]
    for r in rows:
        vals = []
        for k in keys:
            v = r[k]
            if isinstance(v, (float, np.floating)):
                vals.append("nan" if not np.isfinite(v) else f"{float(v):.6f}")
            else:
                vals.append(str(v))
        lines.append(",".join(vals))
    Path(path).write_text("\n".join(lines) + "\n")
