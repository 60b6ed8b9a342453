"""``holodata register``: the depth camera's one-time extrinsic in the map, and per-frame human
points and closed human surfaces in the map frame. Why each step is done as it is, and what was
measured on the way: ``docs/design/register.md``.

Inputs (a dataset scene): ``camera/points`` (ragged, camera frame; for depth images the optical
frame, with the intrinsics in ``sensors.camera.intrinsics``), the LiDAR map (``map/points`` of
``holodata slam``, or ``lidar/points`` + ``pose/T_world_lidar``), ``camera/timestamp_ns`` and
``time/timestamp_ns``.

1. **Static camera cloud** (:func:`static_depth`): the camera does not move, so per pixel the
   depth over up to ``median_frames`` frames, averaged over its background samples (a moving person
   is only ever in front of the static scene), is a denoised picture of the static scene.
2. **Map** (:func:`scene_map`): slam's static point map when it was built from the scene's poses;
   else every scan in the world frame minus the LiDAR foreground and the segmented people
   (:func:`map_cloud`).
3. **Extrinsic** ``T_world_camera`` (:func:`register_extrinsic`): point-to-plane Gauss-Newton ICP
   with a Tukey loss, coarse to fine (``icp_distances``), of the static camera cloud onto the map
   (denoised onto local planes, :func:`local_plane_projection`) and slam's mesh near the camera
   (:func:`mesh_surface_samples`), from ``--init`` or the TF pose. Directions the overlap does not
   pin down are held at the guess (or where the SLAM map's own turn puts it, :func:`anchored_guess`)
   instead of sliding. Accepted only when overlap, fitness, RMSE and the pose's standard deviation
   (:func:`pose_uncertainty`) pass; else FPFH + RANSAC then the same ICP and check; else register
   fails with the numbers.
4. **Human points per frame** (:func:`frame_candidates`, :func:`pick_human`): returns in front of
   the static depth (a moving person) or on no large plane of the static cloud (a person standing
   still), not explained by the map; the largest person-like cluster near the track, outliers
   removed; picks that jump are picked again near the track's prediction (:func:`track_jumps`).
5. **Closed surface per radar frame** (:func:`body_columns`, :func:`closed_surface`): each
   horizontal run of human pixels is an elliptic cross-section of the body behind the visible front
   (deeper behind a person walking along the view, whose far leg is hidden); the columns are
   voxelised and the boundary of the half-filled voxels is a closed, outward-oriented surface; it
   is shifted by the human's velocity from the camera stamp to the radar frame's stamp.

Outputs (scene): ``human/vertices`` + ``human/faces`` ragged per frame (world frame, float32 /
int32; what ``holodata raytrace-gt`` reads), ``human/points`` ragged (world frame),
``calib/T_world_camera`` (4,4), ``lidar/instance`` (the segmentation, :mod:`.segment`) and the
report in the scene attrs ``register``. :func:`camera_points_world` gives any frame's camera cloud
in the map frame; ``write_camera_world`` (``--camera-world``) also stores that copy
(``camera/points_world``, as large as ``camera/points``).

**Processes** (``processes``, default two on a two-CPU machine; :mod:`holodata.parallel`): the LiDAR
half (background model, map unless slam's is used, segmentation of every scan) runs in a forked
process beside the camera half; after the extrinsic, the human candidates of the later half of the
frames and every other frame's surface are made in another one. The results are the same as in
one process (test).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..conventions import rotation_angle_deg, transform_points, yaw_rad
from ..errors import HolodataError, InputError
from ..parallel import cpus, fork_call, release_free_memory
from ..progress import track


class RegistrationError(HolodataError, RuntimeError):
    """Camera-to-map registration did not pass its acceptance check."""


@dataclass(frozen=True)
class RegisterConfig:
    """Parameters (metres unless noted); docs/design/register.md says what each does and why it has
    this value."""

    map_voxel: float = 0.04
    map_max_scans: int = 120
    cam_voxel: float = 0.03
    icp_distances: tuple = (0.15, 0.08, 0.04)
    map_sigma_m: float = 0.015
    map_normal_voxel: float = 0.15
    map_normal_m: float = 0.45
    map_normal_nn: int = 30
    map_plane_m: float = 0.3
    map_plane_ratio: float = 0.1
    mesh_target: bool = True
    mesh_sample_m: float = 0.02
    mesh_keep_map_m: float = 0.0
    mesh_degenerate_ratio: float = 0.025
    search_m: float = 0.0
    max_pose_std_m: float = 0.02
    guess_std_m: float = 0.05   # accuracy of the guess (TF / --init) along directions the data does not
                                # constrain (held at it): a hand-measured mount is good to a few cm
    hold_m: float = 0.05        # directions the ICP holds stay within this of the guess (docs/design/register.md, 3.)
    anchor_max_deg: float = 0.5    # TF guess, slam map: held directions follow a map turn up to this
                                   # (docs/design/register.md, 3.)
    anchor_agree_deg: float = 0.1  # ... that the camera's yaw and position corrections show alike
    # measured on the quick-demo corners (noisy 188x336 stereo, 12 frames): inverse-variance weights
    # and variance-based freezing were no better than uniform weights; kept as options
    noise_weights: bool = False
    max_std_m: float = 0.0
    max_scale_m: float = 0.25
    crop_m: float = 0.6
    check_sigma_m: float = 0.02
    icp_iterations: int = 15
    degenerate_ratio: float = 0.05
    min_normal_cos: float = 0.8
    overlap_m: float = 0.15
    inlier_m: float = 0.05
    min_fitness: float = 0.6
    max_rmse_m: float = 0.03
    min_overlap_points: int = 300
    fpfh_voxel: float = 0.1
    # the global fallback must stay near the informed guess (TF / --init): corridors are
    # self-similar, and FPFH+RANSAC found 5-8 m shifted alignments that passed fitness/RMSE
    fallback_max_shift_m: float = 1.0
    fallback_max_rot_deg: float = 20.0
    max_range_m: float = 12.0
    fg_min_m: float = 0.12
    fg_sigma: float = 4.0
    map_explain_m: float = 0.08
    cluster_m: float = 0.08
    min_height_m: float = 0.5
    max_width_m: float = 1.4
    min_points: int = 100
    min_area_m2: float = 0.1
    cluster_px: float = 1.5
    track_radius_m: float = 2.0
    track_jump_m: float = 0.4
    walk_speed_mps: float = 1.5
    max_depth_spread_m: float = 0.35
    floor_margin_m: float = 0.04
    max_speed_mps: float = 2.5
    plane_dist_m: float = 0.05
    plane_min_fraction: float = 0.03
    max_planes: int = 12
    thickness_m: float = 0.22
    min_thickness_m: float = 0.06
    surface_voxel: float = 0.04
    surface_gap_px: int = 2
    floor_reach_m: float = 0.35
    walk_back_frac: float = 0.3
    walk_back_speed_mps: float = 1.0
    segment_lidar: bool = True
    slam_map: bool = True       # slam's stored static map (map/points) as the map, when built from these poses
    median_frames: int = 60
    processes: int = 0          # 0: two when the machine has two CPUs (the LiDAR half beside the camera half)
    write_camera_world: bool = False   # camera/points_world: the map-frame copy of camera/points

    def to_attrs(self) -> dict:
        d = asdict(self)
        d["icp_distances"] = list(self.icp_distances)
        return d


@dataclass
class Registration:
    """Result of :func:`register_extrinsic`: ``T`` (4,4) T_world_camera; ``method`` "icp" | "fpfh+icp";
    ``fitness`` inlier fraction of the overlap, ``rmse`` m, ``overlap`` points; ``accepted``;
    ``attempts`` the checks of every try (for the report)."""

    T: np.ndarray
    method: str
    fitness: float
    rmse: float
    overlap: int
    accepted: bool
    attempts: list = field(default_factory=list)

    def to_attrs(self) -> dict:
        return {"T_world_camera": np.asarray(self.T).tolist(), "method": self.method, "fitness": self.fitness,
                "rmse_m": self.rmse, "overlap_points": self.overlap, "accepted": self.accepted,
                "attempts": self.attempts}


# ------------------------------------------------------------------------------------ open3d helpers
def voxel_average(points: np.ndarray, voxel: float) -> np.ndarray:
    """(V,3) float64 mean of the points (N,3) in each occupied voxel of edge ``voxel`` (m): open3d's
    ``voxel_down_sample`` (same grid, anchored half a voxel below the points' minimum; same means up to
    rounding) in voxel-key order instead of hash order, ~3x faster on LiDAR scans."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return p.copy()
    lo = p.min(0) - voxel * 0.5
    ijk = np.floor((p - lo) / voxel).astype(np.int64)
    dims = ijk.max(0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    count = np.diff(np.r_[start, len(ks)])
    return np.add.reduceat(p[order], start, axis=0) / count[:, None]


def _pcd(points: np.ndarray, voxel: float | None = None, normals_radius: float | None = None, max_nn: int = 30):
    import open3d as o3d

    p = np.asarray(points, np.float64).reshape(-1, 3)
    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(voxel_average(p, voxel) if voxel else p))
    if normals_radius:
        p.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normals_radius, max_nn=max_nn))
    return p


def _nn_distances(src: np.ndarray, tgt: np.ndarray, within: float = np.inf) -> np.ndarray:
    """(N,) distance from each ``src`` point to its nearest ``tgt`` point; with ``within`` (m) exact
    only up to ``within`` and inf beyond (the search stops there: nearest-neighbour queries far from
    the data — a camera's view of the branch the LiDAR never saw — are the slow ones)."""
    from scipy.spatial import cKDTree

    if len(tgt) == 0:
        return np.full(len(src), np.inf)
    return cKDTree(tgt).query(src, k=1, distance_upper_bound=np.nextafter(within, np.inf), workers=-1)[0]


def _check_from_distances(d: np.ndarray, cfg: RegisterConfig, r: np.ndarray | None = None) -> dict:
    """Overlap = points whose nearest map point is within ``overlap_m`` (``d`` (N,)); inliers = those
    within ``inlier_m`` of the map's surface: |point-to-plane residual| ``r`` (N,) when given (a sparse
    map has its points centimetres apart: the point distance is no measure of alignment), else ``d``."""
    ov = d < cfg.overlap_m
    n = int(ov.sum())
    r = d if r is None else np.abs(r)
    inl = ov & (r < cfg.inlier_m)
    d = r
    fit = float(inl.sum() / n) if n else 0.0
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    ok = n >= cfg.min_overlap_points and fit >= cfg.min_fitness and rmse <= cfg.max_rmse_m
    return {"overlap": n, "fitness": fit, "rmse": rmse, "accepted": bool(ok)}


