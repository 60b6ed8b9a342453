"""Scan-to-map point-to-plane ICP (open3d targets, a Gauss-Newton step) refining the odometry
(:func:`refine`, :func:`global_refine`), with the vertical taken from level seeds where given."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...conventions import rotation_angle_deg, transform_directions, transform_points
from ...geometry.icp import StepRule, gauss_newton_step, open3d_icp, tukey_weights
from ...geometry.voxels import first_per_voxel, voxel_index, voxel_keys
from ...progress import track
from .config import Scans, SlamConfig
from .odometry import _Fixed, advance, deskew, twist
from .points import _o3d_cloud, downsample, scan_normals

# the refinement's map crop reaches this far beyond the LiDAR's range around the scan's guess (the
# guess is within a scan's motion of the pose)
TARGET_MARGIN_M = 1.0
# the rest check's Gauss-Newton step is refused (no rest decision) above this condition number: a
# scan that sees too few plane orientations to pin down every direction
MAX_REST_COND = 1e8
# open3d ICP: stages stop on a relative RMSE change below max(icp_converged_m, this) (open3d's own
# floor for the relative criteria), and a stage with fewer correspondences leaves the pose
MIN_RELATIVE_RMSE = 1e-7
MIN_CORRESPONDENCES = 30


class VoxelMap:
    """Point-to-plane target map: one point (+ normal) per ``voxel``, first come first kept."""

    def __init__(self, voxel: float):
        self.voxel = voxel
        self.keys = np.zeros(0, np.int64)
        self.points = np.zeros((0, 3))
        self.normals = np.zeros((0, 3))

    def _k(self, p):
        return voxel_keys(voxel_index(p, self.voxel))

    def add(self, points: np.ndarray, normals: np.ndarray) -> None:
        k = self._k(points)
        k, idx = np.unique(k, return_index=True)
        new = ~np.isin(k, self.keys, assume_unique=True)
        if not new.any():
            return
        idx = idx[new]
        self.keys = np.concatenate([self.keys, k[new]])
        self.points = np.concatenate([self.points, points[idx]])
        self.normals = np.concatenate([self.normals, normals[idx]])
        o = np.argsort(self.keys)
        self.keys, self.points, self.normals = self.keys[o], self.points[o], self.normals[o]

    def crop(self, center: np.ndarray, radius: float):
        m = np.einsum("ij,ij->i", self.points - center, self.points - center) <= radius * radius
        return self.points[m], self.normals[m]


class _TargetCache:
    """The refinement map cropped around a position (``radius``), as an open3d cloud (ICP target) and a
    scipy KD-tree (rest check), rebuilt only when the map grew or the position moved > 1 m."""

    def __init__(self, radius: float):
        self.radius = radius
        self.key = None
        self.pts = self.nrm = None
        self._cloud = self._tree = None

    def _crop(self, vmap: VoxelMap, center: np.ndarray) -> None:
        if self.key is not None and self.key[0] == len(vmap.points) and np.linalg.norm(center - self.key[1]) < 1.0:
            return
        self.pts, self.nrm = vmap.crop(center, self.radius)
        self.key = (len(vmap.points), np.array(center, np.float64))
        self._cloud = self._tree = None

    def cloud(self, vmap: VoxelMap, center: np.ndarray):
        self._crop(vmap, center)
        if self._cloud is None:
            self._cloud = _o3d_cloud(self.pts, self.nrm)
        return self._cloud

    def tree(self, vmap: VoxelMap, center: np.ndarray):
        from scipy.spatial import cKDTree

        self._crop(vmap, center)
        if self._tree is None:
            self._tree = cKDTree(self.pts)
        return self._tree, self.pts, self.nrm


def _at_rest(src: np.ndarray, target, T: np.ndarray, cfg: SlamConfig) -> bool:
    """One point-to-plane Gauss-Newton step (Tukey weights, correspondences within the finest ICP
    distance) of ``src`` (sensor frame) at pose ``T`` against ``target`` (tree, points, normals): True
    when the step is below ``still_check_m`` and ``still_check_deg`` and enough points correspond."""
    tree, tp, tn = target
    d = float(min(cfg.icp_distances))
    p = transform_points(T, src)
    dist, j = tree.query(p, k=1, distance_upper_bound=d)  # single thread: a few thousand points
    ok = np.isfinite(dist)
    if ok.mean() < cfg.min_fitness or ok.sum() < 30:
        return False
    dx = _gn_step(p[ok], tp[j[ok]], tn[j[ok]], T[:3, 3], d * cfg.tukey_k)
    return dx is not None and _small(dx, cfg.still_check_m, cfg.still_check_deg)


def _gn_step(p: np.ndarray, q: np.ndarray, n: np.ndarray, centre: np.ndarray, k: float) -> np.ndarray | None:
    """One point-to-plane Gauss-Newton step (6,) [rotation vector (rad), translation (m)] moving points
    ``p`` (M,3) onto the planes through ``q`` (M,3) with unit normals ``n`` (M,3), rotation about
    ``centre`` (3,) (the sensor: the translation is its shift), Tukey weights of width ``k`` (m)
    (:func:`holodata.geometry.gauss_newton_step`). None when the system is ill-conditioned (cond >
    :data:`MAX_REST_COND`)."""
    r = np.einsum("ij,ij->i", p - q, n)
    step = gauss_newton_step(p, n, r, tukey_weights(r, k), centre, rule=StepRule(max_cond=MAX_REST_COND))
    return None if step is None else step.y


def _small(dx: np.ndarray, m: float, deg: float) -> bool:
    return bool(np.linalg.norm(dx[3:]) < m and np.degrees(np.linalg.norm(dx[:3])) < deg)


class _SameBeam:
    """The map rest check (:func:`_at_rest`) with its correspondences cached per beam (organised scans,
    :attr:`Scans.pixels`).

    Built from a scan ``a`` (``points`` (N,3) sensor frame, their flat ``pixels`` (N,) of ``n_pixels``)
    that passed the map check (``target``: tree, points, normals) at the held pose ``T``; ``max_points``,
    ``scale`` and ``min_share`` are ``cfg``'s ``same_beam_points``, ``same_beam_scale`` and
    ``same_beam_share``. For at most ``max_points`` of its returns (evenly spread in row-major order) the map point nearest to the
    return (within the finest ICP distance) and its normal, in the sensor frame at ``T``, are kept per
    pixel. While the robot stands, a pixel keeps seeing the same surface, so a later scan ``i`` needs
    no nearest-neighbour search and no downsampling: its return in the same pixel goes with that
    pixel's map plane, and one point-to-plane Gauss-Newton step (Tukey width as in the map check) is
    its motion from ``T``. Scan ``i`` is at rest when that step is below ``scale`` ×
    ``still_check_m`` / ``still_check_deg`` (the map check's bounds by default), at least
    ``min_fitness`` of the cached pixels have a return in scan ``i`` and at least ``min_share`` of
    those returns lie within half the finest ICP distance of their plane; anything else goes to the
    map check. The share guards against a motion beyond the Tukey width: along a corridor only the
    walls facing the motion see it, their residuals drop out of the kernel and the step alone would
    look small (the map check relies on the previous scans not having moved for that). At rest
    nearly every return lies that close, so ``min_share`` 0.9 sends any motion seen by a tenth of
    the beams to the map check (``docs/design/slam.md``: how many scans it decides, and how well)."""

    def __init__(self, points: np.ndarray, pixels: np.ndarray, target, T: np.ndarray, cfg: SlamConfig,
                 n_pixels: int):
        tree, tp, tn = target
        max_points, scale, min_share = cfg.same_beam_points, cfg.same_beam_scale, cfg.same_beam_share
        self.d = float(min(cfg.icp_distances))
        self.k = self.d * cfg.tukey_k
        self.min_share, self.min_fitness = min_share, cfg.min_fitness
        self.m, self.deg = scale * cfg.still_check_m, scale * cfg.still_check_deg
        pick = np.unique(np.linspace(0, len(points) - 1, min(len(points), max_points)).round().astype(np.int64))
        dist, j = tree.query(transform_points(T, points[pick]), k=1, distance_upper_bound=self.d)
        ok = np.isfinite(dist)
        j = j[ok]
        R, t = T[:3, :3], T[:3, 3]
        self.q = (tp[j] - t) @ R                 # the map point and normal found for the beam, sensor frame
        self.n = tn[j] @ R
        self.pix = pixels[pick[ok]]
        self.slot = np.full(n_pixels, -1, np.int32)   # scratch: pixel -> row of the scan under test

    def __len__(self) -> int:
        return len(self.q)

    def at_rest(self, points: np.ndarray, pixels: np.ndarray, keep: np.ndarray) -> bool:
        """Scan ``points`` (N,3) sensor frame, their ``pixels`` (N,), ``keep`` (N,) in the range limits."""
        if len(self.q) < 30:
            return False
        self.slot[pixels[keep]] = np.flatnonzero(keep)
        row = self.slot[self.pix]
        self.slot[pixels[keep]] = -1
        has = row >= 0
        if has.sum() < max(30, self.min_fitness * len(self.q)):
            return False
        p = np.asarray(points[row[has]], np.float64)
        q, n = self.q[has], self.n[has]
        near = np.abs(np.einsum("ij,ij->i", p - q, n)) < 0.5 * self.d
        if near.sum() < self.min_share * len(p):
            return False
        dx = _gn_step(p, q, n, np.zeros(3), self.k)
        return dx is not None and _small(dx, self.m, self.deg)


def icp(src_pts: np.ndarray, target, init: np.ndarray, cfg: SlamConfig, distances=None):
    """Coarse-to-fine point-to-plane ICP of ``src_pts`` (sensor frame) onto ``target`` (open3d
    cloud with normals) (:func:`holodata.geometry.open3d_icp`: Tukey width ``tukey_k`` × the stage's
    distance; a stage with fewer than :data:`MIN_CORRESPONDENCES` correspondences leaves the pose). Returns (T, fitness, inlier
    rmse) of the finest stage."""
    return open3d_icp(src_pts, target, init, distances or cfg.icp_distances, cfg.tukey_k, cfg.icp_iterations,
                      relative_rmse=max(cfg.icp_converged_m, MIN_RELATIVE_RMSE), min_correspondences=MIN_CORRESPONDENCES)


@dataclass
class RefineOptions:
    """How :func:`refine` starts and what it holds to, besides the scans and their initial poses:
    ``T0`` the pose of the first scan (None: the initial poses'); ``ready(i)``: called before scan i
    is used (scans still being read, :func:`stream_scans`); ``vmap``: start from this map (world
    frame) instead of an empty one, and with ``grow_map`` False never add the scans to it
    (localisation against a fixed map); ``vertical``: (S,4,4) world poses of a ground robot's level
    odometry (:func:`level_seeds`) whose height, roll and pitch the refined poses take
    (:func:`with_vertical_of`); level seeds give them when None."""

    T0: np.ndarray | None = None
    ready: Callable[[int], object] | None = None
    vmap: VoxelMap | None = None
    grow_map: bool = True
    vertical: np.ndarray | None = None


def refine(scans: Scans, init, cfg: SlamConfig, max_range: float, quiet: bool = True,
           options: RefineOptions | None = None) -> tuple[np.ndarray, dict]:
    """Scan-to-map refinement (see module doc) of initial poses ``init``: (S,4,4) at the scan stamps,
    or a :class:`KissStream` asked for a scan's kiss-icp pose only when the robot is not at rest (its
    relative motion seeds the ICP; scans at rest are never fed to it); ``options``
    (:class:`RefineOptions`): the first pose, the map to start from, the vertical to hold to. Returns
    the refined (S,4,4) poses and health figures (fitness, rmse per scan). The steps are
    :class:`_Refiner`'s."""
    return _Refiner(scans, init, cfg, max_range, options or RefineOptions()).run(quiet)


class _Refiner:
    """:func:`refine` as named steps sharing their state, scan by scan (:meth:`step`): the rest check
    (:meth:`at_rest`: beam by beam, :class:`_SameBeam`, else against the map, :meth:`_map_rest`); a scan
    at rest holds the last refined pose (:meth:`hold`); any other is deskewed (:meth:`source`),
    registered to the map (:meth:`register`) and, when it moved far enough, added to it
    (:meth:`grow`).

    Each scan is registered at the middle of its sweep (``mid[i]``, deskewed to tc s after the stamp),
    where an error of the deskew twist distorts it symmetrically and biases the pose least;
    ``poses[i]`` at the stamp follows through the twist (docs/design/slam.md: yaw drift on a 10 Hz
    sparse LiDAR)."""

    def __init__(self, scans: Scans, init, cfg: SlamConfig, max_range: float, options: RefineOptions):
        S = len(scans)
        self.scans, self.cfg, self.max_range = scans, cfg, max_range
        self.ready, self.grow_map = options.ready, options.grow_map
        self.t_s = (scans.stamp_ns - scans.stamp_ns[0]).astype(np.float64) * 1e-9
        self._seeds(init, options.T0, options.vertical)
        self.init = self.stream.poses
        self.poses = np.zeros((S, 4, 4))
        self.poses[0] = self.stream.pose(0)
        if options.T0 is not None:
            self.poses[0] = options.T0
        self.use_t = cfg.deskew and scans.times is not None
        self.vmap = options.vmap if options.vmap is not None else VoxelMap(cfg.map_voxel)
        self.fit, self.rmse, self.mid = np.zeros(S), np.zeros(S), np.zeros((S, 4, 4))
        self.xi_prev = np.zeros(6)
        self.fallbacks, self.keyframes, self.still, self.anchor = 0, 0, 0, 0
        self.last_key = None
        self.beams = cfg.same_beam and scans.pixels is not None and scans.grid is not None
        self.n_pix = int(np.prod(scans.grid)) if self.beams else 0
        self.same, self.same_beam = None, 0   # _SameBeam reference of the current anchor pose, scans it found at rest
        self.target = _TargetCache(max_range + TARGET_MARGIN_M)

    def _seeds(self, init, T0: np.ndarray | None, vertical: np.ndarray | None) -> None:
        """The initial poses as a stream; odometry seeds (_Fixed(seed=True)) deskew with their motion about
        each scan, not the last step's; planar seeds (wheel odometry on a level floor): height, roll and
        pitch follow them, not the ICP."""
        stream = _Fixed(np.asarray(init, np.float64)) if isinstance(init, np.ndarray) else init
        self.seed_twist = twists_central(stream.poses, self.scans.stamp_ns) if getattr(stream, "seed", False) else None
        self.vertical_from = "tf" if vertical is not None else None
        if vertical is None and self.seed_twist is not None and level_seeds(stream.poses):
            vertical = (stream.poses[0] if T0 is None else T0) @ np.linalg.inv(stream.poses[0]) @ stream.poses
            self.vertical_from = "seeds"
        self.stream, self.vertical = stream, vertical

    def run(self, quiet: bool) -> tuple[np.ndarray, dict]:
        S = len(self.scans)
        for i in track(range(S), total=S, description="slam: refine (scan-to-map)", quiet=quiet):
            if self.ready is not None:
                self.ready(i)
            self.step(i)
        return self.poses, self.health()

    def in_range(self, p: np.ndarray) -> np.ndarray:
        """(N,) bool: returns within [min_range, max_range] of the sensor."""
        r2 = np.einsum("ij,ij->i", p, p)
        return (r2 >= self.cfg.min_range ** 2) & (r2 <= self.max_range ** 2)

    def ranged(self, p, t):
        p = np.asarray(p, np.float64)
        keep = self.in_range(p)
        return p[keep], (t[keep] if t is not None else None)

    def step(self, i: int) -> None:
        xi = self.xi_prev if i > 0 else np.zeros(6)
        if self.seed_twist is not None:
            xi = self.seed_twist[i]
        at_rest = self.at_rest(i)
        if not at_rest:
            pts, tm, src, tc = self.source(i, xi)
        if i == 0:
            T = Tc = self.poses[0]     # (no twist yet: the middle is the stamp's pose)
            f, e = 1.0, 0.0
        elif at_rest:
            T, Tc, f, e, xi = self.hold(i)
        else:
            T, Tc, f, e, xi = self.register(i, src, xi, tc)
        self.poses[i], self.mid[i] = T, Tc
        self.fit[i], self.rmse[i] = f, e
        self.xi_prev = xi
        if (self.grow_map and not at_rest
                and (self.last_key is None or _moved(self.last_key, T, self.cfg.map_keyframe_m, self.cfg.map_keyframe_deg))):
            self.grow(pts, tm, xi, Tc, T)

    def at_rest(self, i: int) -> bool:
        """Whether scan ``i`` is at rest: the last step was small (and, with given initial poses, they
        moved less than ``still_m`` since the anchor), and the scan passes the rest check beam by beam
        against the last scan that passed the map check at this pose (:class:`_SameBeam`) or against the
        map (:meth:`_map_rest`)."""
        poses, cfg, scans = self.poses, self.cfg, self.scans
        if not (i > 0 and not _moved(poses[i - 2] if i > 1 else poses[0], poses[i - 1], cfg.still_m * 5, cfg.still_deg * 5)
                and (not isinstance(self.stream, _Fixed)
                     or not _moved(self.init[self.anchor], self.init[i], cfg.still_m, cfg.still_deg))):
            return False
        at_rest = False
        pix = scans.pixels[i] if self.beams else None
        if self.same is not None and pix is not None:
            at_rest = self.same.at_rest(scans.points[i], pix, self.in_range(scans.points[i]))
            self.same_beam += at_rest
        if not at_rest:
            at_rest = self._map_rest(i, pix)
        return at_rest

    def _map_rest(self, i: int, pix: np.ndarray | None) -> bool:
        """The rest check on the ICP source voxels (no deskew: the robot was at rest or nearly) against the
        map at the anchor pose; a scan that passes it becomes the beam-by-beam reference."""
        cfg, scans, T = self.cfg, self.scans, self.poses[self.anchor]
        rest, _ = self.ranged(scans.points[i][first_per_voxel(scans.points[i], cfg.source_voxel)], None)
        tgt_tree = self.target.tree(self.vmap, T[:3, 3])
        at_rest = _at_rest(rest, tgt_tree, T, cfg)
        if at_rest and pix is not None:
            p = np.asarray(scans.points[i], np.float64)
            keep = self.in_range(p)
            self.same = _SameBeam(p[keep], pix[keep], tgt_tree, T, cfg, self.n_pix)
        return at_rest

    def source(self, i: int, xi: np.ndarray):
        """Scan ``i``'s returns in range and their times relative to the middle of the sweep ``tc`` (s after
        the stamp), and the ICP source: only the downsampled points that are used are deskewed (ICP
        source, map keyframe). Returns (points, times, source, tc)."""
        cfg = self.cfg
        raw_t = self.scans.times[i] if self.use_t else None
        pts, tm = self.ranged(self.scans.points[i], raw_t)
        i_src = first_per_voxel(pts, cfg.source_voxel)
        tc = 0.5 * float(tm.min() + tm.max()) if self.use_t and len(tm) else 0.0
        if self.use_t:
            tm = tm - tc
        src = deskew(pts[i_src], tm[i_src], xi) if self.use_t else pts[i_src]
        return pts, tm, src, tc

    def hold(self, i: int):
        """At rest: the last step was small, one point-to-plane Gauss-Newton step of this scan from the
        last refined pose against the map is below still_check_m / still_check_deg (and, with given
        initial poses, they moved less than still_m since) -> hold that pose; no ICP, no kiss-icp.
        Returns (T, Tc, fitness, rmse, twist)."""
        self.stream.hold(i)
        a = self.anchor
        T, f, e = self.poses[a].copy(), float(self.fit[a]), float(self.rmse[a])
        self.still += 1
        return T, T, f, e, np.zeros(6)

    def register(self, i: int, src: np.ndarray, xi: np.ndarray, tc: float):
        """Scan ``i``'s ICP ``src`` onto the map from the previous pose moved by the initial poses' motion,
        at the middle of the sweep (``tc``, twist ``xi``); kiss-icp's guess where too few scan points lie
        near the map (sparse, far, outdoor). Returns (T at the stamp, Tc at the middle, fitness, rmse,
        the twist between the middles of the two sweeps)."""
        poses, cfg = self.poses, self.cfg
        guess = poses[i - 1] @ (np.linalg.inv(self.init[i - 1]) @ self.stream.pose(i))
        tgt = self.target.cloud(self.vmap, guess[:3, 3])
        guess = guess @ advance(xi, tc)     # the guess at the middle of the sweep
        Tc, f, e = icp(src, tgt, guess, cfg)
        if f < cfg.min_fitness:  # too few scan points near the map (sparse, far, outdoor): trust kiss-icp
            Tc = guess
            self.fallbacks += 1
        if self.vertical is not None:
            Tc = with_vertical_of(Tc, self.vertical[i])
        if self.seed_twist is None:   # the motion between the middles of the two sweeps
            xi = twist(self.mid[i - 1], Tc, self.t_s[i] - self.t_s[i - 1])
        T = Tc @ advance(xi, -tc)
        if self.vertical is not None:
            T = with_vertical_of(T, self.vertical[i])
        self.anchor = i
        self.same = None
        return T, Tc, f, e, xi

    def grow(self, pts: np.ndarray, tm, xi: np.ndarray, Tc: np.ndarray, T: np.ndarray) -> None:
        """A keyframe: the scan's map voxels (deskewed, with normals) added to the map at ``Tc``."""
        cfg = self.cfg
        i_map = first_per_voxel(pts, cfg.map_voxel)
        dp, dn = scan_normals(deskew(pts[i_map], tm[i_map], xi) if self.use_t else pts[i_map], cfg.scan_normal_radius,
                              cfg.scan_normal_nn)
        self.vmap.add(transform_points(Tc, dp), transform_directions(Tc, dn))
        self.last_key = T
        self.keyframes += 1

    def health(self) -> dict:
        return {"fitness": self.fit, "rmse": self.rmse, "map_points": int(len(self.vmap.points)),
                "kiss_fallbacks": self.fallbacks, "vertical_from": self.vertical_from,
                "map_keyframes": self.keyframes, "still_scans": self.still, "still_same_beam": self.same_beam,
                "kiss_scans": int(self.stream.fed),
                "kiss_s": float(self.stream.seconds)}


def level_seeds(poses: np.ndarray, height_m: float = 0.01, tilt_deg: float = 0.2) -> bool:
    """True when seed poses (S,4,4) are those of a ground robot's odometry on a level floor: their
    height varies by less than ``height_m`` and every tilt (roll/pitch) relative to the first is below
    ``tilt_deg``. Such odometry pins height, roll and pitch better than scan-to-map ICP on a sparse,
    throttled LiDAR (``docs/design/slam.md``, height from a level TF tree), so
    :func:`refine` then takes those three from the seeds (:func:`with_vertical_of`)."""
    P = np.asarray(poses, np.float64)
    if len(P) < 2 or np.ptp(P[:, 2, 3]) >= height_m:
        return False
    z0 = P[0, :3, 2]
    return bool(np.degrees(np.arccos(np.clip(P[:, :3, 2] @ z0, -1, 1))).max() < tilt_deg)


def with_vertical_of(T: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``T`` (4,4) with the height, roll and pitch of ``G`` (4,4): the heading (yaw) and the planar
    position of ``T``, the rest of ``G``."""
    from ...conventions import yaw_rad

    def rz(a):
        c, s_ = np.cos(a), np.sin(a)
        return np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])

    out = G.copy()
    out[:3, :3] = rz(yaw_rad(T) - yaw_rad(G)) @ G[:3, :3]
    out[:2, 3] = T[:2, 3]
    return out


def _moved(Ta: np.ndarray, Tb: np.ndarray, dist_m: float, angle_deg: float) -> bool:
    D = np.linalg.inv(Ta) @ Tb
    return bool(np.linalg.norm(D[:3, 3]) >= dist_m or rotation_angle_deg(D) >= angle_deg)


def mesh_scan_subset(poses: np.ndarray, max_n: int, dist_m: float = 0.05, angle_deg: float = 2.0) -> np.ndarray:
    """Indices of at most ``max_n`` scans: keyframes by motion plus scans evenly spread in time."""
    S = len(poses)
    if max_n >= S:
        return np.arange(S)
    key, last = [0], poses[0]
    for i in range(1, S):
        if _moved(last, poses[i], dist_m, angle_deg):
            key.append(i)
            last = poses[i]
    idx = np.union1d(np.asarray(key), np.linspace(0, S - 1, max(2, max_n // 2)).round().astype(int))
    if len(idx) > max_n:
        idx = idx[np.linspace(0, len(idx) - 1, max_n).round().astype(int)]
    return np.unique(idx)


def twists_central(poses: np.ndarray, stamp_ns: np.ndarray) -> np.ndarray:
    """(S,6) body twists per scan from the neighbouring poses (central difference)."""
    S = len(poses)
    t = (stamp_ns - stamp_ns[0]).astype(np.float64) * 1e-9
    out = np.zeros((S, 6))
    for i in range(S):
        a, b = max(0, i - 1), min(S - 1, i + 1)
        if b > a:
            out[i] = twist(poses[a], poses[b], t[b] - t[a])
    return out


def deskewed_scans(scans: Scans, poses: np.ndarray, cfg: SlamConfig, max_range: float, indices=None
                   ) -> list[np.ndarray]:
    """Per scan (or per scan of ``indices``): range-filtered points deskewed to the scan stamp with
    central-difference twists."""
    xis = twists_central(poses, scans.stamp_ns)
    use_t = cfg.deskew and scans.times is not None
    out = []
    for i in (range(len(scans)) if indices is None else indices):
        pts = np.asarray(scans.points[i], np.float64)
        r = np.linalg.norm(pts, axis=1)
        keep = (r >= cfg.min_range) & (r <= max_range)
        out.append(deskew(pts[keep], scans.times[i][keep] if use_t else None, xis[i]))
    return out


def global_refine(scans: Scans, poses: np.ndarray, cfg: SlamConfig, max_range: float, quiet: bool = True,
                  background=None) -> tuple[np.ndarray, dict]:
    """Second pass: every scan (deskewed with central-difference twists) against the whole map built
    from all scans at ``poses``, moving points removed by ``background`` (a VoxelBackground; built here
    when None). Returns refined poses and health figures."""
    import open3d as o3d

    from ..background import VoxelBackground

    desk = deskewed_scans(scans, poses, cfg, max_range)
    ds = [downsample(p, cfg.fine_map_voxel) for p in desk]
    world = [transform_points(T, p) for T, p in zip(poses, ds)]
    if background is None:
        background = VoxelBackground.build(world, voxel=cfg.background_voxel, min_fraction=cfg.background_min_fraction,
                                           origins=poses[:, :3, 3])
    allp = np.concatenate([w[background.contains(w, tolerance=0)] for w in world])
    allp = downsample(allp, cfg.fine_map_voxel)
    pc = _o3d_cloud(allp)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.map_normal_radius, max_nn=cfg.map_normal_nn))
    # orient normals towards the nearest sensor position
    centers = poses[:, :3, 3]
    from scipy.spatial import cKDTree

    _, ci = cKDTree(centers).query(allp)
    nrm = np.asarray(pc.normals)
    flip = np.einsum("ij,ij->i", nrm, centers[ci] - allp) < 0
    nrm[flip] *= -1
    pc.normals = o3d.utility.Vector3dVector(nrm)
    out = poses.copy()
    fit = np.zeros(len(poses))
    rmse = np.zeros(len(poses))
    for i in track(range(len(poses)), total=len(poses), description="slam: refine (global map)", quiet=quiet):
        src = downsample(desk[i], cfg.fine_source_voxel)
        out[i], fit[i], rmse[i] = icp(src, pc, poses[i], cfg, cfg.fine_distances)
    return out, {"fitness": fit, "rmse": rmse, "map_points": int(len(allp)), "background": background}
