"""Static mesh of the scene from registered LiDAR scans, moving points removed.

1. :class:`PointAccumulator`: world-frame points of every scan with the dynamic ones removed
   (:class:`~holodata.mapping.background.VoxelBackground`), merged into a voxel-averaged cloud
   (``MeshConfig.voxel``; averaging many returns per voxel beats the LiDAR range noise down),
   incrementally, so memory stays flat in the number of scans. Each voxel also keeps the mean
   direction towards the sensors that saw it (normal orientation). With ``split`` it keeps each
   voxel's points apart per background voxel, so that the moving ones can be dropped after the
   accumulation (slam builds the background model meanwhile in a second process).
2. Normals by open3d (hybrid radius search), oriented towards the sensors.
3. Surface reconstruction with open3d, one of (``MeshConfig.method``):

   - ``poisson`` (default): screened Poisson, octree depth from the scene extent so the finest
     cell is about 2·``voxel`` (a finer octree was worse and slower: ``docs/design/mesh.md``);
     low-density vertices (``density_quantile``) and every vertex
     farther than ``trim_distance`` from the cloud are removed (Poisson closes open corridors
     with invented surface; the distance trim takes it away).
   - ``bpa``: ball pivoting with radii ``(2, 4)·voxel``.

   Poisson with trimming is the default: it averages the range noise into smooth planes and
   closes the gaps between rings, where ball pivoting keeps the noise (the comparison, and why
   TSDF is not offered: ``docs/design/slam.md``).
4. Optional quadric decimation to ``max_faces``; then ``snap_planes`` (:func:`snap_to_planes`): the
   large planes (walls, floor, ceiling: RANSAC, >= ``snap_min_vertices`` vertices within
   ``snap_distance``) are flattened — Poisson leaves centimetre bumps whose tilted face normals
   send reflected rays off at twice the tilt, which matters most for bounces 2 and 3
   (``docs/design/slam.md``; ``benchmarks/pipeline.py --gt-diff`` measures it).
5. ``fill_planes``: holes in the floor and the ceiling that are enclosed by observed structure
   (in plan view, ``fill_cell`` grid) are closed with flat quads at the plane's height. A LiDAR
   with a narrow vertical field of view never sees the floor around the robot nor most of the
   ceiling (an OS1-like 33 deg at 0.74 m: floor from ~2.5 m, a 3 m ceiling from ~7.5 m), while
   the radar looks +-45 deg; without the fill, half of its bounce-1 beams ended in such holes.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError
from ..geometry.voxels import unique_voxels, unpack_keys
from ..meshio import merge_meshes

METHODS = ("poisson", "bpa")
SNAP_RANSAC_DRAWS = 200   # planes tried per RANSAC search of snap_to_planes
# Poisson's bounding cube is this × the cloud's extent (open3d's default scale); the octree depth
# is chosen from the same cube
POISSON_SCALE = 1.1
# floor and ceiling levels: points whose normal is this close to vertical (|n_z|), levels holding at
# least this share of them, a ceiling at least this far above the floor (lower: a table top)
VERTICAL_NORMAL_COS = 0.95
MIN_LEVEL_SHARE = 0.01
MIN_CEILING_HEIGHT_M = 1.8
# points this far above the floor are walls for the floor fill's line of sight (below: clutter and
# the floor's own noise; above: a ceiling seen through a door)
WALL_BAND_M = (0.3, 2.0)


@dataclass(frozen=True)
class MeshConfig:
    """Static-mesh settings (metres). See the module doc."""

    method: str = "poisson"
    voxel: float = 0.04
    normal_radius: float = 0.12
    poisson_depth: int | None = None
    density_quantile: float = 0.02
    trim_distance: float = 0.06
    max_faces: int = 400_000
    fill_planes: bool = True
    fill_cell: float = 0.1
    fill_radius: float = 3.0
    snap_planes: bool = True
    snap_distance: float = 0.03
    snap_min_vertices: int = 2000
    snap_max_planes: int = 20

    def __post_init__(self):
        if self.method not in METHODS:
            raise InputError(f"unknown mesh method {self.method!r} (choose from {', '.join(METHODS)})")
        if not 0.005 <= self.voxel <= 0.5:
            raise InputError(f"mesh voxel must be in [0.005, 0.5] m, got {self.voxel}")

    def to_attrs(self) -> dict:
        return asdict(self)


class PointAccumulator:
    """Voxel-averaged world cloud: ``add(points_world, sensor_origin)`` per scan, then ``cloud()``.

    With ``split`` (m, e.g. the background model's voxel): each voxel's sums are kept apart per cell of
    the ``split`` grid its points fell in (a ``voxel`` cell straddles at most 2 such cells per axis),
    so that :meth:`drop_split_cells` can afterwards remove the points of chosen split cells exactly as
    if they had not been added — the accumulation need not wait for the model that decides which."""

    def __init__(self, voxel: float, split: float | None = None):
        self.voxel = float(voxel)
        self.split = float(split) if split else None
        self.keys = np.zeros(0, np.int64)     # voxel key of each row (a row = voxel, or voxel x split cell)
        self.codes = np.zeros(0, np.int64)    # split: the row's split cell, coded relative to the voxel
        self.sums = np.zeros((0, 3))
        self.view = np.zeros((0, 3))
        self.counts = np.zeros(0, np.int64)
        self._pend: list = []
        self._pend_n = 0

    def add(self, points: np.ndarray, origin: np.ndarray) -> None:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        if not len(p):
            return
        d = np.asarray(origin, np.float64)[None, :] - p
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        self._pend.append((p, d))
        self._pend_n += len(p)
        if self._pend_n > 2_000_000:
            self._flush()

    def _flush(self) -> None:
        if not self._pend:
            return
        p = np.concatenate([a for a, _ in self._pend])
        d = np.concatenate([b for _, b in self._pend])
        self._pend, self._pend_n = [], 0
        q = np.floor(np.divide(p, self.voxel, dtype=np.float64))   # voxel_index, still float64
        ijk = np.concatenate([unpack_keys(self.keys), q.astype(np.int64)])
        s = np.concatenate([self.sums, p])
        v = np.concatenate([self.view, d])
        c = np.concatenate([self.counts, np.ones(len(p), np.int64)])
        uk, inv = unique_voxels(ijk)
        if self.split is not None:
            # a point's split cell is its voxel corner's or one more/less per axis: code (d+1)·(9,3,1)
            off = np.floor(np.divide(p, self.split, dtype=np.float64)) - np.floor(q * (self.voxel / self.split)) + 1
            code = np.concatenate([self.codes, (off @ [9.0, 3.0, 1.0]).astype(np.int64)])
            sub = inv.astype(np.int64) * 27 + code
            occ = np.bincount(sub, minlength=27 * len(uk))   # (voxel, split cell) rows: no sort
            cells = np.flatnonzero(occ)
            rank = np.zeros(len(occ), np.int32)
            rank[cells] = np.arange(len(cells))
            inv = rank[sub]
            uk, self.codes = uk[cells // 27], cells % 27
        self.keys = uk
        n = len(uk)
        self.sums = np.stack([np.bincount(inv, s[:, j], n) for j in range(3)], 1)
        self.view = np.stack([np.bincount(inv, v[:, j], n) for j in range(3)], 1)
        self.counts = np.bincount(inv, c.astype(np.float64), n).astype(np.int64)

    def drop_split_cells(self, drop) -> int:
        """Remove the points that fell in the split cells for which ``drop(centres)`` ((M,3) world
        centres of split cells, m → (M,) bool) is True; returns how many points were removed. Then the
        rows are merged back to one per voxel."""
        self._flush()
        if self.split is None:
            raise ValueError("drop_split_cells needs a PointAccumulator made with split")
        off = np.stack([self.codes // 9, self.codes // 3 % 3, self.codes % 3], 1) - 1
        cells = np.floor(unpack_keys(self.keys) * (self.voxel / self.split)) + off   # the split cell of each row
        gone = np.asarray(drop((cells + 0.5) * self.split), bool)
        removed = int(self.counts[gone].sum())
        keys = self.keys[~gone]                  # sorted: rows are ordered by (voxel, split cell)
        first = np.r_[True, keys[1:] != keys[:-1]] if len(keys) else np.zeros(0, bool)
        inv, keys = np.cumsum(first) - 1, keys[first]
        n = len(keys)
        self.sums = np.stack([np.bincount(inv, self.sums[~gone, j], n) for j in range(3)], 1)
        self.view = np.stack([np.bincount(inv, self.view[~gone, j], n) for j in range(3)], 1)
        self.counts = np.bincount(inv, self.counts[~gone].astype(np.float64), n).astype(np.int64)
        self.keys, self.codes, self.split = keys, np.zeros(0, np.int64), None
        return removed

    def cloud(self, min_count: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(points (M,3) voxel means, unit view directions (M,3) towards the sensors, counts (M,))."""
        self._flush()
        if self.split is not None:
            raise ValueError("PointAccumulator with split: call drop_split_cells first")
        m = self.counts >= min_count
        pts = self.sums[m] / self.counts[m, None]
        v = self.view[m]
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        return pts, v, self.counts[m]


def oriented_cloud(points: np.ndarray, view: np.ndarray, radius: float):
    """open3d cloud with normals from a hybrid radius search, flipped to face ``view``."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=float(radius), max_nn=30))
    n = np.asarray(pc.normals)
    flip = np.einsum("ij,ij->i", n, view) < 0
    n[flip] *= -1
    pc.normals = o3d.utility.Vector3dVector(n)
    return pc


def _clean(mesh):
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_duplicated_vertices()
    mesh.remove_unreferenced_vertices()
    return mesh


def poisson_mesh(pc, cfg: MeshConfig):
    import open3d as o3d
    from scipy.spatial import cKDTree

    pts = np.asarray(pc.points)
    extent = float(np.max(pts.max(0) - pts.min(0)))
    depth = cfg.poisson_depth or int(np.clip(np.ceil(np.log2(extent * POISSON_SCALE / (2 * cfg.voxel))), 6, 11))
    # n_threads=1: PoissonRecon's multi-threaded splatting segfaults at random (isl-org/Open3D#6828;
    # it crashed the test suite here once)
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=depth, scale=POISSON_SCALE,
                                                                           linear_fit=False, n_threads=1)
    dens = np.asarray(dens)
    v = np.asarray(mesh.vertices)
    dist, _ = cKDTree(pts).query(v, k=1, distance_upper_bound=cfg.trim_distance * 2)
    bad = (dens < np.quantile(dens, cfg.density_quantile)) | (dist > cfg.trim_distance)
    mesh.remove_vertices_by_mask(bad)
    return _clean(mesh), {"poisson_depth": depth}


def bpa_mesh(pc, cfg: MeshConfig):
    import open3d as o3d

    radii = o3d.utility.DoubleVector([cfg.voxel * 2, cfg.voxel * 4])
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(pc, radii)
    return _clean(mesh), {"radii": list(radii)}


def snap_to_planes(vertices: np.ndarray, faces: np.ndarray, distance: float = 0.03, min_vertices: int = 2000,
                   max_planes: int = 20, cos_min: float = 0.9, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Flatten the large planes of a mesh: planes found one after the other by RANSAC
    (:func:`holodata.geometry.planes.ransac_plane`, 200 draws, ``distance``) among the vertices not yet
    taken, each with at least ``min_vertices`` inliers; an inlier whose vertex normal is within
    acos(``cos_min``) of the plane's normal is projected onto the least-squares plane of those inliers.
    Poisson leaves centimetre bumps on walls whose face normals tilt a few degrees: a reflected ray
    then leaves at twice that error (bounce-2/3 ground truth). Deterministic for a given ``seed``
    (open3d's multithreaded ``segment_plane``, used before, moved a mesh's vertices by up to 0.1 mm
    from run to run, which a short fine-tune on the traced GT amplified). Returns the new vertices
    (V,3) and an info dict (planes, vertices moved, max shift)."""
    import open3d as o3d

    from holodata.geometry.planes import fit_plane, ransac_plane

    v = np.asarray(vertices, np.float64).copy()
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))
    m.compute_vertex_normals()
    vn = np.asarray(m.vertex_normals)
    free = np.ones(len(v), bool)
    rng = np.random.default_rng(seed)
    planes, moved, shift = 0, 0, 0.0
    for _ in range(max_planes):
        idx = np.flatnonzero(free)
        if len(idx) < min_vertices:
            break
        n, d, count = ransac_plane(v[idx], float(distance), SNAP_RANSAC_DRAWS, rng)
        if count < min_vertices:
            break
        inl = idx[np.abs(v[idx] @ n + d) < distance]
        sel = inl[np.abs(vn[inl] @ n) >= cos_min]
        if len(sel) < min_vertices // 2:
            free[inl] = False  # not a surface of this orientation: do not try these again
            continue
        n, d = fit_plane(v[sel])   # the least-squares plane through the inliers of this orientation
        dist = v[sel] @ n + d
        v[sel] -= dist[:, None] * n[None, :]
        free[sel] = False
        planes += 1
        moved += len(sel)
        shift = max(shift, float(np.abs(dist).max()))
    return v, {"planes": planes, "vertices_snapped": int(moved), "max_shift_m": round(shift, 4)}


