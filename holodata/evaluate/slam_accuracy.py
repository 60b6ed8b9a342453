"""Accuracy of ``holodata slam`` against a synthetic truth folder (``holodata synth``'s ``truth/``).

Trajectory (computed with ``evo`` itself): the estimated LiDAR trajectory and
``truth/trajectory_lidar.tum`` are associated by timestamp (``evo.core.sync``, 10 ms), the estimate
is aligned to the truth with Umeyama's method (rotation + translation, no scale — ``evo``'s
``PoseTrajectory3D.align``), then ATE = APE translation RMSE (m) and RPE = relative translation
error per 1 m of travelled distance (``evo`` RPE, ``delta_unit=meters``, all pairs; NaN when the path
is shorter) and per consecutive pose pair — RMSE (m). A path so straight that Umeyama's
position-only fit is degenerate is aligned with :func:`pose_alignment` instead (said in the
result's ``alignment``). Cumulative error curve: fraction of poses with
APE ≤ x.

Mesh (occlusion-aware, Skoltech3D style): both meshes are sampled uniformly by area
(``sample_spacing``); distances are exact point-to-triangle distances (open3d
``RaycastingScene.compute_distance``). A true-mesh sample counts towards completeness (recall)
only if the LiDAR observed it: seen unoccluded (first hit within ``visibility_tol``) from at
least one true LiDAR pose, within the LiDAR's range limits and vertical field of view.
precision(τ) = share of estimated samples within τ of the true mesh (estimated samples whose nearest
true sample is an unobserved one are ignored — surface the LiDAR never saw cannot be judged — while
samples in free space still count), recall(τ) = share of observed
true samples within τ of the estimate, F = 2PR/(P+R), at τ = 2, 5, 10 cm. Chamfer distance =
mean(acc) + mean(comp) (sum, docs/format.md §5).

Coverage (:func:`mesh_coverage`): the share of the true surface *within the radar's multi-bounce
reach* that the estimated mesh covers — the radar's beams (the recording's grid, up to 3 bounces,
the radar's maximum range ``conventions.DEFAULT_MAX_RANGE_M`` of accumulated range) traced from the
true radar poses through the true mesh; the hit points of every bounce are that surface; covered =
within 5 cm of the estimated mesh. The same beams traced through the estimated mesh (in the truth's
frame, same poses) give the GT NLOS points per frame the estimate yields, compared with the true
mesh's.
"""
from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..conventions import DEFAULT_MAX_BOUNCES, DEFAULT_MAX_RANGE_M, transform_points
from ..errors import InputError
from ..trajectory import Trajectory, read_tum

TAUS = (0.02, 0.05, 0.10)
# the LiDAR that decides which true surface was observable, where truth/scene.json does not say:
# any range from 0.3 m to 120 m, the whole vertical half-sphere
DEFAULT_LIDAR = {"min_range_m": 0.3, "max_range_m": 120.0, "fov_deg": (-90.0, 90.0)}
# evo's RPE over 1 m of path: pose pairs whose path length is within this share of the 1 m
RPE_DELTA_TOL = 0.2


# ----------------------------------------------------------------------------------------------
# trajectory (evo)

def _evo(traj: Trajectory):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(poses_se3=[np.asarray(p, np.float64) for p in traj.poses],
                            timestamps=np.asarray(traj.timestamp_ns, np.float64) * 1e-9)