def icp(source: np.ndarray, target_pcd, init: np.ndarray, cfg: RegisterConfig) -> np.ndarray:
    """Coarse-to-fine point-to-plane ICP (open3d, Tukey loss with k = the stage's distance / 2) of
    ``source`` (N,3) onto ``target_pcd`` (with normals) from ``init``; returns the (4,4) transform."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = _pcd(source)
    T = np.asarray(init, np.float64).copy()
    for dist in cfg.icp_distances:
        est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=dist / 2))
        res = reg.registration_icp(src, target_pcd, dist, T, est,
                                   reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7,
                                                              max_iteration=cfg.icp_iterations))
        T = np.asarray(res.transformation)
    return T


def _centred_offset(T: np.ndarray, T0: np.ndarray, c: np.ndarray, Lc: float) -> np.ndarray:
    """(6,) the motion from pose ``T0`` to ``T`` (4,4; ``T = D @ T0``) in :func:`weighted_icp`'s update
    coordinates: rotation vector × ``Lc`` (m), then the translation of the point ``c`` (3,) (m)."""
    from scipy.spatial.transform import Rotation

    D = T @ np.linalg.inv(T0)
    om = Rotation.from_matrix(D[:3, :3]).as_rotvec()
    return np.concatenate([om * Lc, D[:3, :3] @ c + D[:3, 3] - c])


def weighted_icp(source: np.ndarray, weights: np.ndarray, target: np.ndarray, target_normals: np.ndarray,
                 init: np.ndarray, distances=(0.08, 0.04), iterations: int = 15, max_scale: float = 0.25,
                 degenerate_ratio: float = 0.0, info: dict | None = None, source_normals: np.ndarray | None = None,
                 min_normal_cos: float = 0.8, search_m: float = 0.0, max_std_m: float = 0.0,
                 hold_m: float = 0.05) -> np.ndarray:
    """Noise-weighted point-to-plane ICP (Gauss-Newton on the linearised rotation, numpy/scipy):
    ``source`` (N,3) with ``weights`` (N,) (1/σ², m⁻²), ``target`` (M,3) with unit ``target_normals``;
    per stage a nearest-neighbour correspondence within ``max(d, 3σ)`` of the stage distance d and a
    Tukey weight with that same scale (σ = 1/sqrt(weight): noisy far points keep their unbiased
    residuals instead of being truncated). ``degenerate_ratio`` > 0: degeneracy-aware updates (Zhang
    et al., ICRA 2016): the normal matrix, with rotations scaled by the median point distance (so both
    blocks are in metres), is eigen-decomposed and the update is zeroed along eigenvectors whose
    eigenvalue is below ``degenerate_ratio`` × the largest — directions the overlap does not pin
    down keep the initial guess instead of sliding (a corridor seen end-on); a coarser stage may
    have moved along them, and the update takes the pose back to within ``hold_m`` (m; rotations
    scaled as above) of ``init`` along them. ``info`` receives the number of frozen directions, the
    eigenvalues and the held directions (``held``, for :func:`hold_at`). ``source_normals`` (N,3):
    correspondences whose normals disagree (|cos| < ``min_normal_cos``) are dropped — near an edge
    the nearest map point can belong to the other wall, whose normal biases a point-to-plane fit by
    centimetres.
    ``search_m`` > 0: nearest map points up to that far (tangentially) are used, gated on the
    residual only (measured worse on the sparse demo map: 0 by default). ``max_std_m`` > 0 (weights
    must then be inverse variances): directions whose standard deviation 1/sqrt(eigenvalue) exceeds it
    are held too. Returns T (4,4)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(target)
    T0 = np.asarray(init, np.float64)
    T = T0.copy()
    src = np.asarray(source, np.float64)
    w0 = np.asarray(weights, np.float64)
    sig = 1.0 / np.sqrt(w0)
    for d in distances:
        scale = np.clip(3 * sig, d, max_scale)
        for _ in range(iterations):
            p = transform_points(T, src)
            reach = np.maximum(scale, search_m)
            dist, j = tree.query(p, k=1, distance_upper_bound=float(reach.max()), workers=-1)
            ok = np.isfinite(dist) & (dist <= reach)
            jj = np.where(ok, j, 0)
            r_all = np.einsum("ij,ij->i", p - target[jj], target_normals[jj])
            ok &= np.abs(r_all) <= scale     # gated on the distance to the map's surface, not to its points
            if source_normals is not None:
                cosn = np.abs(np.einsum("ij,ij->i", source_normals @ T[:3, :3].T, target_normals[jj]))
                ok &= cosn >= min_normal_cos
            if ok.sum() < 6:
                return T
            pp, nn = p[ok], target_normals[j[ok]]
            r = r_all[ok]
            u = r / scale[ok]
            w = w0[ok] * np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
            J = np.concatenate([np.cross(pp, nn), nn], axis=1)        # d r / d (omega, t)
            H = (J * w[:, None]).T @ J + 1e-9 * np.eye(6) * w.sum()
            g = (J * w[:, None]).T @ r
            if degenerate_ratio > 0:
                # rotations about the cloud's centroid, scaled to metres
                c = np.average(pp, axis=0, weights=np.maximum(w, 1e-12))
                Lc = float(np.median(np.linalg.norm(pp - c, axis=1))) or 1.0
                Jc = np.concatenate([np.cross(pp - c, nn) / Lc, nn], axis=1)
                Hc = (Jc * w[:, None]).T @ Jc
                gc = (Jc * w[:, None]).T @ r
                ev, V = np.linalg.eigh(Hc)
                keep = ev >= degenerate_ratio * ev.max()
                if max_std_m > 0:  # weights are inverse variances: 1/sqrt(ev) is the direction's std (m)
                    keep &= ev >= 1.0 / max_std_m ** 2
                y = -(V[:, keep] @ ((V[:, keep].T @ gc) / ev[keep]))
                if not keep.all():
                    # held directions stay within hold_m of the guess: an earlier (coarser) stage may have
                    # moved along them, rightly (edges within its reach) or not (wrong correspondences)
                    dev = V[:, ~keep].T @ _centred_offset(T, T0, c, Lc)
                    y -= V[:, ~keep] @ (np.sign(dev) * np.maximum(np.abs(dev) - hold_m, 0.0))
                x = _about_origin(y, c, Lc)
                if info is not None:
                    info.update(frozen=int((~keep).sum()), eigenvalues=(ev / ev.max()).round(4).tolist(),
                                held=(V[:, ~keep], c, Lc))
            else:
                x = -np.linalg.solve(H, g)
            T = _moved_by(T, x)
            if np.linalg.norm(x[3:]) < 1e-5 and np.linalg.norm(x[:3]) < 1e-6:
                break
    return T


def _about_origin(y: np.ndarray, c: np.ndarray, Lc: float) -> np.ndarray:
    """A motion (6,) in :func:`weighted_icp`'s update coordinates (rotation vector × ``Lc``, motion of
    the centre ``c``) as (rotation vector, translation) about the origin: t = t_c - ω × c."""
    om = y[:3] / Lc
    return np.concatenate([om, y[3:] - np.cross(om, c)])


def _moved_by(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``D @ T`` with D the motion (6,) ``x`` = (rotation vector, translation), about the origin."""
    from scipy.spatial.transform import Rotation

    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
    D[:3, 3] = x[3:]
    return D @ T


def hold_at(T: np.ndarray, target: np.ndarray, held: tuple) -> np.ndarray:
    """``T`` (4,4) moved along the directions :func:`weighted_icp` held (``info["held"]``: (V (6,k),
    centre c (3,), scale Lc) in its update coordinates) to where ``target`` (4,4) lies along them;
    the other directions keep ``T``'s values (to first order)."""
    V, c, Lc = held
    return _moved_by(T, _about_origin(-V @ (V.T @ _centred_offset(T, target, c, Lc)), c, Lc))


def anchored_guess(T: np.ndarray, init: np.ndarray, anchor: np.ndarray, held_dir: np.ndarray, max_deg: float,
                   agree_deg: float) -> tuple[np.ndarray | None, dict]:
    """The guess ``init`` (4,4) turned about the vertical through ``anchor`` (3,) m by the map offset
    the registration ``T`` (4,4) shows, or None where it shows none; and what was measured.

    A SLAM map anchored at the TF pose of its first scan sits off the TF world by the odometry's
    drift there, a turn δ about that scan's position. It moves the camera by δ·u (u = z × (camera -
    anchor)): along a held direction (``held_dir`` (3,), world) the data cannot tell how far, but a
    turn shows twice where it can, in the camera's yaw correction and in its position correction
    across ``held_dir`` (horizontal). Both must give the same δ within ``agree_deg`` (a TF pose
    that is itself off in yaw turns the camera without moving it) and |δ| <= ``max_deg``; δ is then
    the yaw correction. Returns (target or None, {"yaw_deg", "shift_deg"}: the two estimates)."""
    from scipy.spatial.transform import Rotation

    D = T[:3, :3] @ init[:3, :3].T
    yaw = float(np.degrees(yaw_rad(D)))
    a = np.asarray(anchor, np.float64)
    u = np.cross([0.0, 0.0, 1.0], init[:3, 3] - a)              # m per radian of turn
    h = np.asarray(held_dir, np.float64)
    across = np.array([-h[1], h[0], 0.0])
    across /= max(np.linalg.norm(across), 1e-12)
    lever = float(u @ across)
    shift = (float(np.degrees((T[:3, 3] - init[:3, 3]) @ across / lever))
             if abs(lever) >= 0.3 * np.linalg.norm(u) else None)   # None: the turn moves it along held_dir only
    out = {"yaw_deg": round(yaw, 4), "shift_deg": None if shift is None else round(shift, 4)}
    if shift is None or not (abs(yaw) <= max_deg and abs(shift - yaw) <= agree_deg):
        return None, out
    R = np.eye(4)
    R[:3, :3] = Rotation.from_euler("z", yaw, degrees=True).as_matrix()
    R[:3, 3] = a - R[:3, :3] @ a
    return R @ init, out


def fpfh_ransac(source: np.ndarray, target: np.ndarray, voxel: float, seed: int = 0) -> np.ndarray:
    """Global alignment of two clouds (N,3)/(M,3) by FPFH features + RANSAC (open3d); returns T."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # no "too few correspondences" chatter
    feats = []
    for pts in (source, target):
        p = _pcd(pts, voxel, 2 * voxel)
        f = reg.compute_fpfh_feature(p, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        feats.append((p, f))
    (ps, fs), (pt, ft) = feats
    res = reg.registration_ransac_based_on_feature_matching(
        ps, pt, fs, ft, True, 1.5 * voxel, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    return np.asarray(res.transformation)


def map_normals(map_points: np.ndarray, cfg: RegisterConfig) -> tuple[np.ndarray, np.ndarray]:
    """The registration target: map points voxel-thinned to ``map_voxel`` (M,3) and unit normals (M,3)
    estimated on a coarser copy (``map_normal_voxel``, neighbours within ``map_normal_m``) and given
    to each point by its nearest coarse point. A sparse map (32 beams over 90 deg: rings 25-40 cm
    apart on a wall 5-8 m away) has fine neighbourhoods that hold one ring, a line whose PCA normal
    is arbitrary about it (walls got vertical normals); the coarse neighbourhood spans rings."""
    from scipy.spatial import cKDTree

    pts = np.asarray(_pcd(map_points, cfg.map_voxel).points)
    coarse = _pcd(map_points, cfg.map_normal_voxel, cfg.map_normal_m, cfg.map_normal_nn)
    cp = np.asarray(coarse.points)
    if len(cp) < 3:
        return pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    return pts, np.asarray(coarse.normals)[cKDTree(cp).query(pts, k=1, workers=-1)[1]]


def local_plane_projection(points: np.ndarray, radius: float, ratio: float = 0.1, min_nn: int = 6,
                           only: np.ndarray | None = None, chunk: int = 4096) -> np.ndarray:
    """Denoised copy of a point cloud (N,3): each point moved along the normal of the plane fitted
    (PCA) to its neighbours within ``radius`` onto that plane, where the neighbourhood is planar (smallest
    covariance eigenvalue < ``ratio`` × the middle one) and holds >= ``min_nn`` points; other points
    (edges, corners, clutter) stay. ``only`` (N,) bool: project just those (their neighbourhoods still
    span every point). Vectorised: neighbour pairs (scipy ``sparse_distance_matrix``), first and second
    moments by a sparse product, batched 3×3 eigen-decompositions."""
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree

    X = np.asarray(points, np.float64).reshape(-1, 3)
    idx = np.arange(len(X)) if only is None else np.flatnonzero(only)
    if len(idx) == 0 or radius <= 0:
        return X.copy()
    # neighbours (itself included) of just the projected points, a chunk at a time: a 0.3 m ball on
    # a 4 cm map holds ~400 points (17 M pairs for 41 k points; 1.5 GB at once)
    tree = cKDTree(X)
    XX = (X[:, :, None] * X[:, None, :]).reshape(-1, 9)
    cnt, mu, C = np.empty(len(idx)), np.empty((len(idx), 3)), np.empty((len(idx), 9))
    for s in range(0, len(idx), chunk):
        q = idx[s:s + chunk]
        nb = cKDTree(X[q]).sparse_distance_matrix(tree, radius, output_type="ndarray")
        A = csr_matrix((np.ones(len(nb)), (nb["i"], nb["j"])), shape=(len(q), len(X)))
        cnt[s:s + len(q)] = np.asarray(A.sum(1)).ravel()
        mu[s:s + len(q)] = A @ X
        C[s:s + len(q)] = A @ XX
    mu /= cnt[:, None]
    C = (C / cnt[:, None]).reshape(-1, 3, 3) - mu[:, :, None] * mu[:, None, :]
    w, V = np.linalg.eigh(C)
    n = V[:, :, 0]
    ok = (cnt >= min_nn) & (w[:, 0] < ratio * w[:, 1])
    out = X.copy()
    d = np.einsum("ij,ij->i", X[idx] - mu, n)
    out[idx[ok]] -= d[ok, None] * n[ok]
    return out


def mesh_surface_samples(vertices: np.ndarray, faces: np.ndarray, near: np.ndarray | None = None,
                         reach: float = np.inf, spacing: float = 0.02, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points (P,3) spread over a triangle mesh (``vertices`` (V,3), ``faces`` (F,3) int) about
    ``spacing`` apart (per face round(area / spacing²) uniform barycentric samples, at least its
    centroid) with their faces' unit normals (P,3); with ``near`` (K,3) only the samples within
    ``reach`` of one of its points (faces whose bounding sphere is out of reach are not sampled).
    A denoised registration target: point-to-plane residuals against a sample are residuals
    against the face it lies on. Deterministic for a given ``seed``."""
    from scipy.spatial import cKDTree

    V = np.asarray(vertices, np.float64).reshape(-1, 3)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    crop = near is not None and np.isfinite(reach)
    tree = None
    if len(F) and crop:
        if len(near) == 0:
            F = F[:0]
        else:
            # faces whose bounding sphere (about the centroid) comes within reach of a near point
            tree = cKDTree(np.asarray(near, np.float64))
            cen = V[F].mean(1)
            rad = np.linalg.norm(V[F] - cen[:, None], axis=2).max(1)
            d, _ = tree.query(cen, k=1, distance_upper_bound=np.nextafter(reach + rad.max(), np.inf), workers=-1)
            F = F[d <= reach + rad]
    if len(F) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cr = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cr, axis=1)
    good = area2 > 1e-12
    a, b, c, cr, area2 = a[good], b[good], c[good], cr[good], area2[good]
    n = cr / area2[:, None]
    k = np.maximum(np.rint(0.5 * area2 / spacing ** 2).astype(np.int64), 1)
    face = np.repeat(np.arange(len(a)), k)
    rng = np.random.default_rng(seed)
    u, v = rng.random(len(face)), rng.random(len(face))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    first = np.r_[0, np.cumsum(k)[:-1]]
    u[first], v[first] = 1 / 3, 1 / 3          # every face keeps its centroid
    p = a[face] + u[:, None] * (b - a)[face] + v[:, None] * (c - a)[face]
    if tree is not None:
        d, _ = tree.query(p, k=1, distance_upper_bound=np.nextafter(reach, np.inf), workers=-1)
        return p[d <= reach], n[face][d <= reach]
    return p, n[face]