def horizontal_planes(points: np.ndarray, normals: np.ndarray, bin_m: float = 0.02,
                      min_points: int = 200) -> tuple[float | None, float | None]:
    """Heights (m) of the floor and the ceiling: the lowest and highest well-supported levels of
    points whose normal is vertical (None when absent; the ceiling needs :data:`MIN_CEILING_HEIGHT_M`
    above the floor)."""
    z = points[np.abs(normals[:, 2]) > VERTICAL_NORMAL_COS, 2]
    if len(z) < min_points:
        return None, None
    edges = np.arange(z.min(), z.max() + 2 * bin_m, bin_m)
    hist, _ = np.histogram(z, edges)
    good = np.nonzero(hist >= max(min_points, MIN_LEVEL_SHARE * len(z)))[0]
    if not len(good):
        return None, None
    level = lambda i: float(np.median(z[(z >= edges[i]) & (z < edges[i + 1])]))  # noqa: E731
    floor, ceiling = level(good[0]), level(good[-1])
    return floor, (ceiling if ceiling - floor > MIN_CEILING_HEIGHT_M else None)


def cell_quads(x0: np.ndarray, y0: np.ndarray, cell: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal square quads (two triangles each) at ``height`` over the plan-view cells whose
    lower-left corners are ``x0``, ``y0`` (n,) m: vertices (4n,3), faces (2n,3)."""
    corners = np.stack([np.c_[x0, y0], np.c_[x0 + cell, y0], np.c_[x0 + cell, y0 + cell], np.c_[x0, y0 + cell]], 1)
    v = np.concatenate([corners.reshape(-1, 2), np.full((4 * len(x0), 1), height)], axis=1)
    b = 4 * np.arange(len(x0))[:, None]
    return v, np.concatenate([b + [0, 1, 2], b + [0, 2, 3]]).reshape(-1, 3)


def fill_plane_holes(points: np.ndarray, height: float, other: float | None, cell: float, band: float = 0.06
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Quads at ``height`` over the plan-view cells that are holes in the occupancy of the points
    near that height plus the walls (every point not near the ``other`` horizontal plane): cells
    enclosed by observed structure. Returns vertices (V,3), faces (F,3); empty when none."""
    from scipy.ndimage import binary_closing, binary_fill_holes

    keep = np.ones(len(points), bool) if other is None else np.abs(points[:, 2] - other) > band
    xy = points[keep, :2]
    if not len(xy):
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    lo = xy.min(0) - 2 * cell
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    occ = np.zeros(tuple(ij.max(0) + 3), bool)
    occ[ij[:, 0], ij[:, 1]] = True
    occ = binary_closing(occ, iterations=1)
    ci, cj = np.nonzero(binary_fill_holes(occ) & ~occ)
    return cell_quads(lo[0] + ci * cell, lo[1] + cj * cell, cell, height)


def fill_floor_near_sensors(points: np.ndarray, floor: float, sensor_xyz: np.ndarray, radius: float, cell: float
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Floor quads (at height ``floor``) over the plan-view cells within ``radius`` of a sensor
    position that the sensor sees in plan view without crossing a wall (points :data:`WALL_BAND_M`
    above the floor): the floor under and around the robot, which a narrow-FOV LiDAR never samples."""
    from scipy.ndimage import binary_dilation
    from scipy.spatial import cKDTree

    wall = points[(points[:, 2] > floor + WALL_BAND_M[0]) & (points[:, 2] < floor + WALL_BAND_M[1]), :2]
    s_xy = np.asarray(sensor_xyz, np.float64)[:, :2]
    lo = np.minimum(wall.min(0) if len(wall) else s_xy.min(0), s_xy.min(0)) - radius - 2 * cell
    hi = np.maximum(wall.max(0) if len(wall) else s_xy.max(0), s_xy.max(0)) + radius + 2 * cell
    shape = tuple(np.ceil((hi - lo) / cell).astype(np.int64) + 1)
    occ = np.zeros(shape, bool)
    if len(wall):
        wij = np.floor((wall - lo) / cell).astype(np.int64)
        occ[wij[:, 0], wij[:, 1]] = True
        occ = binary_dilation(occ, iterations=1)
    gi, gj = np.nonzero(np.ones(shape, bool))
    centre = lo + (np.c_[gi, gj] + 0.5) * cell
    dist, near = cKDTree(s_xy).query(centre, distance_upper_bound=radius)
    ok = np.isfinite(dist) & ~occ[gi, gj]
    gi, gj, centre, near = gi[ok], gj[ok], centre[ok], near[ok]
    # walk each cell's plan-view segment from its nearest sensor position: no wall cell on the way
    t = np.linspace(0.0, 1.0, int(np.ceil(radius / (0.5 * cell))) + 1)
    seg = s_xy[near][:, None, :] + t[None, :, None] * (centre - s_xy[near])[:, None, :]
    sij = np.clip(np.floor((seg - lo) / cell).astype(np.int64), 0, np.array(shape) - 1)
    free = ~occ[sij[..., 0], sij[..., 1]].any(axis=1)
    return cell_quads(lo[0] + gi[free] * cell, lo[1] + gj[free] * cell, cell, floor)


def build_mesh(points: np.ndarray, view: np.ndarray, cfg: MeshConfig = MeshConfig(), sensor_xyz=None
               ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Surface from the voxel-averaged static cloud ``points`` (M,3) with view directions ``view``;
    ``sensor_xyz`` (S,3) the scan positions (for filling the floor around them).
    Returns vertices (V,3) float32, faces (F,3) int32 and an info dict (method, counts, seconds)."""
    t0 = time.perf_counter()
    if len(points) < 10:
        raise InputError(f"too few static points for a mesh ({len(points)})")
    pc = oriented_cloud(points, view, cfg.normal_radius)
    if cfg.method == "poisson":
        mesh, info = poisson_mesh(pc, cfg)
    else:
        mesh, info = bpa_mesh(pc, cfg)
    if cfg.max_faces and len(mesh.triangles) > cfg.max_faces:
        mesh = _clean(mesh.simplify_quadric_decimation(int(cfg.max_faces)))
    mv, mf = np.asarray(mesh.vertices), np.asarray(mesh.triangles, np.int32)
    if cfg.snap_planes and len(mf):
        mv, info["snap"] = snap_to_planes(mv, mf, cfg.snap_distance, cfg.snap_min_vertices, cfg.snap_max_planes)
    parts = [(mv.astype(np.float32), mf)]
    if cfg.fill_planes:
        floor, ceiling = horizontal_planes(np.asarray(pc.points), np.asarray(pc.normals))
        filled = {}
        for name, h, other in (("floor", floor, ceiling), ("ceiling", ceiling, floor)):
            if h is None:
                continue
            fills = [fill_plane_holes(points, h, other, cfg.fill_cell)]
            if name == "floor" and sensor_xyz is not None and len(sensor_xyz):
                fills.append(fill_floor_near_sensors(points, h, sensor_xyz, cfg.fill_radius, cfg.fill_cell))
            fv, ff = merge_meshes(fills)
            filled[name] = {"height_m": round(h, 3), "faces": int(len(ff))}
            parts.append((fv.astype(np.float32), ff))
        info["filled"] = filled
    v, f = merge_meshes(parts)
    v, f = v.astype(np.float32), f.astype(np.int32)
    info.update({"method": cfg.method, "vertices": int(len(v)), "faces": int(len(f)), "points": int(len(points)),
                 "seconds": round(time.perf_counter() - t0, 3)})
    return v, f, info


__all__ = ["MeshConfig", "PointAccumulator", "build_mesh", "oriented_cloud", "METHODS"]