def trajectory_errors(estimate: Trajectory, truth: Trajectory, max_diff_s: float = 0.01) -> dict:
    """ATE/RPE of ``estimate`` vs ``truth`` with evo (Umeyama SE(3) alignment). Returns a dict with
    ``ate_rmse_m``, ``ate_mean_m``, ``ate_median_m``, ``ate_max_m``, ``rpe_rmse_m`` (per 1 m of travel,
    NaN when the path is shorter), ``rpe_frame_rmse_m`` (consecutive poses), ``n_matched``, and
    ``ape_m`` (per-pose errors, list) for plots."""
    from evo.core import metrics, sync

    ref, est = sync.associate_trajectories(_evo(truth), _evo(estimate), max_diff=max_diff_s)
    n = len(ref.timestamps)
    if n < 2:
        raise InputError(f"only {n} estimated pose(s) match a true pose within {max_diff_s * 1e3:.0f} ms")
    est = copy.deepcopy(est)
    from evo.core.geometry import GeometryException

    try:
        est.align(ref, correct_scale=False)
        how = "umeyama"
    except GeometryException:  # straight path: positions alone leave the roll about it free
        est.transform(_pose_alignment(ref, est))
        how = "poses (path too straight for Umeyama)"
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    st = metrics.StatisticsType
    out = {"n_matched": n, "alignment": how, "ate_rmse_m": float(ape.get_statistic(st.rmse)),
           "ate_mean_m": float(ape.get_statistic(st.mean)),
           "ate_median_m": float(ape.get_statistic(st.median)), "ate_max_m": float(ape.get_statistic(st.max)),
           "ape_m": [float(x) for x in ape.error]}
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
    rpe.process_data((ref, est))
    out["rpe_frame_rmse_m"] = float(rpe.get_statistic(st.rmse))
    try:
        r1 = metrics.RPE(metrics.PoseRelation.translation_part, delta=1.0, delta_unit=metrics.Unit.meters,
                         rel_delta_tol=RPE_DELTA_TOL, all_pairs=True)
        r1.process_data((ref, est))
        out["rpe_rmse_m"] = float(r1.get_statistic(st.rmse))
    except Exception:  # noqa: BLE001 - evo raises when no pair spans 1 m
        out["rpe_rmse_m"] = float("nan")
    dist = float(np.sum(np.linalg.norm(np.diff(ref.positions_xyz, axis=0), axis=1)))
    out["path_length_m"] = dist
    return out


# ----------------------------------------------------------------------------------------------
# mesh

def sample_mesh(vertices: np.ndarray, faces: np.ndarray, spacing: float, rng=None, max_points: int = 2_000_000
                ) -> np.ndarray:
    """Points uniformly by area, about one per ``spacing``² (m); (N,3) float64."""
    rng = rng or np.random.default_rng(0)
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n = int(min(max_points, max(1000, area.sum() / spacing ** 2)))
    idx = rng.choice(len(f), size=n, p=area / area.sum())
    a, b = rng.random(n), rng.random(n)
    fl = a + b > 1
    a[fl], b[fl] = 1 - a[fl], 1 - b[fl]
    t = tri[idx]
    return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])


def _scene(vertices, faces):
    import open3d as o3d

    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(faces, np.uint32)))
    return s


def mesh_distance(vertices, faces, points: np.ndarray) -> np.ndarray:
    """Exact distance (m) of each point (N,3) to the triangle mesh."""
    import open3d as o3d

    s = _scene(vertices, faces)
    out = np.empty(len(points))
    for i in range(0, len(points), 500_000):
        q = o3d.core.Tensor(np.asarray(points[i:i + 500_000], np.float32))
        out[i:i + 500_000] = s.compute_distance(q).numpy()
    return out


@dataclass(frozen=True)
class LidarView:
    """What a LiDAR sees from its pose (:func:`observed_mask`): returns within [``min_range_m``,
    ``max_range_m``] m and the elevation field of view ``fov_deg`` (min, max) degrees in the sensor
    frame (:data:`DEFAULT_LIDAR` by default)."""

    min_range_m: float = DEFAULT_LIDAR["min_range_m"]
    max_range_m: float = DEFAULT_LIDAR["max_range_m"]
    fov_deg: tuple[float, float] = DEFAULT_LIDAR["fov_deg"]


def observed_mask(vertices, faces, samples: np.ndarray, sensor_poses: np.ndarray, view: LidarView = LidarView(),
                  tol: float = 0.03, max_poses: int = 60) -> np.ndarray:
    """(N,) bool: sample seen unoccluded (within ``tol`` m of the first hit of its ray) from at least one
    of ``sensor_poses`` (T_world_sensor; at most ``max_poses`` of them, evenly spread), within the
    ``view`` (:class:`LidarView`: the range limits and the elevation field of view)."""
    import open3d as o3d

    min_range, max_range, fov_deg = view.min_range_m, view.max_range_m, view.fov_deg
    s = _scene(vertices, faces)
    P = np.asarray(sensor_poses)
    if len(P) > max_poses:
        P = P[np.linspace(0, len(P) - 1, max_poses).round().astype(int)]
    seen = np.zeros(len(samples), bool)
    lo, hi = np.deg2rad(fov_deg[0]), np.deg2rad(fov_deg[1])
    for T in P:
        o = T[:3, 3]
        d = samples - o
        r = np.linalg.norm(d, axis=1)
        dl = d @ T[:3, :3]  # sensor frame
        el = np.arctan2(dl[:, 2], np.linalg.norm(dl[:, :2], axis=1))
        cand = ~seen & (r >= min_range) & (r <= max_range) & (el >= lo) & (el <= hi)
        if not cand.any():
            continue
        idx = np.nonzero(cand)[0]
        u = d[idx] / r[idx, None]
        rays = np.concatenate([np.broadcast_to(o, (len(idx), 3)), u], 1).astype(np.float32)
        t = s.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        seen[idx[t >= r[idx] - tol]] = True
    return seen


