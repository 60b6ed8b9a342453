"""The world frame and per-frame poses (TF anchors, :func:`frame_poses`) and the static mesh of the
scans (:func:`static_mesh`, :class:`StaticMap`)."""
from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np

from ...conventions import transform_points
from ...dataset.layout import LIDAR_TIMESTAMP_NS, POSE_T_WORLD_RADAR, TF_T_WORLD_LIDAR, TIME_TIMESTAMP_NS
from ...progress import track
from ...trajectory import Trajectory
from .config import Scans, SlamConfig
from .points import downsample
from .refine import deskewed_scans, level_seeds, mesh_scan_subset


def _attr_T(d, key) -> np.ndarray | None:
    v = (d or {}).get(key)
    if v is None:
        return None
    T = np.asarray(v, np.float64)
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None


def tf_lidar_poses(scene, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, str] | None:
    """TF poses T_world_lidar (S,4,4) at ``stamps_ns`` (S,) from ingest's ``tf/T_world_lidar`` (the
    LiDAR frame's TF pose at each frame's scan, NaN where TF does not cover it), with (S,) bool
    "covered" (within the covered frames' time span) and the world frame's name; None without it."""
    if TF_T_WORLD_LIDAR not in set(scene.arrays()):
        return None
    a = scene[TF_T_WORLD_LIDAR]
    P = np.asarray(a[...], np.float64)
    name = LIDAR_TIMESTAMP_NS if LIDAR_TIMESTAMP_NS in set(scene.arrays()) else TIME_TIMESTAMP_NS
    t = np.asarray(scene[name][...], np.int64)
    ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1) & (t > 0)
    if not ok.any():
        return None
    t, P = t[ok], P[ok]
    order = np.argsort(t, kind="stable")
    t, P = t[order], P[order]
    keep = np.r_[True, np.diff(t) > 0]
    t, P = t[keep], P[keep]
    s = np.asarray(stamps_ns, np.int64)
    cov = (s >= t[0]) & (s <= t[-1])
    out = Trajectory(t, P).interpolate(np.clip(s, t[0], t[-1])) if len(t) > 1 else np.repeat(P[:1], len(s), 0)
    return out, cov, str(dict(a.attrs).get("world_frame"))


def level_tf_poses(scene, stamps_ns: np.ndarray) -> np.ndarray | None:
    """ingest's TF LiDAR poses (:func:`tf_lidar_poses`, (S,4,4) at ``stamps_ns``, held at the first
    and last covered pose outside TF's span) when they are a ground robot's on a level floor
    (:func:`level_seeds` over the covered scans), else None. A planar TF tree (``map → odom`` from a
    2D localiser, ``odom → base_link`` from wheel odometry) fixes the LiDAR's height, roll and pitch
    without drift — the three degrees of freedom a ground robot's floor fixes (LeGO-LOAM, Shan &
    Englot, IROS 2018, §III-D, solves them from ground points apart from the other three) — where
    scan-to-map ICP on a sparse LiDAR drifts in roll and pitch as the map grows (docs/design/slam.md);
    the kiss-icp-seeded :func:`refine` takes those three from them (``health.sequential.vertical_from``)."""
    rt = tf_lidar_poses(scene, stamps_ns)
    if rt is None or rt[1].sum() < 2 or not level_seeds(rt[0][rt[1]]):
        return None
    return rt[0]


def tf_agreement(scene, stamps_ns: np.ndarray, poses: np.ndarray) -> dict | None:
    """How far slam's LiDAR poses (S,4,4 at ``stamps_ns``) lie from TF's (:func:`tf_lidar_poses`) over
    the scans TF covers: {"scans", "position_max_m", "position_last_m", "yaw_max_deg"}; None without TF
    poses. Both drift away from the anchor scan (odometry in TF; no loop closure in slam), so this
    bounds neither alone, but a map whose world is TF's world is only as close to TF's as this says,
    far from the anchor (a camera pose from TF is a guess good to about that much there)."""
    from ...conventions import yaw_rad

    rt = tf_lidar_poses(scene, stamps_ns)
    if rt is None or not rt[1].any():
        return None
    P, Q = np.asarray(poses, np.float64)[rt[1]], rt[0][rt[1]]
    gap = np.linalg.norm(P[:, :3, 3] - Q[:, :3, 3], axis=1)
    dyaw = np.array([np.degrees(abs(np.angle(np.exp(1j * (yaw_rad(a) - yaw_rad(b)))))) for a, b in zip(P, Q)])
    return {"scans": int(rt[1].sum()), "position_max_m": round(float(gap.max()), 4),
            "position_last_m": round(float(gap[-1]), 4), "yaw_max_deg": round(float(dyaw.max()), 3)}


