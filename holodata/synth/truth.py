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
    truth/mapping_trajectory_base.tum, mapping_trajectory_lidar.tum, mapping_odometry.tum
                                  the same for the mapping pass (``mapping_pass=True``; its own recording
                                  ``mapping/``), in the data pass's world frame; ``scene.json``
                                  ``mapping_pass`` describes it (path, scans, scan rate, odometry)
    truth/radar_frames.csv        frame, header stamp, cycle start/end, true mid time, human centre, LOS→NLOS dB
    truth/human/<frame:06d>.ply   world-frame human mesh per radar frame (only with a human)
    truth/lidar_instances.npz     only with ``visible_walkers``: per-LiDAR-scan truth instance masks on the
                                  scan's organised (rows, cols) grid, sparse: ``stamp_ns`` (S,) scan header
                                  stamps (as in trajectory_lidar.tum), ``shape`` [rows, cols], and per
                                  labelled pixel ``scan`` (M,) int32, ``pixel`` (M,) int32 row-major index,
                                  ``instance`` (M,) uint16 (walkers 1..N, hidden human N+1; 0 = not a person
                                  or no return, not stored); ``n_walkers``, ``hidden_human`` scalars.
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


def write_lidar_instances(path: Path, rows: list, n_walkers: int, hidden_human: bool) -> None:
    """Sparse per-scan instance masks (see the module docstring); ``rows`` = [(stamp_ns, (H,W) uint16)]."""
    shape = rows[0][1].shape if rows else (0, 0)
    scan, pixel, inst = [], [], []
    for i, (_, img) in enumerate(rows):
        flat = np.asarray(img, np.uint16).ravel()
        nz = np.flatnonzero(flat)
        scan.append(np.full(len(nz), i, np.int32))
        pixel.append(nz.astype(np.int32))
        inst.append(flat[nz])
    def cat(xs, dt):
        return np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)

    with open(path, "wb") as fh:  # a file handle: np.savez_compressed would append ".npz" to odd names
        np.savez_compressed(fh, stamp_ns=np.array([r[0] for r in rows], np.int64), shape=np.array(shape, np.int64),
                            scan=cat(scan, np.int32), pixel=cat(pixel, np.int32), instance=cat(inst, np.uint16),
                            n_walkers=np.int64(n_walkers), hidden_human=np.bool_(hidden_human))


def read_lidar_instances(path: Path) -> dict:
    """``truth/lidar_instances.npz`` → {"stamp_ns" (S,), "masks": callable i -> (H,W) uint16, ...}."""
    from ..safe_io import load_npz

    d = load_npz(path, "LiDAR instance file")
    H, W = (int(x) for x in d["shape"])
    order = np.argsort(d["scan"], kind="stable")
    scan, pixel, inst = d["scan"][order], d["pixel"][order], d["instance"][order]
    bounds = np.searchsorted(scan, np.arange(len(d["stamp_ns"]) + 1))

    def mask(i: int) -> np.ndarray:
        m = np.zeros(H * W, np.uint16)
        a, b = bounds[i], bounds[i + 1]
        m[pixel[a:b]] = inst[a:b]
        return m.reshape(H, W)

    d["mask"] = mask
    return d