def pose_uncertainty(points: np.ndarray, sigma: np.ndarray, target: np.ndarray, target_normals: np.ndarray,
                     tree, T: np.ndarray, cfg: RegisterConfig) -> dict:
    """Standard deviations (m) of the point-to-plane pose estimate ``T`` along the eigen-directions of
    its information matrix (rotations scaled by the median lever arm, as in :func:`weighted_icp`):
    correspondences within ``overlap_m`` whose residual is within max(``inlier_m``, 3 sigma), each
    weighted by 1/(sigma_i^2 + map_sigma_m^2) with ``sigma`` (N,) the camera point's depth noise (m).
    Noisy far points (a low-resolution stereo camera: 5-15 cm at 6-10 m) carry little information;
    a pose they alone pin down is uncertain by centimetres even when its fitness looks good.
    Returns {"std_m": sorted (6,) largest first, "n": correspondences}."""
    p = transform_points(T, points)
    d, j = tree.query(p, k=1, distance_upper_bound=cfg.overlap_m, workers=-1)   # (bounded: far points end early)
    ok = d < cfg.overlap_m
    if ok.sum() < 6:
        return {"std_m": [float("inf")] * 6, "n": int(ok.sum())}
    j = j[ok]
    pp, nn = p[ok], target_normals[j]
    r = np.einsum("ij,ij->i", pp - target[j], nn)
    s2 = sigma[ok] ** 2 + cfg.map_sigma_m ** 2
    inl = np.abs(r) <= np.maximum(cfg.inlier_m, 3 * np.sqrt(s2))
    pp, nn, w = pp[inl], nn[inl], 1.0 / s2[inl]
    c = np.average(pp, axis=0, weights=w)
    Lc = float(np.median(np.linalg.norm(pp - c, axis=1))) or 1.0
    J = np.concatenate([np.cross(pp - c, nn) / Lc, nn], axis=1)
    ev = np.linalg.eigvalsh((J * w[:, None]).T @ J)
    std = 1.0 / np.sqrt(np.maximum(ev, 1e-12))
    return {"std_m": sorted(std.tolist(), reverse=True), "n": int(inl.sum())}


def held_directions(held: tuple) -> list[str]:
    """Plain words for the directions :func:`weighted_icp` held at the guess (``info["held"]``: V (6,k)
    in its update coordinates, rotation × lever arm then translation, world frame): "translation along
    (x, y, z)" or "rotation about (x, y, z)", whichever part of the direction is larger."""
    V = held[0]
    out = []
    for v in np.asarray(V, float).T:
        rot, tr = v[:3], v[3:]
        is_tr = np.linalg.norm(tr) >= np.linalg.norm(rot)
        a = (tr if is_tr else rot) / max(np.linalg.norm(tr if is_tr else rot), 1e-12)
        a = a * (1 if a[np.argmax(np.abs(a))] > 0 else -1) + 0.0    # (+ 0.0: no "-0.00")
        a = np.where(np.abs(a) < 0.005, 0.0, a)
        what = "translation along" if is_tr else "rotation about"
        out.append(f"{what} ({a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f})")
    return out


def prior_deviation(T: np.ndarray, init: np.ndarray) -> tuple[float, float]:
    """How far a camera pose ``T`` (4,4) lies from the initial guess ``init``: (metres, degrees)."""
    return float(np.linalg.norm(T[:3, 3] - init[:3, 3])), rotation_angle_deg(np.linalg.inv(init) @ T)


def register_extrinsic(static_cam: np.ndarray, map_points: np.ndarray, init: np.ndarray,
                       cfg: RegisterConfig | None = None, allow_fallback: bool = True,
                       sigma: np.ndarray | None = None, mesh: tuple | None = None,
                       anchor: np.ndarray | None = None) -> Registration:
    """``T_world_camera`` from the static camera cloud ``static_cam`` (N,3, camera frame) and the map
    ``map_points`` (M,3, world) from ``init`` (4,4): open3d point-to-plane ICP then, with per-point
    depth noise ``sigma`` (N,) m, a noise-weighted refinement (:func:`weighted_icp`); checked;
    FPFH+RANSAC+ICP fallback, checked. ``mesh`` (vertices (V,3), faces (F,3)): a static mesh of the
    scene in the map's frame (:func:`scene_mesh`) whose surface near the camera cloud joins the
    target (docs/design/register.md, 3.). ``anchor`` (3,) m: ``init`` is a TF pose and the map a SLAM map
    anchored at the TF pose of a scan taken there; directions the ICP holds then go where the map's
    offset puts the guess (:func:`anchored_guess`) instead of staying at it. Never returns an
    unchecked transform: ``accepted`` False means both failed (the caller raises)."""
    from scipy.spatial import cKDTree

    cfg = cfg or RegisterConfig()
    src_all = np.asarray(static_cam, np.float64)
    sig = np.full(len(src_all), 0.01) if sigma is None else np.maximum(np.asarray(sigma, np.float64), 0.003)
    keep = np.linalg.norm(src_all, axis=1) <= cfg.max_range_m
    src_all, sig = src_all[keep], sig[keep]
    # voxel-thin (one point per cam_voxel cell, the least noisy)
    cell = np.floor(src_all / cfg.cam_voxel).astype(np.int64)
    order = np.argsort(sig, kind="stable")
    _, first = np.unique(cell[order], axis=0, return_index=True)
    sel = order[first]
    src, sig = src_all[sel], sig[sel]
    src_n = np.asarray(_pcd(src, None, 3 * cfg.cam_voxel).normals)   # same order (no thinning)
    mesh_pts = None
    if mesh is not None and cfg.mesh_target and len(mesh[1]):
        mesh_pts, mesh_n = mesh_surface_samples(mesh[0], mesh[1], transform_points(init, src),
                                                cfg.crop_m + cfg.max_scale_m, cfg.mesh_sample_m)
        if len(mesh_pts) < cfg.min_overlap_points:
            mesh_pts = None
    if cfg.map_plane_m > 0 and (mesh_pts is None or cfg.mesh_keep_map_m <= 0):
        # denoise the target: map points near the camera cloud (under the guess) onto their local planes
        mp = voxel_average(map_points, cfg.map_voxel)
        reach = cfg.crop_m + cfg.max_scale_m + cfg.map_plane_m
        near_cam = _nn_distances(mp, transform_points(init, src), reach) <= reach
        map_points = local_plane_projection(mp, cfg.map_plane_m, cfg.map_plane_ratio, only=near_cam)
    tgt_pts, tgt_n = map_normals(map_points, cfg)
    if mesh_pts is not None:
        # the mesh's surface near the camera cloud joins the (denoised) map; with mesh_keep_map_m > 0
        # it replaces the map points within that distance instead (measured a little worse)
        far = (_nn_distances(tgt_pts, mesh_pts, cfg.mesh_keep_map_m) > cfg.mesh_keep_map_m if cfg.mesh_keep_map_m > 0
               else np.ones(len(tgt_pts), bool))
        tgt_pts, tgt_n = np.concatenate([mesh_pts, tgt_pts[far]]), np.concatenate([mesh_n, tgt_n[far]])
    tgt_tree = cKDTree(tgt_pts)
    # only the part of the camera cloud that can overlap the map matters (the rest was never seen by
    # the LiDAR): crop to within crop_m of the map under the initial guess (fast, and fewer outliers)
    full_src, full_sig, full_n = src, sig, src_n
    near = _nn_distances(transform_points(init, src), tgt_pts, cfg.crop_m) <= cfg.crop_m
    if near.sum() >= cfg.min_overlap_points:
        src, sig, src_n = src[near], sig[near], src_n[near]
    attempts = []

    def check(T, frozen: int = 0, held=None):
        # judged on the precise camera points (depth noise <= check_sigma_m) when there are enough:
        # far stereo points are too noisy to tell a right from a slightly wrong alignment
        p = transform_points(T, full_src)
        # only points within overlap_m count: the bounded search ends early for the far ones (the
        # camera's view of what the LiDAR never saw), which an unbounded one searched the whole map for
        d, j = tgt_tree.query(p, k=1, distance_upper_bound=cfg.overlap_m, workers=-1)
        j = np.minimum(j, len(tgt_pts) - 1)
        r = np.einsum("ij,ij->i", p - tgt_pts[j], tgt_n[j])
        precise = full_sig <= cfg.check_sigma_m
        if int((precise & (d < cfg.overlap_m)).sum()) >= cfg.min_overlap_points:
            d, r = d[precise], r[precise]
        c = _check_from_distances(d, cfg, r)
        # and the pose must be determined by the data: directions held at the guess (frozen) aside,
        # the estimate's standard deviation along every direction <= max_pose_std_m
        u = pose_uncertainty(full_src, full_sig, tgt_pts, tgt_n, tgt_tree, T, cfg)
        std = float(u["std_m"][min(frozen, 5)])
        c["pose_std_m"] = std
        # along the held directions the result is the guess: its uncertainty is the guess's, not a
        # measurement (never a sub-centimetre figure the data did not give)
        c["held_directions"] = held_directions(held) if frozen and held is not None else []
        c["uncertainty_m"] = max(std, cfg.guess_std_m) if frozen else std
        if cfg.max_pose_std_m > 0 and c["uncertainty_m"] > cfg.max_pose_std_m:
            c["accepted"] = False
        return c

    def refine(T0, info):
        # Gauss-Newton point-to-plane with Tukey loss and degeneracy-aware updates. Not open3d's
        # registration_icp: from the exact pose it slid 43 cm along a corridor the overlap sees
        # end-on (T corner, 1.5 m wide), and it has no way to hold such directions. Uniform weights:
        # per-point camera noise weights were measured worse (the map's own error is not modelled).
        return weighted_icp(src, (1.0 / (sig ** 2 + cfg.map_sigma_m ** 2)) if cfg.noise_weights else np.full(len(src), 1e4), tgt_pts, tgt_n, T0, cfg.icp_distances, cfg.icp_iterations,
                            degenerate_ratio=ratio, info=info, source_normals=src_n,
                            min_normal_cos=cfg.min_normal_cos, search_m=cfg.search_m,
                            max_std_m=cfg.max_std_m if cfg.noise_weights else 0.0, max_scale=cfg.max_scale_m,
                            hold_m=cfg.hold_m)

    # against the mesh's smooth surface a weak direction (a T corner's corridor seen end-on) is
    # determined by the data; against the noisy points it was held at the guess
    ratio = cfg.mesh_degenerate_ratio if mesh_pts is not None else cfg.degenerate_ratio
    info: dict = {}
    T = refine(init, info)
    anchor_turn = None
    if anchor is not None and info.get("frozen") and cfg.anchor_max_deg > 0:
        V = info["held"][0]
        target, anchor_turn = anchored_guess(T, init, anchor, V[3:, 0], cfg.anchor_max_deg, cfg.anchor_agree_deg)
        if target is not None:
            T = hold_at(T, target, info["held"])
        anchor_turn["applied"] = target is not None
    c = check(T, info.get("frozen", 0), info.get("held"))
    attempts.append({"method": "icp", **c, "target": "map+mesh" if mesh_pts is not None else "map",
                     "frozen_directions": info.get("frozen", 0),
                     "eigenvalues_rel": info.get("eigenvalues"), "anchor_turn": anchor_turn})
    best = ("icp", T, c)
    if not c["accepted"] and allow_fallback:
        src, sig, src_n = full_src, full_sig, full_n
        Tg = fpfh_ransac(src, tgt_pts, cfg.fpfh_voxel)
        info2: dict = {}
        T2 = refine(Tg, info2)
        c2 = check(T2, info2.get("frozen", 0), info2.get("held"))
        shift, rot = prior_deviation(T2, init)
        c2 = {**c2, "prior_shift_m": shift, "prior_rot_deg": rot}
        if shift > cfg.fallback_max_shift_m or rot > cfg.fallback_max_rot_deg:
            c2["accepted"] = False
        attempts.append({"method": "fpfh+icp", **c2, "frozen_directions": info2.get("frozen", 0),
                         "eigenvalues_rel": info2.get("eigenvalues")})
        if c2["accepted"]:
            best = ("fpfh+icp", T2, c2)
    m, T, c = best
    return Registration(T, m, c["fitness"], c["rmse"], c["overlap"], c["accepted"], attempts)


