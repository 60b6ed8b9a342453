"""Point-to-plane ICP: one Gauss-Newton step with robust (Tukey) weights and directions the data does
not pin down held at the guess (:func:`gauss_newton_step`), the iterated solver around it
(:func:`point_to_plane_icp`), the motion algebra it works in, and open3d's coarse-to-fine ICP
(:func:`open3d_icp`).

The point-to-plane residual of a point p against the plane through q with unit normal n is
r = (p - q)·n; a small motion (rotation vector ω about a centre c, translation t of c) changes it by
J·(ω, t) with J = ((p - c) × n, n) (Chen & Medioni 1992; the linearisation of Low 2004). A step
minimises Σ w r² in those coordinates; w is the Tukey biweight of r (Holland & Welsch 1977) times a
per-point weight. Held directions follow the degeneracy-aware update of Zhang, Kaess & Singh (ICRA
2016): the normal matrix, with rotations scaled by a lever arm so both blocks are in metres, is
eigen-decomposed and the update is zeroed along eigenvectors whose eigenvalue is below a fraction of
the largest. No I/O; numpy/scipy (and open3d for :func:`open3d_icp`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..conventions import transform_points

# point_to_plane_icp: a stage has converged when the update moves less than STOP_TRANSLATION_M and
# turns less than STOP_ROTATION_RAD (far below any sensor's noise); fewer than MIN_CORRESPONDENCES
# correspondences cannot pin down 6 degrees of freedom; the plain step's Levenberg damping (× Σw)
# only keeps a rank-deficient system solvable
STOP_TRANSLATION_M = 1e-5
STOP_ROTATION_RAD = 1e-6
MIN_CORRESPONDENCES = 6
PLAIN_DAMPING = 1e-9
# open3d_icp: relative fitness change below which a stage stops
RELATIVE_FITNESS = 1e-7


def tukey_weights(r: np.ndarray, k) -> np.ndarray:
    """(N,) Tukey biweights (1 - (r/k)²)² of residuals ``r`` (N,) with width ``k`` (scalar or (N,)),
    0 where |r| >= k."""
    u = r / k
    return np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)


@dataclass
class Step:
    """One Gauss-Newton update. ``y`` (6,): (rotation vector × ``lever`` (m), translation of ``centre``
    (m)); ``centre`` (3,) m and ``lever`` (m) the coordinates it is in; ``held`` (6,k): the held
    directions (unit eigenvectors in those coordinates; k = 0 when none); ``eigenvalues`` (6,) of the
    normal matrix, ascending, when directions were tested (else None)."""

    y: np.ndarray
    centre: np.ndarray
    lever: float
    held: np.ndarray
    eigenvalues: np.ndarray | None = None

    def motion(self) -> np.ndarray:
        """The update as (rotation vector, translation) about the origin (:func:`about_origin`)."""
        return about_origin(self.y, self.centre, self.lever)


@dataclass(frozen=True)
class StepRule:
    """How :func:`gauss_newton_step` solves. ``hold_ratio`` 0: the plain step -H⁻¹g with ``damping`` × Σw
    added to the diagonal of H, refused (None) when cond(H) > ``max_cond``. ``hold_ratio`` > 0:
    directions (eigenvectors of H) whose eigenvalue is below ``hold_ratio`` × the largest are held: the
    update along them is zero, except that with the step's ``poses`` it takes the pose back to within
    ``hold_m`` (m, in the step's coordinates: :func:`centred_offset`) of the guess along them."""

    damping: float = 0.0
    max_cond: float = np.inf
    hold_ratio: float = 0.0
    hold_m: float = 0.0


def gauss_newton_step(p: np.ndarray, n: np.ndarray, r: np.ndarray, w: np.ndarray, centre: np.ndarray | None = None,
                      lever: float = 1.0, rule: StepRule = StepRule(), poses: tuple | None = None) -> Step | None:
    """One weighted point-to-plane Gauss-Newton step for points ``p`` (M,3) with residuals ``r`` (M,)
    against planes of unit normals ``n`` (M,3), weights ``w`` (M,) (robust × per point), solved as
    ``rule`` says (:class:`StepRule`: plain and damped, or with held directions).

    The rotation is about ``centre`` (3,) with rotation vectors scaled by ``lever`` (m); ``centre``
    None: the weighted centroid of ``p`` and ``lever`` its median distance from it (1 when 0).
    ``poses`` = (current pose, guess) (4,4 each): where held directions are held (the guess)."""
    if centre is None:
        centre = np.average(p, axis=0, weights=np.maximum(w, 1e-12))
        lever = float(np.median(np.linalg.norm(p - centre, axis=1))) or 1.0
    J = np.concatenate([np.cross(p - centre, n) / lever, n], axis=1)      # d r / d (omega * lever, t)
    Jw = J * w[:, None]
    H = Jw.T @ J
    g = Jw.T @ r
    if rule.hold_ratio <= 0:
        if rule.damping:
            H = H + rule.damping * np.eye(6) * w.sum()
        if np.isfinite(rule.max_cond) and np.linalg.cond(H) > rule.max_cond:
            return None
        return Step(-np.linalg.solve(H, g), centre, lever, np.zeros((6, 0)))
    ev, V = np.linalg.eigh(H)
    keep = ev >= rule.hold_ratio * ev.max()
    y = -(V[:, keep] @ ((V[:, keep].T @ g) / ev[keep]))
    if not keep.all() and poses is not None:
        # held directions stay within hold_m of the guess: an earlier (coarser) stage may have moved
        # along them, rightly (edges within its reach) or not (wrong correspondences)
        dev = V[:, ~keep].T @ centred_offset(poses[0], poses[1], centre, lever)
        y -= V[:, ~keep] @ (np.sign(dev) * np.maximum(np.abs(dev) - rule.hold_m, 0.0))
    return Step(y, centre, lever, V[:, ~keep], ev)


@dataclass(frozen=True)
class IcpParams:
    """Settings of :func:`point_to_plane_icp`. ``distances`` (m): the stages' correspondence distances,
    coarse to fine, at most ``iterations`` steps each; ``max_scale`` (m): the largest correspondence
    scale a noisy point gets; ``degenerate_ratio`` > 0: directions the overlap does not pin down are
    held at the initial guess to within ``hold_m`` (m) (:class:`StepRule`'s ``hold_ratio``; 0: the
    plain step); ``min_normal_cos``: correspondences whose normals disagree more (|cos| below it) are
    dropped when the source has normals."""

    distances: tuple = (0.08, 0.04)
    iterations: int = 15
    max_scale: float = 0.25
    degenerate_ratio: float = 0.0
    min_normal_cos: float = 0.8
    hold_m: float = 0.05


def point_to_plane_icp(source: np.ndarray, weights: np.ndarray, target: np.ndarray, target_normals: np.ndarray,
                       init: np.ndarray, params: IcpParams = IcpParams(), info: dict | None = None,
                       source_normals: np.ndarray | None = None) -> np.ndarray:
    """Weighted point-to-plane ICP (iterated :func:`gauss_newton_step`): ``source`` (N,3) with ``weights``
    (N,) (1/σ², m⁻²), ``target`` (M,3) with unit ``target_normals``, from ``init`` (4,4); returns T (4,4).

    Per stage distance d of ``params.distances`` (coarse to fine, at most ``params.iterations`` steps
    each): a nearest-neighbour correspondence within ``max(d, 3σ)`` (at most ``params.max_scale``;
    σ = 1/sqrt(weight): noisy far points keep their unbiased residuals instead of being truncated), kept
    when its point-to-plane residual is within that scale, Tukey-weighted with the same scale
    (:func:`_correspondences`). ``source_normals`` (N,3): correspondences whose normals disagree (|cos| <
    ``params.min_normal_cos``) are dropped — near an edge the nearest map point can belong to the other
    wall. ``params.degenerate_ratio`` > 0: directions the overlap does not pin down
    (:func:`gauss_newton_step`'s ``hold_ratio``, rotations about the correspondences' centroid scaled by
    their median distance from it) keep the initial guess to within ``params.hold_m`` (a corridor seen
    end-on). ``info`` receives the number of held directions (``frozen``), the eigenvalues relative to
    the largest and ``held`` = (V (6,k), centre, lever) for :func:`hold_at`. A stage ends when the
    update is below 10 µm and 1 µrad (:data:`STOP_TRANSLATION_M`, :data:`STOP_ROTATION_RAD`); fewer
    than :data:`MIN_CORRESPONDENCES` (6) correspondences end the solve."""
    from scipy.spatial import cKDTree

    tree = cKDTree(target)
    T0 = np.asarray(init, np.float64)
    T = T0.copy()
    src = np.asarray(source, np.float64)
    w0 = np.asarray(weights, np.float64)
    sig = 1.0 / np.sqrt(w0)
    held = StepRule(hold_ratio=params.degenerate_ratio, hold_m=params.hold_m)
    for d in params.distances:
        scale = np.clip(3 * sig, d, params.max_scale)
        for _ in range(params.iterations):
            c = _correspondences(transform_points(T, src), tree, (target, target_normals), scale,
                                 None if source_normals is None else (source_normals @ T[:3, :3].T, params.min_normal_cos))
            if c is None:
                return T
            pp, nn, r, ok = c
            w = w0[ok] * tukey_weights(r, scale[ok])
            if params.degenerate_ratio > 0:
                step = gauss_newton_step(pp, nn, r, w, None, rule=held, poses=(T, T0))
                x = step.motion()
                if info is not None:
                    ev = step.eigenvalues
                    info.update(frozen=int(step.held.shape[1]), eigenvalues=(ev / ev.max()).round(4).tolist(),
                                held=(step.held, step.centre, step.lever))
            else:
                x = gauss_newton_step(pp, nn, r, w, np.zeros(3), rule=StepRule(damping=PLAIN_DAMPING)).y
            T = moved_by(T, x)
            if np.linalg.norm(x[3:]) < STOP_TRANSLATION_M and np.linalg.norm(x[:3]) < STOP_ROTATION_RAD:
                break
    return T


def _correspondences(p: np.ndarray, tree, target: tuple, scale: np.ndarray, normals: tuple | None):
    """Point-to-plane correspondences of the moved source points ``p`` (N,3) in ``target`` = (points,
    unit normals) (``tree`` a k-d tree over its points): the nearest target point within the point's
    ``scale`` (N,) whose plane is within it too and, with ``normals`` = (the source normals moved (N,3),
    min |cos|), whose normal agrees. (points, their target normals, residuals, which source points) or
    None when fewer than :data:`MIN_CORRESPONDENCES`."""
    pts, tn = target
    dist, j = tree.query(p, k=1, distance_upper_bound=float(scale.max()), workers=-1)
    ok = np.isfinite(dist) & (dist <= scale)
    jj = np.where(ok, j, 0)
    r_all = np.einsum("ij,ij->i", p - pts[jj], tn[jj])
    ok &= np.abs(r_all) <= scale     # gated on the distance to the map's surface, not to its points
    if normals is not None:
        cosn = np.abs(np.einsum("ij,ij->i", normals[0], tn[jj]))
        ok &= cosn >= normals[1]
    if ok.sum() < MIN_CORRESPONDENCES:
        return None
    return p[ok], tn[j[ok]], r_all[ok], ok


def centred_offset(T: np.ndarray, T0: np.ndarray, c: np.ndarray, lever: float) -> np.ndarray:
    """(6,) the motion from pose ``T0`` to ``T`` (4,4; ``T = D @ T0``) in step coordinates: rotation
    vector × ``lever`` (m), then the translation of the point ``c`` (3,) (m)."""
    from scipy.spatial.transform import Rotation

    D = T @ np.linalg.inv(T0)
    om = Rotation.from_matrix(D[:3, :3]).as_rotvec()
    return np.concatenate([om * lever, D[:3, :3] @ c + D[:3, 3] - c])


def about_origin(y: np.ndarray, c: np.ndarray, lever: float) -> np.ndarray:
    """A motion (6,) in step coordinates (rotation vector × ``lever``, motion of the centre ``c``) as
    (rotation vector, translation) about the origin: t = t_c - ω × c."""
    om = y[:3] / lever
    return np.concatenate([om, y[3:] - np.cross(om, c)])


def moved_by(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``D @ T`` with D the motion (6,) ``x`` = (rotation vector, translation), about the origin."""
    from scipy.spatial.transform import Rotation

    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
    D[:3, 3] = x[3:]
    return D @ T


def hold_at(T: np.ndarray, target: np.ndarray, held: tuple) -> np.ndarray:
    """``T`` (4,4) moved along the directions :func:`point_to_plane_icp` held (``info["held"]``: (V (6,k),
    centre c (3,), lever) in step coordinates) to where ``target`` (4,4) lies along them; the other
    directions keep ``T``'s values (to first order)."""
    V, c, lever = held
    return moved_by(T, about_origin(-V @ (V.T @ centred_offset(T, target, c, lever)), c, lever))


def open3d_icp(points: np.ndarray, target, init: np.ndarray, distances, tukey_k: float, iterations: int,
               relative_rmse: float = 1e-7, min_correspondences: int = 0) -> tuple[np.ndarray, float, float]:
    """Coarse-to-fine point-to-plane ICP of ``points`` (N,3) onto ``target`` (an open3d cloud with
    normals) by open3d's ``registration_icp``, from ``init`` (4,4): per distance d of ``distances``
    (m) a Tukey loss of width ``tukey_k`` × d, at most ``iterations`` iterations, relative fitness
    1e-7 and ``relative_rmse``; a stage's result is taken when it has at least ``min_correspondences``.
    Returns (T (4,4), fitness, inlier rmse (m)) of the last stage."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    T = np.asarray(init, np.float64).copy()
    res = None
    for d in distances:
        est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=float(d * tukey_k)))
        res = reg.registration_icp(src, target, float(d), T, est,
                                   reg.ICPConvergenceCriteria(RELATIVE_FITNESS, float(relative_rmse), int(iterations)))
        if len(res.correspondence_set) >= min_correspondences:
            T = np.asarray(res.transformation)
    return T, float(res.fitness), float(res.inlier_rmse)