def mesh_errors(est_vertices, est_faces, true_vertices, true_faces, sensor_poses=None, taus=TAUS,
                sample_spacing: float = 0.02, lidar: dict | None = None) -> dict:
    """Occlusion-aware Chamfer and precision/recall/F at ``taus`` (see module doc). ``sensor_poses``:
    true LiDAR poses for visibility (None: every true sample counts). ``lidar``: {min_range_m,
    max_range_m, fov_deg: (min, max)}. Returns metres / fractions, plus the raw distance arrays
    under ``_acc`` / ``_comp`` (for plots)."""
    from scipy.spatial import cKDTree

    ev, ef = np.asarray(est_vertices, np.float64), np.asarray(est_faces, np.int64)
    tv, tf = np.asarray(true_vertices, np.float64), np.asarray(true_faces, np.int64)
    if len(ef) == 0:
        raise InputError("estimated mesh has no faces")
    ts = sample_mesh(tv, tf, sample_spacing)
    lidar = lidar or {}
    if sensor_poses is not None:
        obs = observed_mask(tv, tf, ts, sensor_poses, LidarView(lidar.get("min_range_m", DEFAULT_LIDAR["min_range_m"]),
                                                                lidar.get("max_range_m", DEFAULT_LIDAR["max_range_m"]),
                                                                tuple(lidar.get("fov_deg", DEFAULT_LIDAR["fov_deg"]))))
    else:
        obs = np.ones(len(ts), bool)
    ts_obs = ts[obs]
    es = sample_mesh(ev, ef, sample_spacing)
    # precision only where the truth was observed: drop estimated samples whose nearest true sample
    # is an unobserved one (surface the LiDAR never saw); samples in free space still count
    _, nn = cKDTree(ts).query(es, k=1)
    es = es[obs[nn]]
    acc = mesh_distance(tv, tf, es)          # estimate → truth
    comp = mesh_distance(ev, ef, ts_obs)     # observed truth → estimate
    out = {"chamfer_m": float(acc.mean() + comp.mean()) if len(acc) and len(comp) else float("nan"),
           "accuracy_mean_m": float(acc.mean()) if len(acc) else float("nan"),
           "completeness_mean_m": float(comp.mean()) if len(comp) else float("nan"),
           "observed_fraction": float(obs.mean()), "n_true_samples": int(len(ts)), "n_est_samples": int(len(es))}
    for tau in taus:
        p = float((acc <= tau).mean()) if len(acc) else 0.0
        r = float((comp <= tau).mean()) if len(comp) else 0.0
        f = 2 * p * r / (p + r) if p + r > 0 else 0.0
        cm = int(round(tau * 100))
        out.update({f"precision_{cm}cm": p, f"recall_{cm}cm": r, f"f_{cm}cm": f})
    out["_acc"], out["_comp"] = acc, comp
    return out


# ----------------------------------------------------------------------------------------------
# mesh coverage within the radar's multi-bounce reach

COVERAGE_TAU = 0.05