# ------------------------------------------------------------------------------------ camera frames
@dataclass
class CameraFrames:
    """A scene's camera clouds on the depth image grid: ``K`` (3,3), ``shape`` (h, w)."""

    scene: object
    K: np.ndarray
    shape: tuple

    @classmethod
    def open(cls, scene, url: str = "") -> "CameraFrames":
        where = f"{url}: scene {scene.id!r}"
        if "camera/points" not in set(scene.arrays()):
            raise InputError(f"{where} has no camera/points (nothing to register)")
        intr = ((scene.attrs.get("sensors") or {}).get("camera") or {}).get("intrinsics")
        if not intr or "K" not in intr:
            raise InputError(f"{where}: camera has no intrinsics (sensors.camera.intrinsics); register needs a "
                             f"depth camera whose pixels can be recovered")
        return cls(scene, np.asarray(intr["K"], float), (int(intr["height"]), int(intr["width"])))

    def points(self, k: int) -> np.ndarray:
        """(N,3) float64 finite camera-frame points of frame ``k`` in front of the camera (z > 0)."""
        return _camera_points(self.scene, k)

    def counts(self) -> np.ndarray:
        """(T,) int64 points stored per frame (from the ragged offsets; nothing else is read)."""
        return np.diff(np.asarray(self.scene["camera/points"].offsets[...], np.int64))

    def depth(self, k: int) -> np.ndarray:
        """(h,w) float32 depth image of frame ``k`` (NaN = none): each point in front of the camera (z > 0)
        at its nearest pixel, in float32 as stored (the camera points of a depth image are its pixels'
        rays, so the same pixels as in float64; ~7x faster at 376x672); non-finite points go nowhere."""
        p = np.asarray(self.scene.ragged("camera/points", k))
        h, w = self.shape
        D = np.full(h * w, np.nan, np.float32)
        if len(p):
            p = p.astype(np.float32, copy=False)
            f32 = np.float32
            with np.errstate(invalid="ignore", divide="ignore"):
                z = p[:, 2]
                iz = f32(1.0) / z
                u = p[:, 0] * iz
                u *= f32(self.K[0, 0])
                u += f32(self.K[0, 2])
                v = p[:, 1] * iz
                v *= f32(self.K[1, 1])
                v += f32(self.K[1, 2])
                np.rint(u, out=u)
                np.rint(v, out=v)
                ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)    # NaN/inf compare False
                pix = v.astype(np.intp)    # flat pixel index: one index array to scatter with, not two
                pix *= w
                pix += u.astype(np.intp)
            if ok.all():                   # (the usual frame: no gathered copies)
                D[pix] = z
            else:
                D[pix[ok]] = z[ok]
        return D.reshape(h, w)

    def rays(self) -> np.ndarray:
        """(h,w,3) camera-frame rays with z = 1."""
        h, w = self.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        return np.stack([(u - self.K[0, 2]) / self.K[0, 0], (v - self.K[1, 2]) / self.K[1, 1], np.ones((h, w))], -1)


def static_depth(cam: CameraFrames, frames: list[int], quiet: bool = True, far_quantile: float = 0.8,
                 images: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Static depth picture from ``frames``: per pixel the mean of the *background* samples (NaN where
    fewer than half the frames have a return), their robust spread σ (1.4826 · MAD, m) and how many
    were averaged. A moving person is only ever in front of the static scene, so the background
    samples are those within 3 σ (stereo model, :func:`depth_noise_model`) of the pixel's
    ``far_quantile`` sample, then within 3 robust sigmas of their median. The plain median failed
    when a person walks along the camera's line of sight and covers the same pixels in most frames
    (quick demo L corner: the person became static scene in 5 of 12 frames and a wall fragment was
    taken instead, 150-180 cm off). A pixel has no static depth (NaN: its returns are candidates in
    every frame) where fewer than half the frames have a return, or where fewer than half the returns
    are background samples and the nearest other sample lies within the window of them (a continuum of
    depths: something moving along the line of sight that covers the pixel in every frame, not a wall
    seen behind a person). Frames whose depth image holds no return are left out; None when none holds
    one. ``images``: a dict that receives {frame: depth image} of ``frames``."""
    if not frames:
        return None
    images = {} if images is None else images
    for k in track(frames, len(frames), "camera background", quiet):
        images[k] = cam.depth(k)
    stack = np.stack([images[k] for k in frames])
    keep = np.isfinite(stack).any(axis=(1, 2))
    return static_depth_of(stack[keep], far_quantile) if keep.any() else None


def static_depth_of(stack: np.ndarray, far_quantile: float = 0.8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`static_depth` of a stack of depth images (F,h,w) float32 m, NaN = no return.

    Everything here is a per-pixel statistic of the frames' samples, so it is read off one sorted
    copy of the stack: a pixel's background samples (within the window of its far sample) are a run
    of its sorted samples, and so are the samples short of that window. One float64 buffer holds the
    deviations; the fresh memory of a temporary per step (~1 GB for 60 frames of 376x672) cost more
    than the arithmetic. Same values as the plain formulation (test)."""
    import warnings

    F = len(stack)
    s = np.sort(stack, axis=0)                       # NaN (and inf) sort last
    n = np.isfinite(stack).sum(0)
    dev = np.empty(stack.shape, np.float64)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        med, far = (_sorted_quantile(s, n, q) for q in (0.5, far_quantile))   # (np.nanmedian, np.nanquantile)
        np.abs(np.subtract(stack, med[None], out=dev), out=dev)
        dev.sort(axis=0)
        mad = 1.4826 * _sorted_quantile(dev, n, 0.5)
        window = np.maximum(3 * depth_noise_model(far, mad), 0.02)
        # the background samples, within the window of the far one: sorted samples [start, start + m)
        np.subtract(s, far[None], out=dev)
        start = (dev < -window[None]).sum(0)
        inside = np.abs(dev, out=dev) <= window[None]
        m = inside.sum(0)
        med = _sorted_quantile(s, m, 0.5, start)
        np.abs(np.subtract(s, med[None], out=dev), out=dev)
        dev[np.logical_not(inside, out=inside)] = np.nan
        dev.sort(axis=0)
        mad = 1.4826 * _sorted_quantile(dev, m, 0.5)
        # the nearest sample short of the background window: a background seen in a minority of the
        # frames must stand apart from what was in front of it (a wall behind a person); far samples
        # that continue the nearer ones are the far end of something moving along the line of sight
        short = (s < (far - window)[None]).sum(0)
        below = np.where(short > 0, np.take_along_axis(s, np.maximum(short - 1, 0)[None], 0)[0], -np.inf)
        apart = (far - window) - below >= window
        inl = np.abs(np.subtract(stack, med[None], out=dev), out=dev) <= np.maximum(3 * mad, 0.005)[None]
        cnt = inl.sum(0)
        s.fill(0.0)                                   # (s as the buffer of the inliers' sum: no NaN in it)
        np.copyto(s, stack, where=inl)
        mean = np.where(cnt > 0, s.sum(axis=0) / np.maximum(cnt, 1), np.nan)
    # no static depth where fewer than half the frames have a return, nor where fewer than half the
    # returns are background and these do not stand apart (the full demo's oblique_18: a person walking
    # along the line of sight covers such pixels in every frame; their "static" depth was the person at
    # the far end of the walk, whose torso was background there in 16 of 40 frames, 48 cm off)
    mean = np.where((n * 2 >= F) & ((cnt * 2 >= n) | apart), mean, np.nan).astype(np.float32)
    return mean, mad.astype(np.float32), cnt.astype(np.int32)


def _sorted_quantile(s: np.ndarray, n: np.ndarray, q: float, start: np.ndarray | int = 0) -> np.ndarray:
    """Quantile ``q`` (linear interpolation, as ``np.nanquantile``) of each pixel's ``n`` (H,W) values
    ``s[start:start + n]`` of a stack ``s`` (F,H,W) sorted along axis 0; NaN where n is 0."""
    top = np.maximum(n - 1, 0)
    pos = q * top
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, top)
    last = len(s) - 1
    v_lo = np.take_along_axis(s, np.minimum(start + lo, last)[None], 0)[0]
    v_hi = np.take_along_axis(s, np.minimum(start + hi, last)[None], 0)[0]
    return np.where(n > 0, v_lo + (pos - lo) * (v_hi - v_lo), np.nan)


def frame_candidates(cam: CameraFrames, frames, T: np.ndarray, rays: np.ndarray, front: np.ndarray,
                     always: np.ndarray, map_tree, cfg: "RegisterConfig", images: dict | None = None,
                     quiet: bool = True, label: str = "human candidates") -> list:
    """Per frame k of ``frames``: the returns that may be a person, (qw (N,3) float64 map frame, vv, uu
    (N,) int64 pixel rows / columns, dv (N,) float32 optical depths m): returns within
    ``cfg.max_range_m`` nearer than ``front`` (h,w) m (the static depth less its noise margin) or on
    pixels marked ``always`` (h,w) bool, moved to the map through ``T`` (4,4) T_world_camera along the
    pixel ``rays`` (h,w,3), and farther than ``cfg.map_explain_m`` from every map point (``map_tree``,
    a cKDTree of them). ``images``: depth images already made, by frame (taken out of the dict as used)."""
    out = []
    bound = np.nextafter(cfg.map_explain_m, np.inf)    # far points end their search early
    for k in track(frames, len(frames), label, quiet):
        D = images.pop(k, None) if images else None
        if D is None:
            D = cam.depth(k)
        with np.errstate(invalid="ignore"):
            fg = np.isfinite(D) & (always | (D < front)) & (D <= cfg.max_range_m)
        vv, uu = np.nonzero(fg)
        dv = D[vv, uu]
        qw = transform_points(T, rays[vv, uu] * dv[:, None])
        if len(qw):
            far = map_tree.query(qw, k=1, distance_upper_bound=bound, workers=1)[0] > cfg.map_explain_m
            qw, vv, uu, dv = qw[far], vv[far], uu[far], dv[far]
        out.append((qw, vv, uu, dv))
    return out


