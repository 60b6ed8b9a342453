"""Accuracy of human segmentation and camera registration against ``holodata synth`` truth.

* :func:`ap50`: instance-segmentation average precision at IoU 0.5 (pixel masks on the LiDAR grid),
  all-point interpolated (VOC 2010+ / COCO-style single threshold). Predictions are ranked by
  score (cluster size); a prediction is a true positive when it overlaps a not-yet-matched truth
  instance of the same scan with IoU >= 0.5. Truth instances with fewer than ``min_truth_pixels``
  returns are *ignored* (neither missed nor matched: predictions on them are not counted as false
  positives), the usual crowd/too-small rule — a person seen by 5 beams at 9 m is not a target.
* :func:`extrinsic_error`: translation (m) and rotation (deg) between an estimated and the true
  ``T_world_camera`` (``truth/extrinsics.json`` ``T_world_camera_optical``: the depth cloud frame).
* :func:`solid_centroid` / :func:`human_centroid_errors`: centre of mass of the solid a closed
  surface encloses; per-frame distance between the registered human surface's and the true human
  mesh's (``truth/human/<frame>.ply``), the same operator on both.
* :func:`robot_relative_extrinsic_error`: the camera pose relative to the LiDAR at each scan, estimate
  (scene poses) vs truth — free of a common offset of a SLAM map against the true world.
* :func:`aligned_extrinsic_error`: the extrinsic after aligning the estimated LiDAR trajectory to the
  true one (evo-style SE(3) alignment of the poses, as the ATE does on a straight path) — how a
  quantity estimated in a SLAM map's frame is judged against the true world.
* :func:`evaluate_register`: all of the above for one registered scene (``holodata register --truth``),
  with a JSON report and a PNG of the per-frame centroid errors.
* :func:`write_truth_poses`: puts the true LiDAR poses (``truth/trajectory_lidar.tum``, matched by
  the scans' header stamps ``lidar/timestamp_ns``) into a dataset as ``pose/T_world_lidar`` (and the
  true radar poses as ``pose/T_world_radar``) so that segmentation/registration can be developed
  and scored without SLAM error.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..conventions import rotation_angle_deg
from ..dataset.layout import (
    CALIB_T_WORLD_CAMERA,
    HUMAN_FACES,
    HUMAN_VERTICES,
    LIDAR_INSTANCE,
    LIDAR_TIMESTAMP_NS,
    POSE_T_WORLD_LIDAR,
    POSE_T_WORLD_RADAR,
)
from ..errors import InputError


# ------------------------------------------------------------------------------ segmentation AP
def match_scan(pred: np.ndarray, truth: np.ndarray, min_truth_pixels: int = 20, iou: float = 0.5
               ) -> tuple[list[tuple[float, bool]], int]:
    """One scan: (list of (score, is_tp) per counted prediction, number of counted truth instances).

    ``pred``/``truth`` (H,W) integer instance images (0 = none). Score = predicted mask size."""
    pred = np.asarray(pred).ravel().astype(np.int64)
    truth = np.asarray(truth).ravel().astype(np.int64)
    pid = np.unique(pred[pred > 0])
    tid, tsz = np.unique(truth[truth > 0], return_counts=True)
    counted = {int(t) for t, s in zip(tid, tsz) if s >= min_truth_pixels}
    ignored = {int(t) for t, s in zip(tid, tsz) if s < min_truth_pixels}
    psz = {int(p): int((pred == p).sum()) for p in pid}
    # overlaps
    both = (pred > 0) & (truth > 0)
    pairs, inter = np.unique(np.stack([pred[both], truth[both]], 1), axis=0, return_counts=True) \
        if both.any() else (np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    tsize = {int(t): int(s) for t, s in zip(tid, tsz)}
    ious: dict[int, list[tuple[float, int]]] = {}
    for (p, t), n in zip(pairs, inter):
        u = psz[int(p)] + tsize[int(t)] - int(n)
        ious.setdefault(int(p), []).append((n / u, int(t)))
    out = []
    used: set[int] = set()
    for p in sorted(psz, key=lambda q: -psz[q]):
        cands = sorted(ious.get(p, []), reverse=True)
        hit = next((t for v, t in cands if v >= iou and t in counted and t not in used), None)
        if hit is not None:
            used.add(hit)
            out.append((float(psz[p]), True))
            continue
        if any(v >= iou and t in ignored for v, t in cands):
            continue  # on an ignored (too small) truth instance: not counted
        out.append((float(psz[p]), False))
    return out, len(counted)


def average_precision(results: list[tuple[float, bool]], n_truth: int) -> dict:
    """All-point interpolated AP from (score, is_tp) over all scans and the number of truth instances."""
    if n_truth == 0:
        return {"ap": float("nan"), "precision": float("nan"), "recall": float("nan"), "n_truth": 0,
                "n_pred": len(results)}
    if not results:
        return {"ap": 0.0, "precision": 0.0, "recall": 0.0, "n_truth": n_truth, "n_pred": 0}
    order = np.argsort([-s for s, _ in results], kind="stable")
    tp = np.array([results[i][1] for i in order], float)
    ctp, cfp = np.cumsum(tp), np.cumsum(1 - tp)
    rec = ctp / n_truth
    prec = ctp / np.maximum(ctp + cfp, 1e-12)
    mrec = np.concatenate([[0.0], rec, [1.0]])
    mpre = np.concatenate([[1.0], prec, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    i = np.flatnonzero(mrec[1:] != mrec[:-1])
    ap = float(np.sum((mrec[i + 1] - mrec[i]) * mpre[i + 1]))
    return {"ap": ap, "precision": float(prec[-1]), "recall": float(rec[-1]), "n_truth": int(n_truth),
            "n_pred": len(results)}


def ap50(preds, truths, min_truth_pixels: int = 20) -> dict:
    """AP at IoU 0.5 over scans: ``preds``/``truths`` iterables of (H,W) instance images."""
    allr, nt = [], 0
    for p, t in zip(preds, truths):
        r, n = match_scan(p, t, min_truth_pixels)
        allr += r
        nt += n
    return average_precision(allr, nt)


def segmentation_ap50(url: str, scene_id: str, truth_dir: str | Path, min_truth_pixels: int = 20) -> dict:
    """AP50 of a scene's ``lidar/instance`` against ``truth/lidar_instances.npz`` (scans matched by
    header stamp ``lidar/timestamp_ns``)."""
    from ..dataset import open_dataset
    from ..synth.truth import read_lidar_instances

    path = Path(truth_dir) / "lidar_instances.npz"
    if not path.is_file():
        raise InputError(f"{path}: no truth instance masks (synthesise with visible_walkers > 0)")
    tr = read_lidar_instances(path)
    sc = open_dataset(url).scene(scene_id)
    inst = sc[LIDAR_INSTANCE]
    stamps = np.asarray(sc[LIDAR_TIMESTAMP_NS][...], np.int64)
    where = {int(s): i for i, s in enumerate(tr["stamp_ns"])}
    preds, truths = [], []
    for k, s in enumerate(stamps):
        i = where.get(int(s))
        if i is None:
            continue
        preds.append(np.asarray(inst[k]))
        truths.append(tr["mask"](i))
    out = ap50(preds, truths, min_truth_pixels)
    out["scans"] = len(preds)
    return out


# ------------------------------------------------------------------------------ registration
def extrinsic_error(T_est: np.ndarray, T_true: np.ndarray) -> dict:
    """{"trans_cm", "rot_deg"} of ``inv(T_true) @ T_est`` (both T_world_camera, 4×4)."""
    D = np.linalg.inv(np.asarray(T_true, float)) @ np.asarray(T_est, float)
    return {"trans_cm": float(np.linalg.norm(D[:3, 3]) * 100.0), "rot_deg": rotation_angle_deg(D)}


def truth_camera_extrinsic(truth_dir: str | Path) -> np.ndarray:
    """True T_world_camera of the depth cloud's frame (optical) from ``truth/extrinsics.json``."""
    p = Path(truth_dir) / "extrinsics.json"
    try:
        d = json.loads(p.read_text())
        return np.asarray(d["T_world_camera_optical"], float)
    except (OSError, KeyError, ValueError) as err:
        raise InputError(f"{p}: cannot read T_world_camera_optical ({err})") from err