def radar_reach(vertices, faces, radar_poses: np.ndarray, grid, max_bounces: int = DEFAULT_MAX_BOUNCES,
                max_range: float = DEFAULT_MAX_RANGE_M, max_frames: int = 60) -> dict:
    """The surface a radar reaches: its beams (``grid``, one origin per frame at the pose's
    translation, the rotation centre) from ``radar_poses`` (T,4,4) T_world_radar traced through the
    mesh with up to ``max_bounces`` specular bounces and accumulated range up to ``max_range`` m
    (:class:`holodata.raytrace.RayScene`, labels on). At most ``max_frames`` poses, evenly spread.
    Returns ``points`` (M,3) float64 the finite hit points of every bounce, ``bounce`` (M,) int
    1..B, ``frame`` (M,) int, ``label`` (M,) uint8 (conventions.Label), ``nlos_per_frame`` (T',)
    count of beams·bounces labelled NLOS
    (structure or human), ``frames`` (T',) the pose indices used."""
    from ..beams import beam_rays
    from ..conventions import Label
    from ..raytrace import RayScene

    P = np.asarray(radar_poses, np.float64)
    idx = np.arange(len(P))
    if len(P) > max_frames:
        idx = np.unique(np.linspace(0, len(P) - 1, max_frames).round().astype(int))
    scene = RayScene(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    pts, bnc, frm, nlos, lab = [], [], [], [], []
    nlos_labels = [int(Label.NLOS_STRUCTURE), int(Label.NLOS_HUMAN)]
    for k in idx:
        o, d = beam_rays(grid, P[k])
        tr = scene.trace(o, d, max_bounces=max_bounces, max_range=max_range)
        ok = np.isfinite(tr.range)
        b = np.nonzero(ok)
        pts.append(np.asarray(tr.point, np.float64)[ok])
        bnc.append(b[1] + 1)
        frm.append(np.full(len(b[0]), k))
        lab.append(np.asarray(tr.label)[ok])
        nlos.append(int(np.isin(tr.label, nlos_labels).sum()))
    def cat(xs, shape):
        return np.concatenate(xs) if xs else np.zeros(shape)

    return {"points": cat(pts, (0, 3)), "bounce": cat(bnc, (0,)).astype(int), "frame": cat(frm, (0,)).astype(int),
            "label": cat(lab, (0,)).astype(np.uint8), "nlos_per_frame": np.asarray(nlos, np.int64), "frames": idx}


@dataclass(frozen=True)
class RadarTrace:
    """How :func:`mesh_coverage` traces the radar's beams (:func:`radar_reach`): up to ``max_bounces``
    specular bounces, accumulated range up to ``max_range`` m, from at most ``max_frames`` poses
    (evenly spread)."""

    max_bounces: int = DEFAULT_MAX_BOUNCES
    max_range: float = DEFAULT_MAX_RANGE_M
    max_frames: int = 60


def mesh_coverage(est_vertices, est_faces, true_vertices, true_faces, radar_poses: np.ndarray, grid,
                  tau: float = COVERAGE_TAU, trace: RadarTrace = RadarTrace()) -> dict:
    """Share of the true surface within the radar's multi-bounce reach that the estimated mesh covers.

    "Within reach": the hit points of every bounce of the radar's beams (``grid``, traced as ``trace``
    says: :class:`RadarTrace`) traced from the true
    ``radar_poses`` (T,4,4) through the true mesh (:func:`radar_reach`); covered: within ``tau`` m
    (default 5 cm) of the estimated mesh (exact point-to-triangle distance). Both meshes in the same
    (true) world frame. Also traces the beams through the estimated mesh from the same poses and
    compares the ground truth's NLOS points per frame (beams·bounces labelled NLOS) of the two.
    Returns ``coverage`` (all bounces), ``coverage_bounce`` {1,2,3}, ``coverage_nlos`` (the hit points
    labelled NLOS only: the surface the radar reaches around the corner, which a map made only
    while approaching lacks; every hit point counts alike in ``coverage``, most are LOS, so it stays
    high on such a map: 0.93 where ``coverage_nlos`` is far lower), ``n_points``,
    ``nlos_per_frame_true`` / ``nlos_per_frame_est`` (means over the frames), ``nlos_ratio``
    (est / true), ``tau_m``."""
    max_bounces, max_range, max_frames = trace.max_bounces, trace.max_range, trace.max_frames
    reach = radar_reach(true_vertices, true_faces, radar_poses, grid, max_bounces, max_range, max_frames)
    est = radar_reach(est_vertices, est_faces, np.asarray(radar_poses)[reach["frames"]], grid, max_bounces, max_range,
                      len(reach["frames"]))
    out = {"tau_m": float(tau), "n_points": int(len(reach["points"])), "frames": int(len(reach["frames"])),
           "grid": [int(grid.H), int(grid.W)], "max_bounces": int(max_bounces), "max_range_m": float(max_range)}
    if len(reach["points"]) == 0:
        out.update({"coverage": float("nan"), "coverage_bounce": {}})
    else:
        d = mesh_distance(est_vertices, est_faces, reach["points"])
        cov = d <= tau
        out["coverage"] = float(cov.mean())
        out["coverage_bounce"] = {int(b): float(cov[reach["bounce"] == b].mean())
                                  for b in range(1, max_bounces + 1) if (reach["bounce"] == b).any()}
        nl = np.isin(reach["label"], [2, 4])
        out["coverage_nlos"] = float(cov[nl].mean()) if nl.any() else float("nan")
    nt, ne = float(reach["nlos_per_frame"].mean()), float(est["nlos_per_frame"].mean())
    out.update({"nlos_per_frame_true": nt, "nlos_per_frame_est": ne,
                "nlos_ratio": ne / nt if nt > 0 else float("nan")})
    return out


def grid_from_scene_json(truth_dir: Path):
    """The radar beam grid (:class:`holodata.conventions.Grid`) of a synth recording (``truth/scene.json``)."""
    from ..conventions import Grid

    d = json.loads((Path(truth_dir) / "scene.json").read_text())
    g = (d.get("radar") or {}).get("grid") or {}
    el = g.get("elev_deg") or [45.0, -45.0]
    return Grid(int(g.get("H", 64)), int(g.get("W", 512)), float(el[0]), float(el[1]))


# ----------------------------------------------------------------------------------------------
# plots and the whole report

def plot_cumulative(curves: dict, path: Path, xlabel: str, title: str, taus=None) -> None:
    """Cumulative error curves {label: errors (m)} → PNG (x in cm)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.8), dpi=110)
    for label, e in curves.items():
        e = np.sort(np.asarray(e, np.float64)) * 100
        if len(e):
            ax.plot(e, np.arange(1, len(e) + 1) / len(e), label=label)
    for t in taus or ():
        ax.axvline(t * 100, color="0.7", lw=0.8, ls="--")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("fraction ≤ x")
    ax.set_ylim(0, 1.01)
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def lidar_from_scene_json(truth_dir: Path) -> dict:
    """LiDAR range limits and vertical field of view from ``truth/scene.json`` (defaults if absent)."""
    p = Path(truth_dir) / "scene.json"
    out = dict(DEFAULT_LIDAR)
    if p.is_file():
        d = json.loads(p.read_text())
        li = d.get("lidar") or {}
        alt = d.get("lidar_beam_altitude_deg")
        out["min_range_m"] = float(li.get("min_range_m", DEFAULT_LIDAR["min_range_m"]))
        out["max_range_m"] = float(li.get("max_range_m", DEFAULT_LIDAR["max_range_m"]))
        if isinstance(alt, list) and alt:
            out["fov_deg"] = (float(min(alt)) - 0.5, float(max(alt)) + 0.5)
        elif "vertical_fov_deg" in li:
            h = float(li["vertical_fov_deg"]) / 2 + 0.5
            out["fov_deg"] = (-h, h)
    return out


def evaluate_slam(estimate: Trajectory, mesh: tuple | None, truth_dir, out_dir=None, label: str = "slam",
                  extra_trajectories: dict | None = None, coverage: bool = True, pass_: str = "data") -> dict:
    """Trajectory and mesh accuracy against ``truth_dir`` (``truth/`` of ``holodata synth``).

    ``estimate``: T_world_lidar at scan stamps; ``mesh``: (vertices, faces) in the same world frame
    or None; ``extra_trajectories`` {label: Trajectory} are evaluated too (e.g. bare kiss-icp).
    The mesh is compared after the pose alignment of the trajectories (:func:`pose_alignment`:
    rotations and positions of all matched poses, well-posed even on a straight path where
    Umeyama's position-only fit leaves the roll about the path free), so a map in another world
    frame is still measured fairly. With ``coverage`` (and a mesh) also the mesh's coverage of the
    true surface within the radar's reach and the GT NLOS points per frame through both meshes
    (:func:`mesh_coverage`, from ``truth/trajectory_radar.tum``), under ``coverage``.
    ``pass_``: "data" (``truth/trajectory_lidar.tum``) or "mapping" (the mapping pass's
    ``truth/mapping_trajectory_lidar.tum``: ``estimate`` is then the mapping scene's trajectory).
    Writes ``accuracy.json`` and PNGs (``ate_cumulative.png``, ``mesh_cumulative.png``) into
    ``out_dir`` when given."""
    from ..meshio import read_mesh

    truth_dir = Path(truth_dir)
    if pass_ not in ("data", "mapping"):
        raise InputError(f"unknown pass {pass_!r} (data or mapping)")
    tl = truth_dir / ("trajectory_lidar.tum" if pass_ == "data" else "mapping_trajectory_lidar.tum")
    tm = truth_dir / "mesh.ply"
    for p in (tl, tm):
        if not p.is_file():
            raise InputError(f"{truth_dir}: no {p.name} (not a holodata synth truth folder?)")
    truth = read_tum(tl)
    res = {"trajectory": trajectory_errors(estimate, truth)}
    curves = {label: res["trajectory"]["ape_m"]}
    for k, tr in (extra_trajectories or {}).items():
        if tr is None:
            continue
        res[f"trajectory_{k}"] = trajectory_errors(tr, truth)
        curves[k] = res[f"trajectory_{k}"]["ape_m"]
    if mesh is not None:
        T_align = pose_alignment(estimate, truth)
        v = transform_points(T_align, np.asarray(mesh[0], np.float64))
        tmesh = read_mesh(tm)
        keep = np.ones(len(tmesh.faces), bool)
        if tmesh.face_class is not None and tmesh.class_names:
            human = [k for k, n in tmesh.class_names.items() if str(n) == "human"]
            keep = ~np.isin(tmesh.face_class, human)
        m = mesh_errors(v, mesh[1], tmesh.vertices, tmesh.faces[keep], sensor_poses=truth.poses,
                        lidar=lidar_from_scene_json(truth_dir))
        acc, comp = m.pop("_acc"), m.pop("_comp")
        res["mesh"] = m
        res["mesh_alignment"] = T_align.tolist()
        tr = truth_dir / "trajectory_radar.tum"
        if coverage and tr.is_file():
            res["coverage"] = mesh_coverage(v, mesh[1], tmesh.vertices, tmesh.faces[keep], read_tum(tr).poses,
                                            grid_from_scene_json(truth_dir))
    if out_dir is not None:
        from ..ownership import claim_folder

        out_dir = claim_folder(out_dir, "holodata slam --report").path   # new, empty or holodata's
        plot_cumulative(curves, out_dir / "ate_cumulative.png", "absolute position error (cm)",
                        "LiDAR trajectory: cumulative APE (Umeyama-aligned)")
        if mesh is not None:
            plot_cumulative({"accuracy (estimate → truth)": acc, "completeness (observed truth → estimate)": comp},
                            out_dir / "mesh_cumulative.png", "distance (cm)", "Static mesh vs true mesh",
                            taus=TAUS)
        slim = json.loads(json.dumps(res, default=float))
        for k in list(slim):
            if k.startswith("trajectory"):
                slim[k].pop("ape_m", None)
        (out_dir / "accuracy.json").write_text(json.dumps(slim, indent=2) + "\n")
    for k in list(res):
        if k.startswith("trajectory"):
            res[k].pop("ape_m", None)
    return res


def pose_alignment(estimate: Trajectory, truth: Trajectory, max_diff_s: float = 0.01) -> np.ndarray:
    """SE(3) (4,4) A minimising Σ‖A·T_est,i − T_true,i‖ over matched poses: rotation = chordal mean of
    R_true,i R_est,iᵀ, translation = mean of p_true,i − R p_est,i."""
    from evo.core import sync

    ref, est = sync.associate_trajectories(_evo(truth), _evo(estimate), max_diff=max_diff_s)
    return _pose_alignment(ref, est)


def _pose_alignment(ref, est) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    Rt = np.stack([p[:3, :3] for p in ref.poses_se3])
    Re = np.stack([p[:3, :3] for p in est.poses_se3])
    R = Rotation.from_matrix(Rt @ np.transpose(Re, (0, 2, 1))).mean().as_matrix()
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = (ref.positions_xyz - est.positions_xyz @ R.T).mean(0)
    return A


def umeyama_transform(estimate: Trajectory, truth: Trajectory, max_diff_s: float = 0.01) -> np.ndarray:
    """The SE(3) (4,4) that evo's Umeyama alignment applies to ``estimate`` to fit ``truth``."""
    from evo.core import geometry, sync

    ref, est = sync.associate_trajectories(_evo(truth), _evo(estimate), max_diff=max_diff_s)
    try:
        r, t, _ = geometry.umeyama_alignment(est.positions_xyz.T, ref.positions_xyz.T, False)
    except geometry.GeometryException:
        return _pose_alignment(ref, est)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = r, t
    return T


__all__ = ["trajectory_errors", "mesh_errors", "mesh_coverage", "radar_reach", "grid_from_scene_json", "COVERAGE_TAU",
           "observed_mask", "sample_mesh", "mesh_distance", "evaluate_slam",
           "plot_cumulative", "umeyama_transform", "pose_alignment", "TAUS"]