def anchor_pose(scene, stamps_ns: np.ndarray) -> tuple[np.ndarray, int, dict]:
    """The world pose T_world_lidar of one scan, that scan's index into ``stamps_ns`` (the scans'
    stamps, (S,)) and how it was chosen (see module doc, 4.): the first scan TF covers, from ingest's
    ``tf/T_world_lidar``, else ingest's TF radar poses through the extrinsics; else the base frame
    (``extrinsics.lidar``) or the LiDAR frame at the first scan."""
    stamps_ns = np.asarray(stamps_ns, np.int64).reshape(-1)
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    prev = (scene.attrs.get("slam") or {}).get("anchor")
    names = set(scene.arrays())
    r = tf_lidar_poses(scene, stamps_ns)
    if r is not None and r[1].any():
        j = int(np.argmax(r[1]))
        return r[0][j], j, {"kind": "tf", "world_frame": r[2], "via": TF_T_WORLD_LIDAR, "scan": j}
    if POSE_T_WORLD_RADAR in names and T_bl is not None and T_br is not None:
        pa = scene[POSE_T_WORLD_RADAR]
        src = dict(pa.attrs).get("source")
        if src == "tf":
            P = np.asarray(pa[...], np.float64)
            t = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64)
            ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
            if ok.sum() >= 1:
                T_wr = Trajectory(t[ok], P[ok]).interpolate(stamps_ns[:1])[0]
                return T_wr @ np.linalg.inv(T_br) @ T_bl, 0, {"kind": "tf", "world_frame": dict(pa.attrs).get("world_frame")}
    if prev and prev.get("kind") == "tf" and prev.get("T_world_lidar0") is not None:
        return np.asarray(prev["T_world_lidar0"], np.float64), 0, {"kind": "tf", "world_frame": prev.get("world_frame")}
    if T_bl is not None:
        return T_bl, 0, {"kind": "base", "world_frame": "base frame at the first scan"}
    return np.eye(4), 0, {"kind": "lidar", "world_frame": "LiDAR frame at the first scan"}


def frame_poses(scene, scans: Scans, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """Per-frame (T,4,4) T_world_lidar at each frame's LiDAR stamp (frame time when it has none) and
    T_world_radar at the frame time through the extrinsic (None without one)."""
    names = set(scene.arrays())
    ft = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64) if TIME_TIMESTAMP_NS in names else None
    lt = np.asarray(scene[LIDAR_TIMESTAMP_NS][...], np.int64) if LIDAR_TIMESTAMP_NS in names else None
    if ft is None:
        ft = lt
    t_l = np.where(lt > 0, lt, ft) if lt is not None else ft
    traj = Trajectory(scans.stamp_ns, poses)
    Tl = traj.interpolate(t_l)
    outside = int(((ft < scans.stamp_ns[0] - 1) | (ft > scans.stamp_ns[-1] + 1)).sum())
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    info = {"frames_outside_scans": outside}
    Tr = None
    if T_br is not None:
        T_lr = (np.linalg.inv(T_bl) if T_bl is not None else np.eye(4)) @ T_br
        Tr = traj.interpolate(ft) @ T_lr
        info["T_lidar_radar"] = T_lr.tolist()
    elif scene.attrs.get("frame_sensor") == "radar":
        info["warning"] = "no radar extrinsic in scene attrs; pose/T_world_radar not written by slam"
    return Tl, Tr, info