def surface_centroid(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted centroid (3,) of a triangle surface (independent of the tessellation)."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return np.full(3, np.nan)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if area.sum() <= 0:
        return v[np.unique(f)].mean(0)
    return ((a + b + c) / 3.0 * area[:, None]).sum(0) / area.sum()


def solid_centroid(vertices: np.ndarray, faces: np.ndarray, voxel: float = 0.01) -> np.ndarray:
    """Centre of mass (3,) of the solid a closed triangle surface encloses (uniform density): mean
    of the centres of the ``voxel`` grid cells inside it (open3d ``RaycastingScene.compute_occupancy``).
    Unlike a surface centroid this ignores interior faces, so a body made of overlapping closed parts
    (the synthetic human) and a single closed surface (register's) are measured alike."""
    import open3d as o3d

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return np.full(3, np.nan)
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    lo, hi = v.min(0), v.max(0)
    axes = [np.arange(lo[i] + voxel / 2, hi[i], voxel) for i in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    occ = sc.compute_occupancy(o3d.core.Tensor(g.astype(np.float32))).numpy() > 0.5
    if not occ.any():
        return v[np.unique(f)].mean(0)
    return g[occ].mean(0)


def human_centroid_errors(url: str, scene_id: str, truth_dir: str | Path, frame: str = "world") -> dict:
    """Per-frame distance (cm) between the centre of mass (:func:`solid_centroid`) of the solid
    enclosed by ``human/vertices``+``human/faces`` and that of ``truth/human/<frame:06d>.ply``: {"per_frame_cm", "mean_cm",
    "median_cm", "max_cm", "frames",
    "missing"} (frames without an estimate count as missing, not as errors). ``frame="radar"``: both
    centroids in the radar frame of their frame (estimate through the scene's ``pose/T_world_radar``,
    truth through ``truth/trajectory_radar.tum``): what the radar ground truth sees, free of a
    common offset of the SLAM map and its poses against the true world. ``frame="lidar"``: the same
    in the LiDAR frame of each frame's scan (estimate through ``pose/T_world_lidar``, truth through
    ``truth/trajectory_lidar.tum``), for recordings without a radar. ``frame="aligned"``: the
    estimate moved by the alignment of the estimated LiDAR trajectory to the true one that
    :func:`aligned_extrinsic_error` uses (identity with true poses)."""
    from ..dataset import open_dataset
    from ..meshio import read_mesh
    from ..trajectory import read_tum

    sc = open_dataset(url).scene(scene_id)
    hd = Path(truth_dir) / "human"
    if frame not in ("world", "radar", "lidar", "aligned"):
        raise InputError(f"frame must be world, radar, lidar or aligned, got {frame!r}")
    A = np.eye(4)
    if frame == "aligned":  # the estimate through the alignment of aligned_extrinsic_error
        pair = _matched_trajectories(np.asarray(sc[LIDAR_TIMESTAMP_NS][...], np.int64),
                                     np.asarray(sc[POSE_T_WORLD_LIDAR][...], float), true_lidar_poses(sc, truth_dir))
        if pair is not None:
            from .slam_accuracy import pose_alignment

            A = pose_alignment(*pair)
    if frame == "radar":
        P_est = np.asarray(sc[POSE_T_WORLD_RADAR][...], float)
        P_true = read_tum(Path(truth_dir) / "trajectory_radar.tum").poses
        if len(P_true) != sc.n_frames:
            raise InputError(f"{truth_dir}: trajectory_radar.tum has {len(P_true)} poses for {sc.n_frames} frames")
    if frame == "lidar":
        P_est, P_true = np.asarray(sc[POSE_T_WORLD_LIDAR][...], float), true_lidar_poses(sc, truth_dir)
    errs, missing = [], 0
    for k in range(sc.n_frames):
        p = hd / f"{k:06d}.ply"
        if not p.is_file():
            continue
        m = read_mesh(p)
        v = np.asarray(sc.ragged(HUMAN_VERTICES, k), float)
        f = np.asarray(sc.ragged(HUMAN_FACES, k), np.int64)
        if len(f) == 0:
            missing += 1
            errs.append(np.nan)
            continue
        ce, ct = solid_centroid(v, f), solid_centroid(m.vertices, m.faces)
        ce = A[:3, :3] @ ce + A[:3, 3]
        if frame in ("radar", "lidar"):
            ce = np.linalg.solve(P_est[k], np.append(ce, 1.0))[:3]
            ct = np.linalg.solve(P_true[k], np.append(ct, 1.0))[:3]
        errs.append(float(np.linalg.norm(ce - ct) * 100.0))
    e = np.asarray(errs, float)
    ok = e[np.isfinite(e)]
    return {"per_frame_cm": e.tolist(), "mean_cm": float(ok.mean()) if len(ok) else float("nan"),
            "median_cm": float(np.median(ok)) if len(ok) else float("nan"),
            "max_cm": float(ok.max()) if len(ok) else float("nan"), "frames": int(len(ok)), "missing": missing}


def true_lidar_poses(sc, truth_dir: str | Path) -> np.ndarray:
    """(T,4,4) true ``T_world_lidar`` of a scene's scans (``truth/trajectory_lidar.tum`` matched by
    ``lidar/timestamp_ns``, nearest within 1 ms); NaN where none matches."""
    from ..trajectory import read_tum

    lid = read_tum(Path(truth_dir) / "trajectory_lidar.tum")
    stamps = np.asarray(sc[LIDAR_TIMESTAMP_NS][...], np.int64)
    where = {int(t): i for i, t in enumerate(lid.timestamp_ns)}
    P = np.full((len(stamps), 4, 4), np.nan)
    for k, s in enumerate(stamps):
        i = where.get(int(s))
        if i is None:  # stamps in the TUM file are rounded to µs or ns: nearest within 1 ms
            j = int(np.argmin(np.abs(lid.timestamp_ns - s)))
            i = j if abs(int(lid.timestamp_ns[j]) - int(s)) < 1_000_000 and s != 0 else None
        if i is not None:
            P[k] = lid.poses[i]
    return P


def robot_relative_extrinsic_error(url: str, scene_id: str, truth_dir: str | Path, T_est: np.ndarray) -> dict:
    """Error of the camera pose *relative to the robot*: per scan k, ``inv(T_world_lidar_est[k]) @ T_est``
    (the scene's ``pose/T_world_lidar``) against ``inv(T_world_lidar_true[k]) @ T_true``; median over
    the scans of {"trans_cm", "rot_deg"}. With SLAM poses the map (and every pose in it) may sit a
    little off the true world (drift since the anchored first scan); the camera registered to that
    map carries the same offset, which the radar ground truth never sees (mesh, radar poses and human
    are all in the map). With true poses this equals :func:`extrinsic_error`."""
    from ..dataset import open_dataset

    sc = open_dataset(url).scene(scene_id)
    return relative_extrinsic_error(np.asarray(sc[POSE_T_WORLD_LIDAR][...], float), T_est,
                                    true_lidar_poses(sc, truth_dir), truth_camera_extrinsic(truth_dir))


def aligned_extrinsic_error(url: str, scene_id: str, truth_dir: str | Path, T_est: np.ndarray) -> dict:
    """Extrinsic error after aligning the scene's LiDAR trajectory (``pose/T_world_lidar``, stamps
    ``lidar/timestamp_ns``) to the true one (``truth/trajectory_lidar.tum``): the error of
    ``A @ T_est`` against the true ``T_world_camera``. A camera registered to a SLAM map lives in that
    map's frame; a map that sits a little off the true world (0.2 deg of yaw about the first pose
    moves a camera 9 m away by 3 cm) is judged after the alignment the ATE uses.

    ``A`` is evo's alignment of the poses, :func:`holodata.evaluate.slam_accuracy.pose_alignment` (rotation =
    chordal mean of R_true R_estᵀ, translation = mean residual; what the ATE falls back to on a
    straight path), not the position-only Umeyama fit: the synthetic corners' robot drives a straight
    line (lateral spread ~7 mm, constant height), where Umeyama's rotation about the path is set by
    centimetre position noise (``docs/design/register.md``, camera alignment) — harmless for the ATE of
    points on that line, meaningless for a camera 9 m off it. The Umeyama variant is returned too
    (``umeyama_trans_cm``, ``umeyama_rot_deg``). Returns {"trans_cm", "rot_deg", "align_rot_deg"
    (size of A's rotation), "umeyama_trans_cm", "umeyama_rot_deg", "umeyama_align_rot_deg"}. With
    true poses A is the identity and this equals :func:`extrinsic_error`."""
    from ..dataset import open_dataset

    sc = open_dataset(url).scene(scene_id)
    return aligned_extrinsic_error_poses(np.asarray(sc[LIDAR_TIMESTAMP_NS][...], np.int64),
                                         np.asarray(sc[POSE_T_WORLD_LIDAR][...], float), T_est,
                                         true_lidar_poses(sc, truth_dir), truth_camera_extrinsic(truth_dir))


def _matched_trajectories(stamps_ns: np.ndarray, P_est: np.ndarray, P_true: np.ndarray):
    """(estimate, truth) :class:`~holodata.trajectory.Trajectory` pair of the scans with both poses
    finite (stamps (K,), poses (K,4,4)), in stamp order without repeated stamps; None if < 3."""
    from ..trajectory import Trajectory

    P_est, P_true = np.asarray(P_est, float), np.asarray(P_true, float)
    ok = np.isfinite(P_est).all((1, 2)) & np.isfinite(P_true).all((1, 2))
    t = np.asarray(stamps_ns, np.int64)
    idx = np.flatnonzero(ok)[np.argsort(t[ok], kind="stable")]
    if len(idx):
        idx = idx[np.r_[True, np.diff(t[idx]) > 0]]   # Trajectory: strictly increasing stamps
    if len(idx) < 3:
        return None
    return Trajectory(t[idx], P_est[idx]), Trajectory(t[idx], P_true[idx])


def aligned_extrinsic_error_poses(stamps_ns: np.ndarray, P_est: np.ndarray, T_est: np.ndarray, P_true: np.ndarray,
                                  T_true: np.ndarray) -> dict:
    """:func:`aligned_extrinsic_error` on arrays: scan stamps (K,), estimated and true T_world_lidar
    (K,4,4) (rows with NaN skipped), estimated and true T_world_camera (4,4)."""
    from .slam_accuracy import pose_alignment, umeyama_transform

    nan = float("nan")
    pair = _matched_trajectories(stamps_ns, P_est, P_true)
    if pair is None:
        return {"trans_cm": nan, "rot_deg": nan, "align_rot_deg": nan, "umeyama_trans_cm": nan,
                "umeyama_rot_deg": nan, "umeyama_align_rot_deg": nan}
    est, tru = pair
    T_est = np.asarray(T_est, float)
    A = pose_alignment(est, tru)
    U = umeyama_transform(est, tru)
    e, u = extrinsic_error(A @ T_est, T_true), extrinsic_error(U @ T_est, T_true)
    return {**e, "align_rot_deg": rotation_angle_deg(A), "umeyama_trans_cm": u["trans_cm"],
            "umeyama_rot_deg": u["rot_deg"], "umeyama_align_rot_deg": rotation_angle_deg(U)}


def relative_extrinsic_error(P_est: np.ndarray, T_est: np.ndarray, P_true: np.ndarray, T_true: np.ndarray) -> dict:
    """Median over poses k of :func:`extrinsic_error` between ``inv(P_est[k]) @ T_est`` and
    ``inv(P_true[k]) @ T_true`` (``P_*`` (K,4,4) T_world_lidar, NaN rows skipped; ``T_*`` (4,4)
    T_world_camera): {"trans_cm", "rot_deg", "scans"}."""
    tr, rot = [], []
    for Pe, Pt in zip(P_est, P_true):
        if not (np.isfinite(Pe).all() and np.isfinite(Pt).all()):
            continue
        e = extrinsic_error(np.linalg.solve(Pe, T_est), np.linalg.solve(Pt, T_true))
        tr.append(e["trans_cm"])
        rot.append(e["rot_deg"])
    if not tr:
        return {"trans_cm": float("nan"), "rot_deg": float("nan"), "scans": 0}
    return {"trans_cm": float(np.median(tr)), "rot_deg": float(np.median(rot)), "scans": len(tr)}


# ------------------------------------------------------------------------------ truth poses
def write_truth_poses(url: str, scene_id: str, truth_dir: str | Path) -> None:
    """Write the true ``pose/T_world_lidar`` (scan poses matched by ``lidar/timestamp_ns``) and
    ``pose/T_world_radar`` (``truth/trajectory_radar.tum`` line k = frame k) into a scene, replacing
    existing ones. For development and scoring without SLAM error."""
    from ..dataset import open_dataset
    from ..trajectory import read_tum

    truth_dir = Path(truth_dir)
    ds = open_dataset(url)
    sc = ds.scene(scene_id)
    P = true_lidar_poses(sc, truth_dir)
    rad = read_tum(truth_dir / "trajectory_radar.tum")
    w = open_dataset(url, "r+")
    sw = w.scene(scene_id)
    with sw.stage("truth-poses", rerun="rerun holodata.evaluate.register_accuracy.write_truth_poses to finish it"):
        for name, poses in ((POSE_T_WORLD_LIDAR, P), (POSE_T_WORLD_RADAR, rad.poses if len(rad) == sc.n_frames else None)):
            if poses is None:
                continue
            if name in sw.arrays():
                sw.remove(name)
            a = sw.frame_array(name, (4, 4), attrs={"world_frame": "map", "source": "truth"})
            for s in range(a.n_shards):
                a.write_shard(s, poses[a.frames(s)])


def evaluate_register(url: str, scene_id: str, truth_dir: str | Path, out_dir: str | Path | None = None) -> dict:
    """``holodata register --truth``: a registered scene against a ``holodata synth`` truth folder.
    Returns {"extrinsic": world frame {"trans_cm", "rot_deg"}, "extrinsic_aligned" (LiDAR trajectory
    aligned to the truth first, :func:`aligned_extrinsic_error`; the floor is judged on it),
    "extrinsic_robot" (:func:`robot_relative_extrinsic_error`), "human_centroid" (world) and
    "human_centroid_radar" (radar frame; without radar poses absent) from
    :func:`human_centroid_errors`, "segmentation" (:func:`segmentation_ap50`, when the truth has
    instance masks)}. With ``out_dir``: ``register_accuracy.json`` and ``human_centroid.png``
    (per-frame centroid error and its cumulative curve)."""
    from ..dataset import open_dataset

    truth_dir = Path(truth_dir)
    sc = open_dataset(url).scene(scene_id)
    if CALIB_T_WORLD_CAMERA not in sc.arrays():
        raise InputError(f"{url}: scene {scene_id!r} has no calib/T_world_camera (run holodata register first)")
    T = np.asarray(sc[CALIB_T_WORLD_CAMERA][...], float)
    out = {"extrinsic": extrinsic_error(T, truth_camera_extrinsic(truth_dir)),
           "extrinsic_aligned": aligned_extrinsic_error(url, scene_id, truth_dir, T),
           "extrinsic_robot": robot_relative_extrinsic_error(url, scene_id, truth_dir, T),
           "human_centroid": human_centroid_errors(url, scene_id, truth_dir)}
    if POSE_T_WORLD_RADAR in sc.arrays() and (truth_dir / "trajectory_radar.tum").is_file():
        out["human_centroid_radar"] = human_centroid_errors(url, scene_id, truth_dir, frame="radar")
    if (truth_dir / "lidar_instances.npz").is_file() and LIDAR_INSTANCE in sc.arrays():
        out["segmentation"] = segmentation_ap50(url, scene_id, truth_dir)
    if out_dir is not None:
        from ..ownership import claim_folder

        out_dir = claim_folder(out_dir, "holodata register --report").path   # new, empty or holodata's
        (out_dir / "register_accuracy.json").write_text(json.dumps(out, indent=2, default=float))
        plot_centroid_errors({label: out[k]["per_frame_cm"] for k, label in
                              (("human_centroid", "world frame"), ("human_centroid_radar", "radar frame")) if k in out},
                             out_dir / "human_centroid.png")
    return out


def plot_centroid_errors(per_frame_cm: dict, path: Path) -> None:
    """{label: per-frame centroid errors (cm, NaN = no human found)} → PNG: error per frame (left)
    and the cumulative fraction of frames within x (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=110)
    for label, e in per_frame_cm.items():
        e = np.asarray(e, float)
        a.plot(np.arange(len(e)), e, ".-", ms=3, lw=0.8, label=label)
        ok = np.sort(e[np.isfinite(e)])
        if len(ok):
            b.plot(ok, np.arange(1, len(ok) + 1) / len(e), label=f"{label} ({len(ok)}/{len(e)} frames with a human)")
    for ax in (a, b):
        ax.axhline(5, color="0.7", lw=0.8, ls="--") if ax is a else ax.axvline(5, color="0.7", lw=0.8, ls="--")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    a.set_xlabel("frame")
    a.set_ylabel("human centroid error (cm)")
    b.set_xlabel("human centroid error (cm)")
    b.set_ylabel("fraction of frames ≤ x")
    b.set_ylim(0, 1.01)
    b.set_xlim(left=0)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


__all__ = ["ap50", "match_scan", "average_precision", "segmentation_ap50", "extrinsic_error", "truth_camera_extrinsic",
           "surface_centroid", "human_centroid_errors", "write_truth_poses", "true_lidar_poses",
           "robot_relative_extrinsic_error", "relative_extrinsic_error", "aligned_extrinsic_error",
           "aligned_extrinsic_error_poses", "evaluate_register", "plot_centroid_errors"]