def camera_seen_through(points: np.ndarray, T: np.ndarray, K: np.ndarray, shape: tuple, images,
                        margin: np.ndarray | float, min_fraction: float = 0.2) -> np.ndarray:
    """(N,) bool: map ``points`` (N,3, world) the camera at ``T`` (4,4, T_world_camera; pinhole ``K``,
    image ``shape`` (h, w)) sees *through* — in at least ``min_fraction`` of the depth ``images`` (an
    iterable of (h, w) float32 m, NaN = none) with a return at the point's pixel, that return lies
    more than ``margin`` (m, scalar or (h, w)) beyond the point. Free-space carving with the camera's
    rays: a LiDAR map keeps a person who walks along the LiDAR's line of sight (the scans that would
    see through the far end of the walk are the ones the person blocks), but from the camera's
    side those voxels are empty whenever the person is elsewhere; such map points must not explain
    the person's returns away."""
    h, w = shape
    q = transform_points(np.linalg.inv(T), np.asarray(points, np.float64))
    z = q[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.rint(K[0, 0] * q[:, 0] / z + K[0, 2])
        v = np.rint(K[1, 1] * q[:, 1] / z + K[1, 2])
    inside = np.flatnonzero((z > 0.1) & (u >= 0) & (u < w) & (v >= 0) & (v < h))
    out = np.zeros(len(q), bool)
    if not len(inside):
        return out
    pix = v[inside].astype(np.intp) * w + u[inside].astype(np.intp)
    zi = z[inside]
    mg = np.broadcast_to(np.asarray(margin, np.float64), (h, w)).reshape(-1)[pix]
    through = np.zeros(len(inside), np.int32)
    seen = np.zeros(len(inside), np.int32)
    for D in images:
        d = D.reshape(-1)[pix]
        ok = np.isfinite(d)
        seen += ok
        through += ok & (d > zi + mg)
    out[inside] = (seen > 0) & (through >= np.maximum(1, min_fraction * seen))
    return out


def depth_noise_model(depth: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Per-pixel depth noise σ (m) from the stereo model σ = a·z² (disparity noise), with ``a`` the
    median of spread/z² over the pixels: smooth in z, unlike the per-pixel spread of a few frames
    (chance small spreads would get huge weights). Falls back to the spread where a is not finite."""
    z = np.asarray(depth, np.float64)
    s = np.asarray(spread, np.float64)
    ok = np.isfinite(z) & np.isfinite(s) & (z > 0.1) & (s > 0)
    if ok.sum() < 100:
        return np.where(np.isfinite(s), s, 0.01)
    a = float(np.median(s[ok] / z[ok] ** 2))
    return np.maximum(a * z ** 2, 1e-3)


# ------------------------------------------------------------------------------------ humans
def cluster_points(points: np.ndarray, dist: float) -> np.ndarray:
    """Connected components of points (N,3) whose voxels (edge ``dist``) touch (26-neighbourhood):
    labels (N,) int64 0..n-1 (vectorised: packed voxel keys, sorted, neighbour lookup by searchsorted)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .background import _keys

    if len(points) == 0:
        return np.zeros(0, np.int64)
    ijk = np.floor(np.asarray(points) / dist).astype(np.int64)
    keys = _keys(ijk)
    uniq, inv = np.unique(keys, return_inverse=True)
    inv = inv.reshape(-1)
    cells = ijk[np.unique(inv, return_index=True)[1]]
    rows, cols = [], []
    for o in [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) > (0, 0, 0)]:
        nk = _keys(cells + np.array(o))
        pos = np.minimum(np.searchsorted(uniq, nk), len(uniq) - 1)
        hit = uniq[pos] == nk
        rows.append(np.flatnonzero(hit))
        cols.append(pos[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    g = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(uniq), len(uniq)))
    _, comp = connected_components(g, directed=False)
    return comp[inv]


def static_residual(points: np.ndarray, cfg: "RegisterConfig", seed: int = 0) -> np.ndarray:
    """(N,) bool: points of the static camera cloud (N,3, any frame) that are on none of the large
    planes (floor, ceiling, walls: RANSAC planes, :func:`ransac_plane`, each holding at least
    ``plane_min_fraction`` of the points, up to ``max_planes``). Catches a person who stands still
    (and is therefore part of the temporal background)."""
    pts = np.asarray(points, np.float64)
    keep = np.ones(len(pts), bool)
    if len(pts) < 100:
        return keep
    rng = np.random.default_rng(seed)
    vox = np.floor(pts / cfg.cam_voxel).astype(np.int64)
    _, first, inv = np.unique(vox, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    sub = pts[first]
    alive = np.ones(len(sub), bool)
    for _ in range(cfg.max_planes):
        idx = np.flatnonzero(alive)
        if len(idx) < 100:
            break
        normal, offset, n_in = ransac_plane(sub[idx], cfg.plane_dist_m, 400, rng)
        if n_in < cfg.plane_min_fraction * len(sub):
            break
        alive &= ~(np.abs(sub @ normal + offset) < cfg.plane_dist_m)
    return alive[inv]


def ransac_plane(points: np.ndarray, dist: float, iterations: int, rng) -> tuple[np.ndarray, float, int]:
    """Plane with the most points (N,3) within ``dist`` (m) among ``iterations`` planes through three
    random points (numpy ``rng``), refitted by least squares to its inliers: (unit normal (3,), offset,
    inlier count) with ``normal · p + offset = 0``. Deterministic for a given ``rng`` state (open3d's
    multithreaded ``segment_plane`` is not, even seeded: its result depended on thread timing)."""
    p = np.asarray(points, np.float64)
    i = rng.integers(0, len(p), (iterations, 3))
    n = np.cross(p[i[:, 1]] - p[i[:, 0]], p[i[:, 2]] - p[i[:, 0]])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-12
    n, a = n[ok] / norm[ok, None], p[i[ok, 0]]
    d = -np.einsum("ij,ij->i", n, a)
    counts = np.zeros(len(n), np.int64)
    step = max(1, 4_000_000 // max(len(p), 1))          # (N, step) distances at a time
    for s in range(0, len(n), step):
        counts[s:s + step] = (np.abs(p @ n[s:s + step].T + d[s:s + step]) < dist).sum(0)
    if not len(counts):
        return np.array([0.0, 0.0, 1.0]), 0.0, 0
    b = int(np.argmax(counts))
    q = p[np.abs(p @ n[b] + d[b]) < dist]
    c = q.mean(0)
    normal = np.linalg.svd(q - c, full_matrices=False)[2][-1]     # least-squares plane of the inliers
    offset = -float(normal @ c)
    return normal, offset, int((np.abs(p @ normal + offset) < dist).sum())


def _robust_plan_extent(xy: np.ndarray) -> float:
    """Plan extent (m) along the principal axes, 2-98 % spread (stereo noise sprays a few points far
    behind a person)."""
    if len(xy) < 4:
        return 0.0
    c = xy - xy.mean(0)
    _, vec = np.linalg.eigh(c.T @ c)
    q = c @ vec
    lo, hi = np.percentile(q, [2, 98], axis=0)
    return float((hi - lo).max())


def pick_human(points_world: np.ndarray, cfg: RegisterConfig, centre: np.ndarray | None = None,
               footprint: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of the largest person-like cluster of ``points_world`` (N,3) (z up); with
    ``centre`` (3,) only clusters whose centroid is within ``track_radius_m`` (plan) of it count.

    ``footprint`` (N,): each return's pixel footprint in metres (optical depth / focal length in
    pixels). The camera's resolution then sets two things a fixed number cannot: clusters link points
    at least ``cluster_px`` footprints (at the candidates' median depth) apart, not only ``cluster_m``
    (a 160-column camera's pixels are 8 cm apart at 7 m: a person there is dust at 8 cm), and a
    cluster is evidence enough with ``min_points`` returns *or* ``min_area_m2`` of surface (each
    return covering footprint²: a sixth of a person's front), whichever the camera can give at that
    depth. Without it: ``cluster_m`` and ``min_points`` alone."""
    out = np.zeros(len(points_world), bool)
    fp2 = None if footprint is None else np.asarray(footprint, np.float64) ** 2
    if len(points_world) < cfg.min_points and (fp2 is None or fp2.sum() < cfg.min_area_m2):
        return out
    dist = cfg.cluster_m if fp2 is None else max(cfg.cluster_m, cfg.cluster_px * float(np.sqrt(np.median(fp2))))
    lab = cluster_points(points_world, dist)
    sizes = np.bincount(lab)
    enough = sizes >= cfg.min_points
    if fp2 is not None:
        enough |= np.bincount(lab, weights=fp2, minlength=len(sizes)) >= cfg.min_area_m2
    for c in np.argsort(-sizes):
        if not enough[c]:
            continue
        m = lab == c
        p = points_world[m]
        if centre is not None and np.linalg.norm(p[:, :2].mean(0) - centre[:2]) > cfg.track_radius_m:
            continue
        if np.ptp(p[:, 2]) >= cfg.min_height_m and _robust_plan_extent(p[:, :2]) <= cfg.max_width_m:
            # stereo noise sprays single points behind/in front of the body: statistical outlier removal
            _, keep = _pcd(p).remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
            idx = np.flatnonzero(m)
            m[:] = False
            m[idx[np.asarray(keep, np.int64)]] = True
            return m
    return out


def pixel_runs(rows: np.ndarray, cols: np.ndarray, gap: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal runs of pixels (``rows``, ``cols`` (N,) int): ``order`` (N,) the row-major sort of the
    pixels and ``run`` (N,) the run id of each sorted pixel (0..R-1). A run continues across fewer than
    ``gap`` missing pixels (``gap`` 1: strictly adjacent; 2 bridges the single stereo holes that split a
    torso into two narrow runs)."""
    order = np.lexsort((cols, rows))
    r, c = rows[order], cols[order]
    new = np.ones(len(r), bool)
    new[1:] = (r[1:] != r[:-1]) | (c[1:] - c[:-1] > gap)
    return order, np.cumsum(new) - 1


def body_columns(points_world: np.ndarray, rows: np.ndarray, cols: np.ndarray, depth: np.ndarray, eye: np.ndarray,
                 fx: float, lo: float, hi: float, gap: int = 2, floor_z: float | None = None,
                 floor_reach_m: float = 0.35, back_frac: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The solid behind a person's visible front, one horizontal column per human pixel.

    ``points_world`` (N,3) the pixels' points (map frame), ``rows``/``cols`` (N,) their pixels,
    ``depth`` (N,) their optical depths (m), ``eye`` (3,) the camera centre, ``fx`` px. Each horizontal
    run of pixels (:func:`pixel_runs`, bridging ``gap``) is a cross-section of width w (run length ·
    mean depth / fx) and depth D = clip(w, ``lo``, ``hi``) m (limbs about as deep as wide, the torso
    capped), modelled as an ellipse with axes w and D: the pixel at lateral position s in (-1, 1) of its
    run spans ± h = D/2 · sqrt(1 - s²) around the run's centre range c, and c is the mean over the run of
    each pixel's estimate (its measured plan range + h; values more than ``hi`` from the run's median are
    left out). The measured front only places the centre: stereo noise (σ ~5 cm at 3.6 m on the synthetic
    ZED) no longer scatters the surface, the back is the front mirrored through the centre, and a round
    limb is an ellipse of area π w D / 4 rather than a w × D box pushed a whole D back.

    Returns ``span`` (N,2): the column's near and far ends as offsets (m) along the horizontal viewing
    direction from the pixel's point (negative: toward the camera), ``pixel_m`` (N,) the pixel's footprint
    edge (depth / fx, m) and ``down_to`` (N,) heights (m) the column reaches down to, NaN for none: with
    ``floor_z`` given, the lowest human pixel of each image column lying within ``floor_reach_m`` above
    it reaches the floor (the foreground test loses the feet, whose background — the floor just
    behind them — is too near: 1-2 l of the body missing, the centroid 2 cm too high; and a walking
    person's far foot, hidden behind the near one in stride). ``back_frac``:
    every column's far end goes ``back_frac`` · D further back (the front stays): a person walking along
    the view hides the far leg and arm behind the near ones (register: ``walk_back_frac`` scaled by
    :func:`radial_speed`)."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    n = len(p)
    z = np.asarray(depth, np.float64)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    order, rid = pixel_runs(rows, cols, gap)
    nr = int(rid[-1]) + 1
    c, zs = cols[order], z[order]
    cmin = np.full(nr, np.iinfo(np.int64).max)
    np.minimum.at(cmin, rid, c)
    cmax = np.full(nr, -1, np.int64)
    np.maximum.at(cmax, rid, c)
    npx = cmax - cmin + 1
    cnt = np.bincount(rid, minlength=nr)
    w = npx * (np.bincount(rid, zs, minlength=nr) / cnt) / fx
    D = np.clip(w, lo, hi)[rid]
    s = (c - cmin[rid] + 0.5) / npx[rid] * 2.0 - 1.0
    h = 0.5 * D * np.sqrt(np.clip(1.0 - s * s, 0.0, 1.0))
    d = p[order] - np.asarray(eye, float)
    rho = np.linalg.norm(d[:, :2], axis=1)
    est = rho + h
    o = np.lexsort((est, rid))                       # per-run median, then the mean of the values near it
    start = np.cumsum(cnt) - cnt
    srt = est[o]
    med = 0.5 * (srt[start + (cnt - 1) // 2] + srt[start + cnt // 2])
    near = np.abs(est - med[rid]) <= hi
    centre = np.bincount(rid, est * near, minlength=nr) / np.maximum(np.bincount(rid, near, minlength=nr), 1)
    off = centre[rid] - rho
    span = np.empty((n, 2))
    span[order] = np.stack([off - h, off + h + back_frac * D], 1)
    down = np.full(n, np.nan)
    if floor_z is not None and np.isfinite(floor_z):
        oc = np.lexsort((-rows, cols))              # per image column, the lowest pixel (largest row) first
        low = oc[np.r_[True, cols[oc][1:] != cols[oc][:-1]]]
        low = low[p[low, 2] < floor_z + floor_reach_m]
        down[low] = floor_z
    return span, z / fx, down


def _repeat_index(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Item i repeated ``counts[i]`` times: (owner (sum,) item index, (sum,) index within its repeats)."""
    owner = np.repeat(np.arange(len(counts)), counts)
    return owner, np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)


def closed_surface(points_world: np.ndarray, eye: np.ndarray, thickness, voxel: float,
                   horizontal: bool = True, pixel_m=None, down_to=None) -> tuple[np.ndarray, np.ndarray]:
    """Closed triangle surface around the volume swept by the points (N,3) along their viewing rays
    from ``eye`` (3,) (their horizontal part when ``horizontal``: a body's depth is horizontal),
    voxelised at ``voxel`` m: vertices (V,3) float64, faces (F,3) int32, outward (counter-clockwise seen
    from outside).

    ``thickness``: scalar or (N,) m — each point extruded away from the camera over it; or (N,2) — the
    column from the first to the second offset (m, negative toward the camera; :func:`body_columns`).
    ``pixel_m`` (scalar or (N,), m): each point stands for a square pixel footprint of that edge; then a
    voxel is occupied when the columns fill at least half of it (their volume, sampled every voxel/2
    along the column, summed per voxel): an unbiased voxelisation. Without it every voxel a column
    touches is occupied (each dimension grows by about a voxel: a 15 cm leg became 19 cm wide).
    A footprint wider than the voxel is split into m × m sub-pixels (m = ceil(edge / voxel)) so that
    its volume spreads over the voxels it covers. ``down_to`` (N,) m, NaN for none: the point's column
    also fills the vertical strip below its footprint down to that height (feet reaching the floor)."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    d = p - np.asarray(eye, float)
    if horizontal:  # a body's depth is horizontal: extrude along the ray's plan direction
        d[:, 2] = 0.0
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    th = np.asarray(thickness, float)
    if th.ndim == 2:
        a, b = th[:, 0], th[:, 1]
    else:
        a, b = np.zeros(len(p)), np.broadcast_to(th, (len(p),)).astype(float)
    if pixel_m is None:
        L = b - a
        frac = np.linspace(0.0, 1.0, max(2, int(np.ceil(max(L.max(), 0.0) / (voxel / 2))) + 1))
        t = a[:, None, None] + frac[None, :, None] * L[:, None, None]
        sw = (p[:, None, :] + t * d[:, None, :]).reshape(-1, 3)
        return voxel_boundary(np.floor(sw / voxel).astype(np.int64), voxel)     # repeated voxels are fine
    px = np.broadcast_to(np.asarray(pixel_m, float), (len(p),))
    m_sub = np.maximum(1, np.ceil(px / voxel - 1e-9).astype(np.int64))
    if (m_sub > 1).any():
        # a footprint wider than a voxel (a coarse camera, a far person) is split into m × m sub-pixels
        # across it (lateral × vertical), else its whole volume lands in the voxels along one line
        j, k = _repeat_index(m_sub ** 2)
        mj = m_sub[j]
        u = ((k % mj) + 0.5) / mj - 0.5
        v = ((k // mj) + 0.5) / mj - 0.5
        lat = np.stack([-d[j, 1], d[j, 0], np.zeros(len(j))], 1)
        lat /= np.maximum(np.linalg.norm(lat, axis=1, keepdims=True), 1e-9)
        p = p[j] + (u * px[j])[:, None] * lat + np.outer(v * px[j], [0.0, 0.0, 1.0])
        d, a, b, px = d[j], a[j], b[j], px[j] / mj
        if down_to is not None:
            down_to = np.asarray(down_to, float)[j]
    step = voxel / 2
    L = np.maximum(b - a, 0.0)
    ns = np.maximum(1, np.ceil(L / step).astype(np.int64))
    idx, k = _repeat_index(ns)
    t = a[idx] + (k + 0.5) / ns[idx] * L[idx]
    q = p[idx] + t[:, None] * d[idx]
    wgt = px[idx] ** 2 * (L / ns)[idx]
    if down_to is not None:
        dz = np.asarray(down_to, float)
        sel = np.isfinite(dz[idx])
        if sel.any():                                # strips below the footprint, down to ``down_to``
            qs, ws, j0 = q[sel], wgt[sel], idx[sel]
            ext = np.maximum(qs[:, 2] - px[j0] / 2 - dz[j0], 0.0)
            m = np.maximum(1, np.ceil(ext / step).astype(np.int64))
            j, kk = _repeat_index(m)
            qq = qs[j].copy()
            qq[:, 2] -= px[j0][j] / 2 + (kk + 0.5) / m[j] * ext[j]
            q = np.concatenate([q, qq])
            wgt = np.concatenate([wgt, ws[j] / px[j0][j] * ext[j] / m[j]])
    ijk = np.floor(q / voxel).astype(np.int64)
    lo = ijk.min(0)
    ijk -= lo
    dims = ijk.max(0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    full = np.flatnonzero(np.bincount(key, wgt, minlength=int(np.prod(dims))) >= 0.5 * voxel ** 3)
    if not len(full):
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    occ = np.stack(np.unravel_index(full, tuple(dims)), 1) + lo
    return voxel_boundary(occ, voxel)


def voxel_boundary(occ: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Boundary surface of a set of occupied voxels ``occ`` (N,3) int (repeats allowed): two triangles
    per voxel face not shared with another occupied voxel; shared vertices (a closed mesh), outward
    orientation; vertices in lexicographic lattice order."""
    occ = np.asarray(occ, np.int64).reshape(-1, 3)
    if len(occ) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    lo = occ.min(0) - 1
    o = occ - lo
    dims = o.max(0) + 2
    grid = np.zeros(dims, bool)
    grid[o[:, 0], o[:, 1], o[:, 2]] = True
    quads = []
    # for each axis and direction: faces where occupied voxel meets empty neighbour
    for ax in range(3):
        for sgn in (1, -1):
            nb = np.roll(grid, -sgn, axis=ax)
            face = grid & ~nb
            idx = np.argwhere(face)
            if not len(idx):
                continue
            # face plane at coordinate idx[ax] + (1 if sgn > 0 else 0); the other two axes span it
            a1, a2 = [a for a in range(3) if a != ax]
            base = idx.copy()
            base[:, ax] += 1 if sgn > 0 else 0
            c = np.zeros((len(idx), 4, 3), np.int64)
            for q, (da, db) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
                c[:, q] = base
                c[:, q, a1] += da
                c[:, q, a2] += db
            # orientation: (a1, a2, ax) right-handed for ax = 0 -> (1,2), 1 -> (2,0), 2 -> (0,1)
            right = (a1, a2) in ((1, 2), (2, 0), (0, 1))
            if right != (sgn > 0):
                c = c[:, ::-1]
            quads.append(c)
    q = np.concatenate(quads)                      # (Q,4,3) corner lattice coordinates, in 0..dims
    # vertex ids on a dense lattice of the box (C order: lexicographic, as a sort would number them)
    flat = np.ravel_multi_index((q[..., 0], q[..., 1], q[..., 2]), tuple(dims + 1))
    used = np.zeros(int(np.prod(dims + 1)), bool)
    used[flat] = True
    cells = np.flatnonzero(used)
    ids = np.zeros(len(used), np.int64)
    ids[cells] = np.arange(len(cells))
    inv = ids[flat]
    faces = np.concatenate([inv[:, [0, 1, 2]], inv[:, [0, 2, 3]]]).astype(np.int32)
    corners = np.stack(np.unravel_index(cells, tuple(dims + 1)), 1)
    verts = (corners + lo).astype(np.float64) * voxel
    return verts, faces


# ------------------------------------------------------------------------------------ pipeline
def _parse_init(init) -> np.ndarray | None:
    if init is None:
        return None
    a = np.asarray(init, float)
    if a.shape == (4, 4):
        return a
    if a.shape == (6,):
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", np.deg2rad(a[3:])).as_matrix()
        T[:3, 3] = a[:3]
        return T
    raise InputError(f"--init needs x,y,z,roll,pitch,yaw (m, degrees), got {init!r}")


def map_cloud(scans, bg, traj, voxel: float, deskew: bool = True, instances=None, margin_m: float = 0.25,
              max_scans: int = 0, world_points: dict | None = None) -> np.ndarray:
    """World-frame static map: every scan's returns inside the background model and farther than
    ``margin_m`` from the scan's segmented instances ``instances`` (lazy (T,H,W) array or None),
    voxel-thinned; at most ``max_scans`` scans (0: all): motion keyframes plus scans spread in time,
    as for slam's mesh (a 400-cycle corner has 400 scans, most taken at rest). The instance margin
    removes the parts of people that fall into static voxels (a hand near a wall, feet on the
    floor), which would otherwise bias the registration. ``world_points``: {frame: world points of
    the valid returns (N,3)} already de-skewed with ``traj`` (the segmentation's background pass);
    scans in it without instances are taken from it instead of being read and de-skewed again."""
    from scipy.spatial import cKDTree

    from .segment import in_background

    pts = []
    ks = list(range(len(scans.stamps)))
    if max_scans and len(ks) > max_scans:  # long recordings: motion keyframes + scans evenly spread in time
        from .slam import mesh_scan_subset

        ks = [k for k in ks if scans.usable(k)]
        ks = [ks[i] for i in mesh_scan_subset(np.asarray(scans.poses)[ks], max_scans)]
    for k in ks:
        inst = np.asarray(instances[k]) > 0 if instances is not None else None
        if world_points is not None and k in world_points and (inst is None or not inst.any()):
            p = np.asarray(world_points[k], np.float64)
        else:
            valid, _, Pw = scans.scan(k, traj, deskew)
            if inst is not None and (inst & valid).any():
                d, _ = cKDTree(Pw[inst & valid]).query(Pw[valid], k=1, distance_upper_bound=margin_m, workers=-1)
                keep = np.zeros_like(valid)
                keep[valid] = ~np.isfinite(d)
                valid = keep
            p = Pw[valid]
        if bg is not None and len(p):
            p = p[in_background(bg, p, 0)]
        if len(p):
            pts.append(voxel_average(p, voxel))
    if not pts:
        return np.zeros((0, 3))
    return voxel_average(np.concatenate(pts), voxel)


def lidar_map(url: str, sid: str, cfg: RegisterConfig, segment: bool, quiet: bool = True, build_map: bool = True,
              early=None) -> tuple[np.ndarray | None, dict | None, dict]:
    """The LiDAR half of :func:`register_scene` (step 2 and the segmentation): background model,
    the static map (when ``build_map``) and, when ``segment``, ``lidar/instance``. The map is built
    first, with the instance masks of the few map scans that have foreground computed on the spot,
    and handed to ``early`` (a callback, or None) before the segmentation of every scan starts.
    Returns (map points (M,3) float64 world or None, segmentation summary or None, timings
    {background_s, map_s, segment_s})."""
    from ..dataset import open_dataset
    from .segment import InstanceMasks, LidarScans, SegmentConfig, background_and_segment, segment_scene

    t0 = time.perf_counter()
    scene = open_dataset(url).scene(sid)
    scans = LidarScans.open(scene, url)
    traj = scans.trajectory()
    scfg = SegmentConfig()
    bg, _, world_points = background_and_segment(url, sid, scfg, quiet, segment=False, scans=scans, traj=traj)
    t1 = time.perf_counter()
    if segment:
        inst = InstanceMasks(scans, bg, scfg, traj, world_points)
    else:
        inst = scene["lidar/instance"] if "lidar/instance" in set(scene.arrays()) else None
    M = map_cloud(scans, bg, traj, cfg.map_voxel, instances=inst, max_scans=cfg.map_max_scans,
                  world_points=world_points) if build_map else None
    t2 = time.perf_counter()
    if early is not None:
        early(M)
    seg_summary = (segment_scene(url, sid, scfg, quiet, background=bg, world_points=world_points, masks=inst)
                   if segment else None)         # the masks the map asked for are not computed again
    return M, seg_summary, {"background_s": t1 - t0, "map_s": t2 - t1, "segment_s": time.perf_counter() - t2}


def _camera_points(scene, k: int) -> np.ndarray:
    """(N,3) float64 finite camera-frame points of frame ``k`` in front of the camera (z > 0)."""
    p = np.asarray(scene.ragged("camera/points", k), np.float64)
    return p[np.isfinite(p).all(1) & (p[:, 2] > 0)] if len(p) else p.reshape(0, 3)


def _camera_points_through(scene, T: np.ndarray, k: int) -> np.ndarray:
    """(N,3) float32: :func:`_camera_points` of frame ``k`` through ``T`` (4,4) T_world_camera."""
    return transform_points(T, _camera_points(scene, k)).astype(np.float32)


def camera_points_world(scene, k: int) -> np.ndarray:
    """(N,3) float32 camera points of frame ``k`` of a registered ``scene`` in the map frame (finite,
    in front of the camera): ``camera/points_world`` where register stored it, else the same values
    from ``camera/points`` through ``calib/T_world_camera``."""
    names = set(scene.arrays())
    if "camera/points_world" in names:
        return np.asarray(scene.ragged("camera/points_world", k))
    if "calib/T_world_camera" not in names:
        raise InputError(f"scene {scene.id!r} has no calib/T_world_camera (run holodata register first)")
    return _camera_points_through(scene, np.asarray(scene["calib/T_world_camera"][...], np.float64), k)


def camera_world(url: str, sid: str, T: np.ndarray) -> None:
    """Write ``camera/points_world`` of scene ``sid`` (made by the caller): every camera point in the
    map frame through ``T`` (4,4) T_world_camera, float32, shard by shard (the recording's clouds
    never sit in memory together)."""
    from ..dataset import create_dataset, open_dataset

    ds = open_dataset(url)
    scene = ds.scene(sid)
    arr = create_dataset(url, grid=ds.grid, range_bins=ds.range_bins).scene(sid).ragged_array(
        "camera/points_world", 3, "float32", "m", ["point", "xyz"])
    for s in range(arr.n_shards):
        sl = arr.frames(s)
        arr.write_shard(s, [_camera_points_through(scene, T, k) for k in range(sl.start, sl.stop)])


def human_surfaces(points: list, columns: list, shift: np.ndarray, eye: np.ndarray, voxel: float) -> list:
    """:func:`closed_surface` per frame: (vertices (V,3) float32, faces (F,3) int32) of each frame's
    human points (N,3) moved by its velocity ``shift`` (3,) m, seen from ``eye`` (3,), with its
    :func:`body_columns` (span (N,2), pixel_m (N,), down_to (N,)); empty for a frame without points."""
    out = []
    for p, (span, px, down), d in zip(points, columns, shift):
        if len(p) == 0:
            out.append((np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)))
            continue
        down = down + d[2] if down is not None else None
        v, f = closed_surface(np.asarray(p, np.float64) + d, eye + d, span, voxel, pixel_m=px, down_to=down)
        out.append((v.astype(np.float32), f.astype(np.int32)))
    return out


def register_processes(cfg: RegisterConfig) -> int:
    """Processes :func:`register_scene` uses: ``cfg.processes``, or with 0 two when the machine has two
    CPUs for it (one otherwise)."""
    if cfg.processes:
        return max(1, int(cfg.processes))
    return 2 if cpus() >= 2 else 1


def _built_from_the_poses(scene, names: tuple) -> bool:
    """True when the scene holds the arrays ``names`` and each one's ``source`` attribute equals
    ``pose/T_world_lidar``'s (``holodata slam`` writes "slam" on its poses, mesh and map; poses
    replaced afterwards, e.g. by the true ones, leave products that no longer match them)."""
    nodes = scene.nodes()
    names = names + ("pose/T_world_lidar",)
    if not all(n in nodes for n in names):
        return False
    src = [(nodes[n][1].get("attributes") or {}).get("source") for n in names]
    return src[0] is not None and len(set(src)) == 1


def slam_anchor(scene) -> np.ndarray | None:
    """(3,) m: the LiDAR position at the first scan when the scene's poses are ``holodata slam``'s,
    anchored at the TF pose of that scan (their world is the TF world, off by the odometry's error
    there); None otherwise."""
    nodes = scene.nodes()
    if "pose/T_world_lidar" not in nodes:
        return None
    if (nodes["pose/T_world_lidar"][1].get("attributes") or {}).get("source") != "slam":
        return None
    anchor = (scene.attrs.get("slam") or {}).get("anchor") or {}
    T0 = anchor.get("T_world_lidar0")
    if anchor.get("kind") != "tf" or T0 is None:
        return None
    return np.asarray(T0, np.float64)[:3, 3]


def scene_mesh(scene) -> tuple[np.ndarray, np.ndarray] | None:
    """The scene's static mesh (``mesh/vertices`` (V,3), ``mesh/faces`` (F,3)) when it was built from
    the poses the scene holds now (:func:`_built_from_the_poses`); None otherwise."""
    if not _built_from_the_poses(scene, ("mesh/vertices", "mesh/faces")):
        return None
    return np.asarray(scene["mesh/vertices"][...], np.float64), np.asarray(scene["mesh/faces"][...], np.int64)


def scene_map(scene) -> np.ndarray | None:
    """slam's static map ``map/points`` (M,3) float64 world when it was built from the poses the scene
    holds now (:func:`_built_from_the_poses`); None otherwise."""
    if not _built_from_the_poses(scene, ("map/points",)):
        return None
    return np.asarray(scene["map/points"][...], np.float64)


def camera_tf_guess(scene) -> tuple[str | None, list | None]:
    """(world frame, T_world_camera 4x4 nested list) of the camera's static TF pose that ingest stored
    (``sensors.camera.T_<world>_sensor``); (None, None) without one."""
    cam = (scene.attrs.get("sensors") or {}).get("camera") or {}
    for k, v in cam.items():
        if k.startswith("T_") and k.endswith("_sensor") and v is not None:
            return k[2:-len("_sensor")], v
    return None, None


def map_frame_problem(scene, world: str) -> str | None:
    """Why the scene's LiDAR poses (``pose/T_world_lidar``, hence its map) are not in the TF frame
    ``world``, or None when they are: slam found no TF pose of the LiDAR (its world is then the
    first scan's frame: ``anchor`` base or lidar), or its poses name another world frame."""
    nodes = scene.nodes()
    if "pose/T_world_lidar" not in nodes:
        return None
    a = nodes["pose/T_world_lidar"][1].get("attributes") or {}
    if a.get("source") == "slam" and a.get("anchor") not in (None, "tf"):
        return (f"the LiDAR map is in the {a.get('world_frame') or 'first scan frame'} (slam found no TF pose of "
                f"the LiDAR: TF does not connect its frame to {world!r})")
    wf = a.get("world_frame")
    if wf and (a.get("source") != "slam" or a.get("anchor") == "tf") and str(wf).lstrip("/") != world.lstrip("/"):
        return f"the LiDAR map is in {wf!r}"
    return None


REGISTER_OUTPUTS = ("calib/T_world_camera", "human/vertices", "human/faces", "human/points")


def register_fingerprint(scene, cfg: RegisterConfig, init) -> str:
    """What register's outputs depend on, hashed: the settings (less ``processes``, which changes no
    result), ``--init``, the camera's TF pose and intrinsics (``sensors.camera``), ingest's
    fingerprint (the camera and LiDAR arrays) and the bytes of slam's poses, map points and mesh."""
    import hashlib
    import json

    h = hashlib.sha256()
    params = {k: v for k, v in cfg.to_attrs().items() if k != "processes"}
    head = {"params": params, "init": None if init is None else np.asarray(_parse_init(init), float).tolist(),
            "camera": (scene.attrs.get("sensors") or {}).get("camera"),
            "ingest": (scene.attrs.get("ingest") or {}).get("fingerprint")}
    h.update(json.dumps(head, sort_keys=True, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)).encode())
    names = set(scene.arrays())
    for name in ("pose/T_world_lidar", "map/points", "mesh/vertices", "mesh/faces"):
        if name in names:
            h.update(name.encode())
            h.update(np.ascontiguousarray(scene[name][...]).tobytes())
    return h.hexdigest()[:16]


def register_scene(url: str, scene_id: str | None = None, init=None, cfg: RegisterConfig | None = None,
                   quiet: bool = True, force: bool = False) -> dict:
    """``holodata register``: extrinsic + human points/surfaces for one scene (see the module
    docstring). Returns a summary dict; raises :class:`RegistrationError` if no registration passes.
    A scene registered before from the same inputs and settings (:func:`register_fingerprint`, every
    output present) is not registered again unless ``force``: the stored report comes back with
    ``skipped`` set, as slam does."""
    from ..dataset import create_dataset, open_dataset
    from .segment import LidarScans, _scene_id, instance_state

    cfg = cfg or RegisterConfig()
    t0 = time.perf_counter()
    timings = {}
    ds = open_dataset(url)
    sid = _scene_id(ds, url, scene_id)
    scene = ds.scene(sid)
    scene.require_complete("register")
    fingerprint = register_fingerprint(scene, cfg, init)
    done = scene.attrs.get("register") or {}
    if (not force and done.get("fingerprint") == fingerprint and set(REGISTER_OUTPUTS) <= set(scene.arrays())
            and (not cfg.segment_lidar or instance_state(scene) == "current")):
        return {"scene": sid, **{k: v for k, v in done.items() if k not in ("params", "T_init")},
                "skipped": "already done with the same inputs and settings (use --force to recompute)"}
    release_free_memory()      # (before the forks below)
    cam = CameraFrames.open(scene, url)
    LidarScans.open(scene, url)   # checks the LiDAR arrays and poses before any work starts
    T_init = _parse_init(init)
    init_source = "--init"
    if T_init is None:
        world, tf = camera_tf_guess(scene)
        if tf is None:
            raise InputError(f"{url}: scene {sid!r}: no TF pose of the camera in a world frame (sensors.camera."
                             f"T_<world>_sensor); give --init x,y,z,roll,pitch,yaw")
        problem = map_frame_problem(scene, world)
        if problem:
            raise InputError(f"{url}: scene {sid!r}: the camera's TF pose is in {world!r} but {problem}; register "
                             f"cannot start from it: give --init x,y,z,roll,pitch,yaw in the map's frame")
        T_init, init_source = np.asarray(tf, float), "tf"
    names = set(scene.arrays())
    n = scene.n_frames
    processes = register_processes(cfg)
    # 1.-2. the LiDAR half (segmentation, map) and the camera half (depth images, static depth) are
    # independent until the extrinsic: side by side in two processes (the LiDAR one quiet)
    # (lidar/instance made with other poses is made again; one left unfinished is resumed)
    segment = cfg.segment_lidar and instance_state(scene) != "current"
    stored_map = scene_map(scene) if cfg.slam_map else None
    lidar = None
    if segment or stored_map is None:
        lidar = fork_call(lidar_map, url, sid, cfg, segment, quiet or processes > 1, stored_map is None,
                          label=f"{url}: scene {sid!r}: LiDAR map", enabled=processes > 1, early=stored_map is None)
    try:
        t1 = time.perf_counter()
        # the static depth from an evenly spread subset of the frames with points; every frame's depth
        # image is made again in the humans loop (a recording's images never sit in memory together)
        cam_frames = [int(k) for k in np.flatnonzero(cam.counts() > 0)]
        if len(cam_frames) > cfg.median_frames:
            cam_frames = [cam_frames[i] for i in np.linspace(0, len(cam_frames) - 1, cfg.median_frames).round().astype(int)]
        images = {}          # the depth images made for the static depth, used again for the humans
        static = static_depth(cam, cam_frames, quiet, images=images)
        if static is None:
            if stored_map is None:
                lidar.early()
            raise InputError(f"{url}: scene {sid!r}: camera/points is empty in every frame")
        med, mad, cnt = static
        rays = cam.rays()
        okm = np.isfinite(med) & (cnt > 0)
        static_cam = rays[okm] * med[okm][:, None]
        sig_mean = depth_noise_model(med[okm], mad[okm]) / np.sqrt(cnt[okm])
        resid = static_residual(static_cam, cfg)
        timings["camera_s"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        # (the LiDAR process goes on with the segmentation of every scan)
        M = stored_map if stored_map is not None else lidar.early()
        timings["map_wait_s"] = time.perf_counter() - t1
        if len(M) < 100:
            raise InputError(f"{url}: scene {sid!r}: the LiDAR map is empty (no usable scans/poses)")
        # 3. extrinsic
        t1 = time.perf_counter()
        # (onto slam's mesh near the camera where it was built from these poses)
        reg = register_extrinsic(static_cam, M, T_init, cfg, sigma=sig_mean,
                                 mesh=scene_mesh(scene) if cfg.mesh_target else None,
                                 anchor=slam_anchor(scene) if init_source == "tf" else None)
        timings["extrinsic_s"] = time.perf_counter() - t1
        if not reg.accepted:
            a = "; ".join(f"{x['method']}: overlap {x['overlap']} pts, fitness {x['fitness']:.2f}, rmse {x['rmse'] * 100:.1f} cm, "
                          f"pose std {x.get('pose_std_m', float('nan')) * 100:.1f} cm"
                          + (f", the data does not constrain {len(x['held_directions'])} direction(s) "
                             f"({', '.join(x['held_directions'])}): held at the guess, good to "
                             f"{cfg.guess_std_m * 100:.1f} cm (--guess-std)" if x.get("held_directions") else "")
                          + (f", {x['prior_shift_m']:.1f} m / {x['prior_rot_deg']:.0f} deg from the {init_source} guess"
                             if "prior_shift_m" in x else "")
                          for x in reg.attempts)
            raise RegistrationError(f"{url}: scene {sid!r}: camera-to-map registration failed its check ({a}; need "
                                    f">= {cfg.min_overlap_points} pts, fitness >= {cfg.min_fitness}, rmse <= "
                                    f"{cfg.max_rmse_m * 100:.1f} cm, pose std <= {cfg.max_pose_std_m * 100:.1f} cm); "
                                    f"give a better --init (or --guess-std if the guess is that good)")
        T = reg.T
        # 4. humans
        t2 = time.perf_counter()
        from scipy.spatial import cKDTree

        eye = T[:3, 3]
        sigma = np.where(np.isfinite(mad), mad, 0.0)
        # map points the camera sees through (a person the LiDAR map kept) explain nothing away
        carved = camera_seen_through(M, T, cam.K, cam.shape, images.values(),
                                     np.maximum(cfg.fg_min_m, cfg.fg_sigma * depth_noise_model(
                                         np.where(np.isfinite(med), med, 0.0), sigma)))
        mtree = cKDTree(M[~carved])
        # a person standing still is in the temporal background: static points on no large plane and not
        # explained by the map are candidates in every frame
        still = np.zeros(med.shape, bool)
        if resid.any():
            sw_ = transform_points(T, static_cam[resid])
            dmap_ = mtree.query(sw_, k=1, distance_upper_bound=np.nextafter(cfg.map_explain_m, np.inf), workers=-1)[0]
            rr = np.zeros(len(static_cam), bool)
            rr[np.flatnonzero(resid)[dmap_ > cfg.map_explain_m]] = True
            still[okm] = rr
        human_pts, columns, pixels = [], [], []
        w = create_dataset(url, grid=ds.grid, range_bins=ds.range_bins)
        sw = w.scene(sid)
        for name in ("human/vertices", "human/faces", "human/points", "camera/points_world"):
            if name in sw.arrays():
                sw.remove(name)
        cam_world = lambda: None  # noqa: E731
        if cfg.write_camera_world:  # made here, written by a second process while this one finds the humans
            sw.ragged_array("camera/points_world", 3, "float32", "m", ["point", "xyz"])
            cam_world = fork_call(camera_world, url, sid, T, label=f"{url}: scene {sid!r}: camera/points_world",
                                  enabled=processes > 1)
        front = med - np.maximum(cfg.fg_min_m, cfg.fg_sigma * sigma)    # a return nearer than this moved
        always = ~np.isfinite(med) | still
        # the later half of the frames in a second process (numpy and scipy only: it may fork after
        # open3d's OpenMP), once the LiDAR half has had most of the time before the extrinsic
        half = n // 2 if processes > 1 else n
        later = fork_call(frame_candidates, cam, range(half, n), T, rays, front, always, mtree, cfg, images,
                          label=f"{url}: scene {sid!r}: human candidates", enabled=half < n)
        cand = frame_candidates(cam, range(half), T, rays, front, always, mtree, cfg, images, quiet, f"register {sid}")
        cand += later()
        del images
        timings["candidates_s"] = time.perf_counter() - t2
        # the person of interest: person-like clusters near the track's median (people farther away, e.g.
        # walking past in another corridor, are not it)
        f_px = float(cam.K[0, 0])
        first = [pick_human(q[0], cfg, footprint=q[3] / f_px) for q in cand]
        cents = np.array([q[0][m].mean(0) for q, m in zip(cand, first) if m.any()])
        centre = np.median(cents, axis=0) if len(cents) else None
        floor_z = None
        if centre is not None:  # the floor under the person: low percentile of the map's nearby heights
            near = np.linalg.norm(M[:, :2] - centre[:2], axis=1) < 2.5
            if near.sum() > 50:
                floor_z = float(np.percentile(M[near, 2], 2))
        def finish(qw, hm):
            if hm.any():
                # a body is at most ~0.5 m deep along the view and stands on the floor: stereo streaks
                # along the rays and floor returns at the feet go
                rng_ = np.linalg.norm(qw - eye, axis=1)
                mid = np.median(rng_[hm])
                hm &= np.abs(rng_ - mid) <= cfg.max_depth_spread_m
                if floor_z is not None:
                    hm &= qw[:, 2] > floor_z + cfg.floor_margin_m
            return hm

        def near_centre(qw, m0):
            # the largest person-like cluster already lies near the track: it is also the largest near it
            return m0.any() and np.linalg.norm(qw[m0, :2].mean(0) - centre[:2]) <= cfg.track_radius_m

        picks = [finish(qw, m0 if centre is None or near_centre(qw, m0)
                        else pick_human(qw, cfg, centre, footprint=dv / f_px))
                 for (qw, vv, uu, dv), m0 in zip(cand, first)]
        ts = np.asarray(scene["time/timestamp_ns"][...], np.int64)
        cts = np.asarray(scene["camera/timestamp_ns"][...], np.int64) if "camera/timestamp_ns" in names else ts
        # track continuity: a pick far from where its neighbours put the person (a wall fragment while
        # the person is lost in far stereo noise) is picked again near that prediction, or dropped
        cen0 = np.array([c[0][m].mean(0) if m.any() else np.full(3, np.nan) for c, m in zip(cand, picks)])
        t_cam = np.where(cts != 0, cts, ts)
        jumped = track_jumps(cen0, t_cam, cfg.track_jump_m, cfg.walk_speed_mps)
        pred = track_prediction(np.where(jumped[:, None], np.nan, cen0), t_cam)
        jump_cfg = replace(cfg, track_radius_m=2 * cfg.track_jump_m)
        n_repicked = int(jumped.sum())
        for k, ((qw, vv, uu, dv), hm) in enumerate(zip(cand, picks)):
            if jumped[k]:
                hm = (finish(qw, pick_human(qw, jump_cfg, pred[k], footprint=dv / f_px)) if np.isfinite(pred[k]).all()
                      else np.zeros_like(hm))
            human_pts.append(qw[hm].astype(np.float32))
            pixels.append((qw[hm], vv[hm], uu[hm], dv[hm]))
        # velocity compensation: camera stamp -> frame stamp
        cen = np.array([p.mean(0) if len(p) else np.full(3, np.nan) for p in human_pts], float)
        shift = velocity_shift(cen, cts, ts, cfg.max_speed_mps)
        # the solid behind the visible front (deeper behind a person walking along the view: the far leg)
        walk = cfg.walk_back_frac * np.minimum(
            1.0, radial_speed(cen, cts, eye, cfg.max_speed_mps) / cfg.walk_back_speed_mps)
        for k, (qh, vh, uh, dh) in enumerate(pixels):
            back = float(walk[k])
            columns.append(body_columns(qh, vh, uh, dh, eye, cam.K[0, 0], cfg.min_thickness_m, cfg.thickness_m,
                                        cfg.surface_gap_px, floor_z, cfg.floor_reach_m, back))
        del pixels
        timings["picks_s"] = time.perf_counter() - t2 - timings["candidates_s"]
        cam_world()
        # every other frame's surface in a second process
        odd = fork_call(human_surfaces, human_pts[1::2], columns[1::2], shift[1::2], eye, cfg.surface_voxel,
                        label=f"{url}: scene {sid!r}: human surfaces", enabled=processes > 1)
        even = human_surfaces(human_pts[0::2], columns[0::2], shift[0::2], eye, cfg.surface_voxel)
        surfaces = [None] * n
        surfaces[0::2], surfaces[1::2] = even, odd()
        timings["humans_s"] = time.perf_counter() - t2
        # 5. write
        specs = {"human/vertices": (3, "float32", "m", ["vertex", "xyz"], [s[0] for s in surfaces]),
                 "human/faces": (3, "int32", "1", ["face", "corner"], [s[1] for s in surfaces]),
                 "human/points": (3, "float32", "m", ["point", "xyz"], human_pts)}
        for name, (width, dt, units, dims, per_frame) in specs.items():
            r = sw.ragged_array(name, width, dt, units, dims)
            for s in range(r.n_shards):
                sl = r.frames(s)
                r.write_shard(s, per_frame[sl])
        sw.write_array("calib/T_world_camera", T, dims=["row", "col"], units="m",
                       attrs={"frame": "camera points frame (optical for depth images)", "source": "holodata register"})
        t1 = time.perf_counter()
        seg_summary = None
        if lidar is not None:
            _, seg_summary, lidar_timings = lidar()   # the segmentation of every scan (lidar/instance)
            timings.update(lidar_timings)
        timings["segment_wait_s"] = time.perf_counter() - t1
        n_h = int(sum(len(s[1]) > 0 for s in surfaces))
        report = {"extrinsic": reg.to_attrs(), "init": init_source, "T_init": np.asarray(T_init).tolist(),
                  "map": "slam (map/points)" if stored_map is not None else "built from the LiDAR scans",
                  "frames_with_human": n_h, "frames": n, "map_points_seen_through": int(carved.sum()), "frames_repicked": n_repicked, "params": cfg.to_attrs(),
                  "surface": "voxel boundary (half-filled voxels) of elliptic per-run columns behind the "
                             "visible front (closed)",
                  "velocity_shift_m_max": float(np.nanmax(np.linalg.norm(shift, axis=1))) if n else 0.0,
                  "seconds": time.perf_counter() - t0, "timings": timings, "fingerprint": fingerprint}
        sw.set_attrs({"register": report})
        out = {"scene": sid, **{k: v for k, v in report.items() if k not in ("params", "T_init")}}
        if seg_summary:
            out["segment"] = seg_summary
    except BaseException:
        if lidar is not None:
            lidar.join()   # it must not write on after register has failed
        raise
    return out


def track_jumps(centroids: np.ndarray, t_ns: np.ndarray, jump_m: float = 0.6, speed_mps: float = 1.5) -> np.ndarray:
    """(T,) bool: frames whose centroid (``centroids`` (T,3), NaN = none) is farther (plan) from the
    centroid of *each* nearest frame with one, before and after, than ``jump_m`` + ``speed_mps`` ×
    the time between them (``t_ns`` (T,)): a person cannot have walked there."""
    c = np.asarray(centroids, float)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1))
    out = np.zeros(len(c), bool)
    for i, k in enumerate(ok):
        nb = [ok[j] for j in (i - 1, i + 1) if 0 <= j < len(ok)]
        out[k] = bool(nb) and all(np.linalg.norm(c[k, :2] - c[j, :2]) > jump_m + speed_mps * abs(t[k] - t[j]) for j in nb)
    return out


def track_prediction(centroids: np.ndarray, t_ns: np.ndarray, max_gap_s: float = 2.0) -> np.ndarray:
    """(T,3) where each frame's centroid is expected from its neighbours: the nearest frame with a
    centroid on each side (within ``max_gap_s``), linearly interpolated in time (``t_ns`` (T,)), or
    the one side's centroid when only one exists; NaN when none. ``centroids`` (T,3), NaN = none."""
    c = np.asarray(centroids, float)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1))
    out = np.full_like(c, np.nan)
    for k in range(len(c)):
        before = ok[(ok < k) & (t[k] - t[ok] <= max_gap_s)]
        after = ok[(ok > k) & (t[ok] - t[k] <= max_gap_s)]
        a = before[-1] if len(before) else None
        b = after[0] if len(after) else None
        if a is not None and b is not None and t[b] > t[a]:
            out[k] = c[a] + (c[b] - c[a]) * (t[k] - t[a]) / (t[b] - t[a])
        elif a is not None or b is not None:
            out[k] = c[a if a is not None else b]
    return out


def track_velocity(centroids: np.ndarray, cam_ts: np.ndarray, max_speed: float = 2.5) -> np.ndarray:
    """(T,3) plan velocity (m/s, z = 0) of the centroid track ``centroids`` (T,3) (NaN: no detection) by
    central differences over the frames with a detection and a camera stamp ``cam_ts`` (T,) ns (zero
    where it cannot be estimated: a single detection, neighbours more than 2 s apart, or faster than
    ``max_speed``, a wrong detection next door rather than a walking person)."""
    n = len(centroids)
    out = np.zeros((n, 3))
    ok = np.isfinite(centroids).all(1) & (cam_ts != 0)
    idx = np.flatnonzero(ok)
    if len(idx) < 2:
        return out
    t = cam_ts[idx].astype(np.float64) / 1e9
    c = centroids[idx]
    for j, k in enumerate(idx):
        a, b = max(j - 1, 0), min(j + 1, len(idx) - 1)
        if t[b] - t[a] <= 0 or t[b] - t[a] > 2.0:
            continue
        v = (c[b] - c[a]) / (t[b] - t[a])
        v[2] = 0.0
        if np.linalg.norm(v) > max_speed:
            continue
        out[k] = v
    return out


def velocity_shift(centroids: np.ndarray, cam_ts: np.ndarray, frame_ts: np.ndarray, max_speed: float = 2.5) -> np.ndarray:
    """(T,3) shifts = velocity (:func:`track_velocity`) · (frame time − camera time)."""
    v = track_velocity(centroids, cam_ts, max_speed)
    return v * ((np.asarray(frame_ts, np.int64) - np.asarray(cam_ts, np.int64)) / 1e9)[:, None]


def radial_speed(centroids: np.ndarray, cam_ts: np.ndarray, eye: np.ndarray, max_speed: float = 2.5) -> np.ndarray:
    """(T,) m/s: how fast the person walks along the camera's view in each frame — the larger of the
    one-sided plan speeds toward the previous and the next detection (within 2 s, at most ``max_speed``)
    along the plan direction from ``eye`` (3,) to the frame's centroid (``centroids`` (T,3), NaN: no
    detection; ``cam_ts`` (T,) ns, 0: none). One-sided: at a turn the central difference is near zero
    while the legs are still in stride. 0 without a neighbour."""
    c = np.asarray(centroids, float)
    out = np.zeros(len(c))
    idx = np.flatnonzero(np.isfinite(c).all(1) & (np.asarray(cam_ts) != 0))
    t = np.asarray(cam_ts, np.int64)[idx] / 1e9
    for j, k in enumerate(idx):
        u = c[k, :2] - np.asarray(eye, float)[:2]
        nu = np.linalg.norm(u)
        if nu < 1e-9:
            continue
        for m in (j - 1, j + 1):
            if 0 <= m < len(idx) and 0 < abs(t[m] - t[j]) <= 2.0:
                v = (c[idx[m], :2] - c[k, :2]) / (t[m] - t[j])
                if np.linalg.norm(v) <= max_speed:
                    out[k] = max(out[k], abs(float(v @ u)) / nu)
    return out


__all__ = ["RegisterConfig", "Registration", "RegistrationError", "register_extrinsic", "icp", "fpfh_ransac",
           "closed_surface", "voxel_boundary", "cluster_points", "pick_human", "static_depth", "camera_points_world",
           "CameraFrames", "register_scene", "velocity_shift", "map_cloud", "static_residual",
           "body_columns", "pixel_runs",
           "weighted_icp", "depth_noise_model", "map_normals", "pose_uncertainty", "track_prediction",
           "track_jumps", "local_plane_projection", "track_velocity", "radial_speed", "mesh_surface_samples",
           "scene_mesh"]
