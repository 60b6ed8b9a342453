"""The depth camera's extrinsic in the map: point-to-plane Gauss-Newton ICP with directions the
overlap does not pin down held at the guess, the FPFH + RANSAC fallback, the pose's
uncertainty and the acceptance check (:func:`register_extrinsic`), and the open3d helpers. The ICP
solvers, voxel means and plane fits are :mod:`holodata.geometry`'s."""
from __future__ import annotations

import numpy as np

from ...conventions import rotation_angle_deg, transform_points, yaw_rad
from ...geometry.icp import STOP_TRANSLATION_M, IcpParams, centred_offset, hold_at, open3d_icp, point_to_plane_icp
from ...geometry.planes import local_plane_projection
from ...geometry.voxels import voxel_average, voxel_keys
from .camera import UNKNOWN_SIGMA_M
from .config import RegisterConfig, Registration

# every camera point's ICP weight, 1/σ² for σ = 1 cm: the correspondence and Tukey scale is then
# max(stage distance, 3 cm) for every point (holodata.geometry.point_to_plane_icp)
UNIFORM_WEIGHT = 1e4
# per-point depth noise is floored at this for the thinning's "least noisy" choice and the checks
MIN_SIGMA_M = 0.003
# a map turn is read from the camera's position correction only where the turn's lever across the
# held direction is at least this share of the whole lever (else the turn moves it along it)
MIN_LEVER_SHARE = 0.3
# held directions are taken to the guess by at most this many first-order steps (hold_at_guess)
HOLD_STEPS = 5
# FPFH + RANSAC (open3d): normals within 2 voxels, features within 5 (at most 100 neighbours);
# correspondences within 1.5 voxels, edge-length check 0.9; 100000 iterations, confidence 0.999
FPFH_NORMAL_VOXELS, FPFH_FEATURE_VOXELS, FPFH_MAX_NN = 2, 5, 100
RANSAC_DISTANCE_VOXELS, RANSAC_EDGE_LENGTH = 1.5, 0.9
RANSAC_ITERATIONS, RANSAC_CONFIDENCE = 100000, 0.999