def _mesh_background(world: list, origins: np.ndarray, cfg: SlamConfig):
    """The voxel background model of the mesh scans ``world`` (list of (Ni,3) deskewed world points)
    seen from ``origins`` (S,3), downsampled to ``fine_map_voxel``: numpy and scipy only, so it can run
    in a forked process."""
    from ..background import VoxelBackground

    return VoxelBackground.build([downsample(w, cfg.fine_map_voxel) for w in world], voxel=cfg.background_voxel,
                                 min_fraction=cfg.background_min_fraction, origins=origins)


@dataclass
class StaticMap:
    """The static scene :func:`static_mesh` makes: the mesh ``vertices`` (V,3) / ``faces`` (F,3), the
    ``points`` (M,3) float64 m it was reconstructed from (world frame; the scans' static returns
    averaged per ``MeshConfig.voxel`` cell, moving ones removed: the map ``holodata register``
    registers the camera to), ``info`` (mesh figures) and the voxel ``background`` model used."""

    vertices: np.ndarray
    faces: np.ndarray
    points: np.ndarray
    info: dict
    background: object


def static_mesh(scans: Scans, poses: np.ndarray, cfg: SlamConfig, max_range: float, mesh_cfg=None, background=None,
                quiet: bool = True) -> StaticMap:
    """Mesh of the static scene from the scans at ``poses`` (world frame), with its point cloud.

    Without a ``background`` its model is built in a forked process while this one accumulates the
    points split by background voxel (:class:`~.mesh.PointAccumulator` ``split``), whose moving ones
    are dropped once the model is there: the same cloud as filtering each scan first."""
    from ...parallel import cpus, fork_call
    from ..mesh import MeshConfig, PointAccumulator, build_mesh

    mesh_cfg = mesh_cfg or MeshConfig()
    sub = mesh_scan_subset(poses, cfg.mesh_max_scans, cfg.map_keyframe_m, cfg.map_keyframe_deg)
    P = poses[sub]
    # each scan deskewed and moved to the world once, for both the background model and the cloud
    world = [transform_points(T, p) for T, p in zip(P, deskewed_scans(scans, poses, cfg, max_range, sub))]
    model = None
    if background is None:
        model = fork_call(_mesh_background, world, P[:, :3, 3], cfg, label="slam: mesh background model",
                          enabled=cpus() > 1)
    acc = PointAccumulator(mesh_cfg.voxel, split=cfg.background_voxel if background is None else background.voxel)
    try:
        for T, w in track(list(zip(P, world)), total=len(P), description="slam: static points", quiet=quiet):
            acc.add(w, T[:3, 3])
    except BaseException:
        if model is not None:
            with contextlib.suppress(Exception):
                model()   # reap the worker before raising
        raise
    del world
    if model is not None:
        background = model()
    removed = acc.drop_split_cells(lambda centres: ~background.contains(centres, tolerance=0))
    pts, view, _ = acc.cloud()
    v, f, info = build_mesh(pts, view, mesh_cfg, sensor_xyz=P[:, :3, 3])
    info["dynamic_points_removed"] = removed
    info["scans_used"] = int(len(sub))
    return StaticMap(v, f, pts, info, background)


def guess_poses(scene, scans: Scans) -> tuple[np.ndarray | None, str]:
    """Odometry/TF-based guesses T_world_lidar (S,4,4) at the scan stamps: ingest's TF radar poses
    (``pose/T_world_radar``, source tf) through the extrinsics, else ingest's ``tf/T_world_lidar``
    (:func:`tf_lidar_poses`); (None, "none") without either. Only the dataset is read: ingest stored
    what TF says (a dataset is self-sufficient once ingested)."""
    names = set(scene.arrays())
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    if POSE_T_WORLD_RADAR in names and T_br is not None and dict(scene[POSE_T_WORLD_RADAR].attrs).get("source") == "tf":
        P = np.asarray(scene[POSE_T_WORLD_RADAR][...], np.float64)
        t = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64)
        ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
        if ok.sum() >= 2:
            T_rl = np.linalg.inv(T_br) @ (T_bl if T_bl is not None else np.eye(4))
            return Trajectory(t[ok], P[ok]).interpolate(scans.stamp_ns) @ T_rl, "tf (pose/T_world_radar)"
    rt = tf_lidar_poses(scene, scans.stamp_ns)
    if rt is not None and rt[1].all():
        return rt[0], "tf (tf/T_world_lidar)"
    return None, "none"