# ------------------------------------------------------------------------------------ open3d helpers
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
    """Coarse-to-fine point-to-plane ICP (:func:`holodata.geometry.open3d_icp`, Tukey loss with k = the
    stage's distance / 2) of ``source`` (N,3) onto ``target_pcd`` (with normals) from ``init``; returns
    the (4,4) transform."""
    return open3d_icp(source, target_pcd, init, cfg.icp_distances, 0.5, cfg.icp_iterations)[0]


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
             if abs(lever) >= MIN_LEVER_SHARE * np.linalg.norm(u) else None)   # None: the turn moves it along held_dir only
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
        p = _pcd(pts, voxel, FPFH_NORMAL_VOXELS * voxel)
        f = reg.compute_fpfh_feature(p, o3d.geometry.KDTreeSearchParamHybrid(radius=FPFH_FEATURE_VOXELS * voxel,
                                                                              max_nn=FPFH_MAX_NN))
        feats.append((p, f))
    (ps, fs), (pt, ft) = feats
    res = reg.registration_ransac_based_on_feature_matching(
        ps, pt, fs, ft, True, RANSAC_DISTANCE_VOXELS * voxel, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(RANSAC_EDGE_LENGTH),
         reg.CorrespondenceCheckerBasedOnDistance(RANSAC_DISTANCE_VOXELS * voxel)],
        reg.RANSACConvergenceCriteria(RANSAC_ITERATIONS, RANSAC_CONFIDENCE))
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
    its information matrix (rotations scaled by the median lever arm, as in :func:`~holodata.geometry.point_to_plane_icp`):
    correspondences within ``overlap_m`` whose residual is within max(``inlier_m``, 3 sigma), each
    weighted by 1/(sigma_i^2 + map_sigma_m^2) with ``sigma`` (N,) the camera point's depth noise (m).
    Noisy far points (a low-resolution stereo camera: 5-15 cm at 6-10 m) carry little information;
    a pose they alone pin down is uncertain by centimetres even when its fitness looks good.
    Returns {"std_m": sorted (6,) largest first, "n": correspondences}.

    Fewer than 6 correspondences (a pose that puts the camera cloud nowhere near the map, e.g. a
    global fallback's wrong alignment) determine nothing: every standard deviation is inf, a failed
    check, never an exception."""
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
    if inl.sum() < 6:       # near the map but on none of its surfaces: no inlier to weigh
        return {"std_m": [float("inf")] * 6, "n": int(inl.sum())}
    pp, nn, w = pp[inl], nn[inl], 1.0 / s2[inl]
    c = np.average(pp, axis=0, weights=w)
    Lc = float(np.median(np.linalg.norm(pp - c, axis=1))) or 1.0
    J = np.concatenate([np.cross(pp - c, nn) / Lc, nn], axis=1)
    ev = np.linalg.eigvalsh((J * w[:, None]).T @ J)
    std = 1.0 / np.sqrt(np.maximum(ev, 1e-12))
    return {"std_m": sorted(std.tolist(), reverse=True), "n": int(inl.sum())}


def held_directions(held: tuple) -> list[str]:
    """Plain words for the directions :func:`~holodata.geometry.point_to_plane_icp` held at the guess (``info["held"]``: V (6,k)
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


def camera_held(held: tuple, camera: np.ndarray) -> tuple:
    """The directions :func:`~holodata.geometry.point_to_plane_icp` held (``info["held"]``: V (6,k)
    in step coordinates about the correspondences' centroid c, rotations × lever) as the same motions
    in step coordinates about the camera's position ``camera`` (3,) m: (Q (6,k) orthonormal, camera,
    lever) for :func:`~holodata.geometry.hold_at`. A rotation ω about c is the rotation ω about the
    camera plus the translation ω × (camera - c): holding c where the guess puts it lets a turn the
    data does measure (a TF yaw error) carry the camera along a direction the data does not
    (docs/design/register.md, 3.: held directions)."""
    V, c, lever = held
    V = np.asarray(V, np.float64)
    cam = np.asarray(camera, np.float64)
    om = V[:3] / lever
    Vc = np.concatenate([V[:3], V[3:] + np.cross(om.T, cam - np.asarray(c, np.float64)).T])
    return np.linalg.qr(Vc)[0], cam, lever


def map_turn_reach(held: tuple, camera: np.ndarray, anchor: np.ndarray, max_deg: float) -> np.ndarray:
    """(k,) m: how far a turn of the map by ``max_deg`` about the vertical through ``anchor`` (3,) m
    moves the camera at ``camera`` (3,) m along each of the k held directions (``held``: the ICP's
    ``info["held"]``). A SLAM map anchored at a TF pose is the TF world turned so by the odometry's
    error there (:func:`anchored_guess`); where that turn could not be read, the TF guess's camera
    is off in the map by up to this along a direction nothing measured."""
    Q, cam, lever = camera_held(held, camera)
    d = np.radians(max_deg)
    m = np.concatenate([[0.0, 0.0, d * lever], np.cross([0.0, 0.0, d], cam - np.asarray(anchor, np.float64))])
    return np.abs(Q.T @ m)


def hold_at_guess(T: np.ndarray, guess: np.ndarray, held: tuple | None) -> tuple[np.ndarray, np.ndarray]:
    """``T`` (4,4) moved along the directions the ICP held (``held``: its ``info["held"]`` or None) to
    where the camera pose ``guess`` (4,4) lies along them, read about the guess's camera
    (:func:`camera_held`); and the slide (k,) m: how far the result still lies from the guess along
    each of the k held directions, which the reported uncertainty adds to the guess's: 0 but where
    :func:`~holodata.geometry.hold_at`, a first-order step repeated up to :data:`HOLD_STEPS` times,
    has not come within the ICP's own resolution (:data:`~holodata.geometry.icp.STOP_TRANSLATION_M`)
    of the guess (a fallback pose far from it). Neither a coarse stage's slide nor a measured turn
    about a far centroid moves the camera along a direction nothing measured."""
    if held is None or np.asarray(held[0]).shape[1] == 0:
        return T, np.zeros(0)
    Q, cam, lever = camera_held(held, guess[:3, 3])
    for _ in range(HOLD_STEPS):
        T = hold_at(T, guess, (Q, cam, lever))
        slide = Q.T @ centred_offset(T, guess, cam, lever)
        if np.abs(slide).max() < STOP_TRANSLATION_M:
            break
    return T, slide


def check_held(measured_std_m: float, slide_m: float, cfg: RegisterConfig) -> bool:
    """The pose part of the acceptance check: True when the largest standard deviation along the
    directions the data measured (``measured_std_m``, :func:`pose_uncertainty`) and how far the result
    still lies from the guess along the directions held at it (``slide_m``, :func:`hold_at_guess`)
    are both within ``max_pose_std_m`` (0: no pose check).

    What is physically right for a held direction. The camera's view does not constrain it (a
    corridor seen end-on): every pose along it fits the data alike, so the data can neither confirm
    nor improve the guess there, and the result *is* the guess. Its precision is the guess's
    (``guess_std_m``, ``--guess-std``: what the user has, a TF extrinsic from the recording's
    ``/tf_static`` or a hand-measured ``--init``), which is reported as the direction's uncertainty
    (``uncertainty_m``, with the direction in words) and accepted as stated: judging it against
    ``max_pose_std_m`` (a measurement's precision) refused every held direction under the default
    5 cm guess (benchmarks/results/register_defaults.md), although no registration of that data could
    do better than the guess and a refusal left the scene without a person. A guess known better
    (the synthetic recordings' exact TF) is stated with a smaller ``--guess-std``; the figure never
    changes the result. What is judged is what register itself did: the directions it measured, and
    that it left the held ones at the guess (a slide of the result along them, e.g. a global
    fallback whose pose the hold could not bring back, is a move nothing measured)."""
    if cfg.max_pose_std_m <= 0:
        return True
    return bool(measured_std_m <= cfg.max_pose_std_m and slide_m <= cfg.max_pose_std_m)


def prior_deviation(T: np.ndarray, init: np.ndarray) -> tuple[float, float]:
    """How far a camera pose ``T`` (4,4) lies from the initial guess ``init``: (metres, degrees)."""
    return float(np.linalg.norm(T[:3, 3] - init[:3, 3])), rotation_angle_deg(np.linalg.inv(init) @ T)


def register_extrinsic(static_cam: np.ndarray, map_points: np.ndarray, init: np.ndarray,
                       cfg: RegisterConfig | None = None, allow_fallback: bool = True,
                       sigma: np.ndarray | None = None, mesh: tuple | None = None,
                       anchor: np.ndarray | None = None) -> Registration:
    """``T_world_camera`` from the static camera cloud ``static_cam`` (N,3, camera frame) and the map
    ``map_points`` (M,3, world) from ``init`` (4,4): open3d point-to-plane ICP then, with per-point
    depth noise ``sigma`` (N,) m, a noise-weighted refinement (:func:`~holodata.geometry.point_to_plane_icp`); checked;
    FPFH+RANSAC+ICP fallback, checked. ``mesh`` (vertices (V,3), faces (F,3)): a static mesh of the
    scene in the map's frame (:func:`scene_mesh`) whose surface near the camera cloud joins the
    target (docs/design/register.md, 3.). ``anchor`` (3,) m: ``init`` is a TF pose and the map a SLAM map
    anchored at the TF pose of a scan taken there; directions the ICP holds then go where the map's
    offset puts the guess (:func:`anchored_guess`) instead of staying at it. Never returns an
    unchecked transform: ``accepted`` False means both failed (register then finishes the scene without a
    person). The steps are :class:`_ExtrinsicFit`'s."""
    fit = _ExtrinsicFit(static_cam, map_points, init, cfg or RegisterConfig(), sigma, mesh)
    best = fit.icp_attempt(anchor)
    if not best[2]["accepted"] and allow_fallback:
        best = fit.fallback_attempt(anchor) or best
    m, T, c = best
    return Registration(T, m, c["fitness"], c["rmse"], c["overlap"], c["accepted"], fit.attempts)


class _ExtrinsicFit:
    """:func:`register_extrinsic` as named steps sharing their state: the camera cloud voxel-thinned
    (:meth:`_thinned`), the target (the map denoised near the camera, :meth:`_denoised_map`, with the
    mesh's surface there, :meth:`_mesh_samples`), the camera cloud cropped to what can overlap it
    (:meth:`_crop`); then the ICP (:meth:`icp_attempt`) and the global fallback
    (:meth:`fallback_attempt`), each refined (:meth:`refine`) and checked (:meth:`check`).
    ``attempts`` collects every try's checks (for the report)."""

    def __init__(self, static_cam: np.ndarray, map_points: np.ndarray, init: np.ndarray, cfg: RegisterConfig,
                 sigma: np.ndarray | None, mesh: tuple | None):
        from scipy.spatial import cKDTree

        self.init, self.cfg = init, cfg
        src, sig, src_n = self._thinned(static_cam, sigma)
        mesh_pts, mesh_n = self._mesh_samples(mesh, src)
        tgt_pts, tgt_n = map_normals(self._denoised_map(map_points, src), cfg)
        if mesh_pts is not None:
            # the mesh's surface near the camera cloud joins the (denoised) map (docs/design/register.md, 3.)
            tgt_pts, tgt_n = np.concatenate([mesh_pts, tgt_pts]), np.concatenate([mesh_n, tgt_n])
        self.with_mesh = mesh_pts is not None
        self.tgt_pts, self.tgt_n, self.tgt_tree = tgt_pts, tgt_n, cKDTree(tgt_pts)
        self.full_src, self.full_sig, self.full_n = src, sig, src_n
        self.src, self.src_n = self._crop(src, src_n)
        # against the mesh's smooth surface a weak direction (a T corner's corridor seen end-on) is
        # determined by the data; against the noisy points it was held at the guess
        self.ratio = cfg.mesh_degenerate_ratio if self.with_mesh else cfg.degenerate_ratio
        self.attempts: list = []

    def _thinned(self, static_cam: np.ndarray, sigma: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The camera points within ``max_range_m``, voxel-thinned (one point per ``cam_voxel`` cell, the
        least noisy): (points (N,3), depth noise (N,) m, normals (N,3))."""
        cfg = self.cfg
        src_all = np.asarray(static_cam, np.float64)
        sig = (np.full(len(src_all), UNKNOWN_SIGMA_M) if sigma is None
               else np.maximum(np.asarray(sigma, np.float64), MIN_SIGMA_M))
        keep = np.linalg.norm(src_all, axis=1) <= cfg.max_range_m
        src_all, sig = src_all[keep], sig[keep]
        cell = np.floor(src_all / cfg.cam_voxel).astype(np.int64)
        order = np.argsort(sig, kind="stable")
        _, first = np.unique(voxel_keys(cell[order]), return_index=True)   # (rows sort like their keys)
        sel = order[first]
        src, sig = src_all[sel], sig[sel]
        return src, sig, np.asarray(_pcd(src, None, 3 * cfg.cam_voxel).normals)   # same order (no thinning)

    def _mesh_samples(self, mesh: tuple | None, src: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Samples of the mesh's surface within reach of the camera cloud ``src`` under the guess, and
        their normals; (None, None) without a mesh or with too few samples."""
        cfg = self.cfg
        if mesh is None or not cfg.mesh_target or not len(mesh[1]):
            return None, None
        mesh_pts, mesh_n = mesh_surface_samples(mesh[0], mesh[1], transform_points(self.init, src),
                                                cfg.crop_m + cfg.max_scale_m, cfg.mesh_sample_m)
        if len(mesh_pts) < cfg.min_overlap_points:
            return None, None
        return mesh_pts, mesh_n

    def _denoised_map(self, map_points: np.ndarray, src: np.ndarray) -> np.ndarray:
        """Denoise the target: map points near the camera cloud ``src`` (under the guess) onto their
        local planes (``map_plane_m`` 0: the map as given)."""
        cfg = self.cfg
        if cfg.map_plane_m <= 0:
            return map_points
        mp = voxel_average(map_points, cfg.map_voxel)
        reach = cfg.crop_m + cfg.max_scale_m + cfg.map_plane_m
        near_cam = _nn_distances(mp, transform_points(self.init, src), reach) <= reach
        return local_plane_projection(mp, cfg.map_plane_m, cfg.map_plane_ratio, only=near_cam)

    def _crop(self, src: np.ndarray, src_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Only the part of the camera cloud that can overlap the map matters (the rest was never seen by
        the LiDAR): cropped to within ``crop_m`` of the map under the initial guess (fast, and fewer
        outliers), unless fewer than ``min_overlap_points`` remain."""
        near = _nn_distances(transform_points(self.init, src), self.tgt_pts, self.cfg.crop_m) <= self.cfg.crop_m
        if near.sum() >= self.cfg.min_overlap_points:
            return src[near], src_n[near]
        return src, src_n

    def refine(self, T0: np.ndarray, info: dict) -> np.ndarray:
        """Gauss-Newton point-to-plane with Tukey loss and degeneracy-aware updates of the current source
        from ``T0``. Not open3d's registration_icp: it slides along a corridor the overlap sees end-on,
        and it has no way to hold such directions (docs/design/register.md, 3.). Uniform weights:
        per-point camera noise weights did no better (the map's own error is not modelled)."""
        cfg = self.cfg
        return point_to_plane_icp(self.src, np.full(len(self.src), UNIFORM_WEIGHT), self.tgt_pts, self.tgt_n, T0,
                                  IcpParams(cfg.icp_distances, cfg.icp_iterations, cfg.max_scale_m, self.ratio,
                                            cfg.min_normal_cos, cfg.hold_m), info=info, source_normals=self.src_n)

    def icp_attempt(self, anchor: np.ndarray | None) -> tuple[str, np.ndarray, dict]:
        """The ICP from the guess, its held directions at the (anchored) guess, checked: ("icp", T, check)."""
        cfg, init = self.cfg, self.init
        info: dict = {}
        T = self.refine(init, info)
        anchor_turn, target = None, None
        if anchor is not None and info.get("frozen") and cfg.anchor_max_deg > 0:
            V = info["held"][0]
            target, anchor_turn = anchored_guess(T, init, anchor, V[3:, 0], cfg.anchor_max_deg, cfg.anchor_agree_deg)
            anchor_turn["applied"] = target is not None
        # held directions: at the (anchored) guess, about its camera, all the way
        T, slide = hold_at_guess(T, init if target is None else target, info.get("held") if info.get("frozen") else None)
        turn_reach = None
        if anchor is not None and info.get("frozen") and target is None:
            # the map's turn about its anchor was not read: the TF guess's camera is off in the map by
            # up to anchor_max_deg's reach along the held directions, which nothing measured
            turn_reach = map_turn_reach(info["held"], init[:3, 3], anchor, cfg.anchor_max_deg)
        c = self.check(T, info.get("frozen", 0), info.get("held"), slide, turn_reach)
        self.attempts.append({"method": "icp", **c, "target": "map+mesh" if self.with_mesh else "map",
                              "frozen_directions": info.get("frozen", 0),
                              "eigenvalues_rel": info.get("eigenvalues"), "anchor_turn": anchor_turn})
        return "icp", T, c

    def fallback_attempt(self, anchor: np.ndarray | None) -> tuple[str, np.ndarray, dict] | None:
        """FPFH + RANSAC on the whole camera cloud, refined, held at the guess and checked (and refused
        far from the guess): ("fpfh+icp", T, check) when accepted, else None."""
        cfg, init = self.cfg, self.init
        self.src, self.src_n = self.full_src, self.full_n
        Tg = fpfh_ransac(self.src, self.tgt_pts, cfg.fpfh_voxel)
        info2: dict = {}
        T2 = self.refine(Tg, info2)
        # (the ICP held its directions where RANSAC put them: they go to the guess too)
        T2, slide2 = hold_at_guess(T2, init, info2.get("held") if info2.get("frozen") else None)
        c2 = self.check(T2, info2.get("frozen", 0), info2.get("held"), slide2,
                        map_turn_reach(info2["held"], init[:3, 3], anchor, cfg.anchor_max_deg)
                        if anchor is not None and info2.get("frozen") else None)
        shift, rot = prior_deviation(T2, init)
        c2 = {**c2, "prior_shift_m": shift, "prior_rot_deg": rot}
        if shift > cfg.fallback_max_shift_m or rot > cfg.fallback_max_rot_deg:
            c2["accepted"] = False
        self.attempts.append({"method": "fpfh+icp", **c2, "frozen_directions": info2.get("frozen", 0),
                              "eigenvalues_rel": info2.get("eigenvalues")})
        return ("fpfh+icp", T2, c2) if c2["accepted"] else None

    def check(self, T: np.ndarray, frozen: int = 0, held=None, slide=None, turn_reach=None) -> dict:
        """The acceptance check of pose ``T``: the fit (:meth:`_fit`) and the pose's uncertainty along the
        directions the data measured, with the ``frozen`` directions ``held`` at the guess reported as
        the guess's (:meth:`_pose`)."""
        c = self._fit(T)
        return self._pose(c, T, frozen, held, slide, turn_reach)

    def _fit(self, T: np.ndarray) -> dict:
        """Overlap, fitness and RMSE of the whole camera cloud at ``T``, judged on the precise camera
        points (depth noise <= ``check_sigma_m``) when there are enough: far stereo points are too noisy
        to tell a right from a slightly wrong alignment."""
        cfg, tgt_pts, tgt_n = self.cfg, self.tgt_pts, self.tgt_n
        p = transform_points(T, self.full_src)
        # only points within overlap_m count: the bounded search ends early for the far ones (the
        # camera's view of what the LiDAR never saw), which an unbounded one searched the whole map for
        d, j = self.tgt_tree.query(p, k=1, distance_upper_bound=cfg.overlap_m, workers=-1)
        j = np.minimum(j, len(tgt_pts) - 1)
        r = np.einsum("ij,ij->i", p - tgt_pts[j], tgt_n[j])
        precise = self.full_sig <= cfg.check_sigma_m
        if int((precise & (d < cfg.overlap_m)).sum()) >= cfg.min_overlap_points:
            d, r = d[precise], r[precise]
        return _check_from_distances(d, cfg, r)

    def _pose(self, c: dict, T: np.ndarray, frozen: int, held, slide, turn_reach) -> dict:
        """``c`` with the pose part of the check: the pose must be determined by the data (directions held
        at the guess aside, the estimate's standard deviation along every direction <= ``max_pose_std_m``,
        :func:`check_held`)."""
        cfg = self.cfg
        u = pose_uncertainty(self.full_src, self.full_sig, self.tgt_pts, self.tgt_n, self.tgt_tree, T, cfg)
        std = float(u["std_m"][min(frozen, 5)])
        c["pose_std_m"] = std
        # along the held directions the result is the guess: its uncertainty is the guess's, not a
        # measurement (never a sub-centimetre figure the data did not give), plus however far the
        # result lies from the guess along them (a slide nothing measured adds to the guess's error)
        c["held_directions"] = held_directions(held) if frozen and held is not None else []
        c["held_slide_m"] = [] if slide is None else [round(float(x), 5) for x in slide]
        moved = float(np.abs(slide).max()) if slide is not None and len(slide) else 0.0
        moved = moved if moved >= STOP_TRANSLATION_M else 0.0     # (within the ICP's resolution: none)
        if turn_reach is not None and len(turn_reach):
            # reported as a bound beside the uncertainty, not in it: anchor_max_deg is the largest turn
            # the anchored hold looks for, not a measured one, and counting it refused every demo
            # scene with a held direction far from slam's anchor (docs/design/register.md)
            c["map_turn_reach_m"] = [round(float(x), 5) for x in turn_reach]
        c["uncertainty_m"] = max(std, cfg.guess_std_m + moved) if frozen else std
        # judged: what the data measured (std) and whether the result came back to the guess along the
        # held directions (moved); not the guess's own precision, which the data can neither confirm
        # nor improve: a held direction is accepted at the stated guess_std_m (see check_held)
        if not check_held(std, moved, cfg):
            c["accepted"] = False
        return c
