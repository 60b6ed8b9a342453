"""Analytic tests of the geometry core (holodata/geometry): voxel keys and averaging, plane fits,
the per-neighbourhood plane projection and its compiled ball sums (against brute force and the
sparse-matrix road they replace), the point-to-plane Gauss-Newton step and ICP (exact recovery, held
directions)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from holodata.geometry import (
    IcpParams,
    StepRule,
    about_origin,
    cell_keys,
    centred_offset,
    dense_box,
    first_per_voxel,
    fit_height_plane,
    fit_plane,
    flat_index,
    gauss_newton_step,
    hold_at,
    local_plane_projection,
    moved_by,
    point_to_plane_icp,
    ransac_plane,
    tukey_weights,
    unique_voxels,
    unpack_keys,
    voxel_average,
    voxel_index,
    voxel_keys,
)
from holodata.geometry import voxels as V
from holodata.geometry._ball_kernel import ball_moments


def _pose(t, rotvec_deg) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.deg2rad(rotvec_deg)).as_matrix()
    T[:3, 3] = t
    return T


# ------------------------------------------------------------------------------------ voxels
def test_voxel_keys_round_trip_and_sort_like_flat_cells():
    rng = np.random.default_rng(0)
    ijk = rng.integers(-(1 << 19), 1 << 19, (5000, 3))
    assert np.array_equal(unpack_keys(voxel_keys(ijk)), ijk)
    # inside a box, C-order flat cell indices order the voxels as the keys do, and map back to them
    small = rng.integers(-7, 9, (2000, 3))
    lo, dims = dense_box(small.min(0), small.max(0))
    flat = flat_index(small, lo, dims)
    k = voxel_keys(small)
    assert np.array_equal(np.argsort(flat, kind="stable"), np.argsort(k, kind="stable"))
    assert np.array_equal(cell_keys(flat, lo, dims), k)


def test_voxel_index_is_floor_and_first_per_voxel_keeps_the_first_point():
    v = 0.25
    p = np.array([[0.1, 0.1, 0.1], [-0.1, 0.0, 0.0], [0.2, 0.0, 0.24], [0.26, 0.0, 0.0], [-0.01, 0.0, 0.0]])
    assert np.array_equal(voxel_index(p, v), [[0, 0, 0], [-1, 0, 0], [0, 0, 0], [1, 0, 0], [-1, 0, 0]])
    assert np.array_equal(first_per_voxel(p, v), [0, 1, 3])         # points 2 and 4 share earlier voxels
    assert first_per_voxel(np.zeros((0, 3)), v).shape == (0,)


def test_unique_voxels_equals_np_unique_of_the_keys(monkeypatch):
    rng = np.random.default_rng(4)
    for n, scale in ((0, 1.0), (1, 1.0), (50, 0.1), (20000, 3.0), (3000, 2e4)):   # the last: sorted fallback
        ijk = voxel_index(rng.normal(size=(n, 3)) * scale, 0.04)
        a, ai = np.unique(voxel_keys(ijk), return_inverse=True)
        b, bi = unique_voxels(ijk)
        assert np.array_equal(a, b) and np.array_equal(ai.reshape(-1), bi)
    ijk = voxel_index(rng.normal(size=(500, 3)), 0.04)
    dense = unique_voxels(ijk)
    monkeypatch.setattr(V, "DENSE_MAX_CELLS", 0)                   # every box too large: sorted keys
    assert dense_box(ijk.min(0), ijk.max(0)) is None
    ref = unique_voxels(ijk)
    assert np.array_equal(dense[0], ref[0]) and np.array_equal(dense[1], ref[1].reshape(-1))


def test_voxel_average_of_clusters_is_their_means():
    rng = np.random.default_rng(1)
    # clusters 0.4 m wide, 1-3 m apart: one per 1 m voxel of the grid anchored half a voxel below the minimum
    centres = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 2.0, 1.0]])
    p = np.concatenate([c + rng.uniform(-0.2, 0.2, (40, 3)) for c in centres])
    got = voxel_average(p, 1.0)
    want = np.array([p[40 * i:40 * (i + 1)].mean(0) for i in range(3)])
    np.testing.assert_allclose(got[np.lexsort(got.T)], want[np.lexsort(want.T)], rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------ planes
def _plane_points(normal, offset, n=500, seed=0):
    """Exact points on the plane normal·p + offset = 0 (normal unit)."""
    rng = np.random.default_rng(seed)
    e1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    uv = rng.uniform(-2, 2, (n, 2))
    return uv[:, :1] * e1 + uv[:, 1:] * e2 - offset * normal


def test_fit_plane_of_exact_points_returns_the_plane():
    nrm = np.array([0.3, -0.4, 0.8]) / np.linalg.norm([0.3, -0.4, 0.8])
    n, d = fit_plane(_plane_points(nrm, -1.7))
    s = np.sign(n @ nrm)
    np.testing.assert_allclose(s * n, nrm, atol=1e-12)
    assert s * d == pytest.approx(-1.7, abs=1e-12)


def test_fit_height_plane_of_exact_points_returns_the_coefficients():
    rng = np.random.default_rng(2)
    xy = rng.uniform(-3, 3, (300, 2))
    z = 0.02 * xy[:, 0] - 0.05 * xy[:, 1] + 0.4
    np.testing.assert_allclose(fit_height_plane(np.c_[xy, z]), [0.02, -0.05, 0.4], atol=1e-12)


def test_ransac_plane_of_an_exact_plane_among_outliers_is_that_plane():
    nrm = np.array([0.0, 0.6, 0.8])
    on = _plane_points(nrm, 0.5, 3000)
    out = np.random.default_rng(3).uniform(-3, 3, (1000, 3))
    out = out[np.abs(out @ nrm + 0.5) > 0.05]
    n, d, k = ransac_plane(np.concatenate([on, out]), 0.01, 100, np.random.default_rng(0))
    s = np.sign(n @ nrm)
    np.testing.assert_allclose(s * n, nrm, atol=1e-12)
    assert s * d == pytest.approx(0.5, abs=1e-12) and k == 3000


def _csr_plane_projection(X, radius, ratio=0.1, min_nn=6, only=None):
    """local_plane_projection as it was written before the compiled kernel: neighbour pairs from
    scipy's cKDTree, moments by a sorted sparse matrix times the points (the reference to the bit)."""
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree

    idx = np.arange(len(X)) if only is None else np.flatnonzero(only)
    nb = cKDTree(X[idx]).sparse_distance_matrix(cKDTree(X), radius, output_type="ndarray")
    A = csr_matrix((np.ones(len(nb)), (nb["i"], nb["j"])), shape=(len(idx), len(X)))
    cnt = np.asarray(A.sum(1)).ravel()
    mu = (A @ X) / cnt[:, None]
    C = ((A @ (X[:, :, None] * X[:, None, :]).reshape(-1, 9)) / cnt[:, None]).reshape(-1, 3, 3) \
        - mu[:, :, None] * mu[:, None, :]
    w, V_ = np.linalg.eigh(C)
    n = V_[:, :, 0]
    ok = (cnt >= min_nn) & (w[:, 0] < ratio * w[:, 1])
    out = X.copy()
    out[idx[ok]] -= np.einsum("ij,ij->i", X[idx] - mu, n)[ok, None] * n[ok]
    return out


def test_ball_moments_are_the_brute_force_sums_over_each_ball():
    """Counts, sums and second moments of every query's ball against all pairs' distances in numpy;
    a lattice puts many pairs exactly at the radius (included, as cKDTree includes them), and a
    cloud spread over 1e8 m widens the grid's cells beyond the radius (still every neighbour)."""
    rng = np.random.default_rng(5)
    clouds = [(rng.uniform(-1, 1, (1500, 3)) * [1.0, 2.0, 0.5], 0.2),
              (np.round(rng.uniform(0, 1, (800, 3)) * 10) / 10, 0.1),
              (np.concatenate([rng.uniform(0, 1, (300, 3)), rng.uniform(0, 1, (300, 3)) + 1e8]), 0.3)]
    for X, r in clouds:
        q = rng.choice(len(X), len(X) // 3, replace=False)
        cnt, s1, s2 = ball_moments(X, r, q)
        d2 = ((X[q, None, :] - X[None, :, :]) ** 2).sum(-1)
        inside = d2 <= r * r
        assert np.array_equal(cnt, inside.sum(1)) and (cnt >= 1).all()
        np.testing.assert_allclose(s1, inside @ X, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(s2, inside @ (X[:, :, None] * X[:, None, :]).reshape(-1, 9), rtol=1e-12, atol=1e-6)
    cnt, s1, s2 = ball_moments(np.zeros((0, 3)), 0.1)
    assert cnt.shape == (0,) and s1.shape == (0, 3) and s2.shape == (0, 9)


def test_local_plane_projection_equals_the_sparse_matrix_road_to_the_bit():
    """The compiled neighbourhood sums take each ball's points in ascending index order, as the
    sorted CSR product did: the projected cloud is the same bits (random clutter, noisy planes and a
    lattice with pairs at exactly the radius; all points and a subset)."""
    rng = np.random.default_rng(6)
    xy = rng.uniform(0, 3, (4000, 2))
    planes = np.concatenate([np.c_[xy, 0.01 * rng.normal(size=len(xy))],
                             np.c_[xy[:, :1], np.full(len(xy), 3.0) + 0.01 * rng.normal(size=len(xy)), xy[:, 1:]]])
    for X, r in ((rng.uniform(0, 2, (5000, 3)), 0.15), (planes + [10.0, -20.0, 1.5], 0.3),
                 (np.round(rng.uniform(0, 1, (3000, 3)) * 20) / 20, 0.1)):
        only = rng.uniform(size=len(X)) < 0.4
        for sel in (None, only):
            got = local_plane_projection(X, r, only=sel)
            assert np.array_equal(got, _csr_plane_projection(X, r, only=sel))
            assert (got != X).any()


# ------------------------------------------------------------------------------------ ICP
def test_tukey_weights():
    r = np.array([0.0, 0.05, -0.05, 0.1, -0.2, 0.0999])
    w = tukey_weights(r, 0.1)
    np.testing.assert_allclose(w, [1.0, 0.5625, 0.5625, 0.0, 0.0, (1 - 0.999 ** 2) ** 2], rtol=1e-12)
    np.testing.assert_allclose(tukey_weights(r, np.full(len(r), 0.1)), w, rtol=0, atol=0)


def _box_planes():
    """Unit normals (6,3) and offsets (6,) of a 4 x 3 x 2.5 m room's walls, floor and ceiling, and points
    (N,3) sampled exactly on them."""
    nrm = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    off = np.array([0.0, 4.0, 0.0, 3.0, 0.0, 2.5])
    rng = np.random.default_rng(5)
    pts, which = [], []
    for i, (n, d) in enumerate(zip(nrm, off)):
        u = rng.uniform(0, 1, (400, 3)) * [4.0, 3.0, 2.5]
        a = int(np.argmax(np.abs(n)))
        u[:, a] = -d * n[a]
        pts.append(u)
        which.append(np.full(len(u), i))
    return nrm, off, np.concatenate(pts), np.concatenate(which)


def test_gauss_newton_steps_recover_a_known_rigid_motion_from_planes():
    """Points on a room's six planes, moved by a known motion: iterated steps on the exact point-to-plane
    residuals take them back to their planes, and the accumulated motion is the inverse of it."""
    nrm, off, pts, which = _box_planes()
    D = _pose([0.05, -0.03, 0.02], [1.0, -2.0, 3.0])
    src = pts @ D[:3, :3].T + D[:3, 3]
    n = nrm[which]
    T = np.eye(4)
    for _ in range(10):
        p = src @ T[:3, :3].T + T[:3, 3]
        r = np.einsum("ij,ij->i", p, n) + off[which]
        T = moved_by(T, gauss_newton_step(p, n, r, np.ones(len(p)), np.zeros(3)).motion())
    np.testing.assert_allclose(T @ D, np.eye(4), atol=1e-12)
    # the same about another centre, and with the held-direction solver (nothing is held in a room)
    T2 = np.eye(4)
    for _ in range(10):
        p = src @ T2[:3, :3].T + T2[:3, 3]
        r = np.einsum("ij,ij->i", p, n) + off[which]
        step = gauss_newton_step(p, n, r, np.ones(len(p)), None, rule=StepRule(hold_ratio=0.01))
        assert step.held.shape == (6, 0)
        T2 = moved_by(T2, step.motion())
    np.testing.assert_allclose(T2 @ D, np.eye(4), atol=1e-12)


def test_point_to_plane_icp_recovers_a_known_rigid_motion_exactly():
    """Camera points on the room's planes; the target a dense sampling of the same planes: the
    point-to-plane residual to any sample of the right plane is exact, so ICP lands on the true pose."""
    nrm, off, world, which = _box_planes()
    T_true = _pose([2.0, 1.5, 1.2], [0.0, 0.0, 30.0])
    cam = (world - T_true[:3, 3]) @ T_true[:3, :3]
    guess = _pose([0.03, -0.02, 0.01], [0.5, -0.5, 1.0]) @ T_true
    T = point_to_plane_icp(cam, np.full(len(cam), 1e4), world, nrm[which], guess, IcpParams(distances=(0.15, 0.05)))
    np.testing.assert_allclose(T, T_true, atol=1e-9)


def _corridor():
    """A corridor along y: walls x = ±1, floor z = 0, ceiling z = 2.5 (nothing fixes y)."""
    rng = np.random.default_rng(6)
    u = rng.uniform(size=(3000, 2))
    pts = np.concatenate([np.c_[np.full(len(u), s), u[:, 0] * 10, u[:, 1] * 2.5] for s in (-1.0, 1.0)]
                         + [np.c_[u[:, 0] * 2 - 1, u[:, 1] * 10, np.full(len(u), z)] for z in (0.0, 2.5)])
    nrm = np.zeros_like(pts)
    nrm[:2 * len(u), 0] = 1.0
    nrm[2 * len(u):, 2] = 1.0
    return pts, nrm


def test_a_held_direction_stays_at_its_initial_value():
    """In a corridor nothing fixes the shift along it: the step holds that direction (one held
    eigenvector, along y) and moves the pose only across; ICP from a guess shifted along y keeps that
    shift while it recovers x and z."""
    pts, nrm = _corridor()
    D = _pose([0.02, 0.07, -0.01], [0.0, 0.0, 0.0])
    p = pts + D[:3, 3]
    r = np.einsum("ij,ij->i", p - pts, nrm)
    step = gauss_newton_step(p, nrm, r, np.ones(len(p)), None, rule=StepRule(hold_ratio=0.02))
    assert step.held.shape == (6, 1)
    np.testing.assert_allclose(np.abs(step.held[:, 0]), [0, 0, 0, 0, 1, 0], atol=1e-12)
    x = step.motion()
    np.testing.assert_allclose(x[3:], [-0.02, 0.0, 0.01], atol=1e-12)
    np.testing.assert_allclose(x[:3], 0.0, atol=1e-12)
    # the solver: the guess's y stays, x and z go to the truth
    guess = _pose([0.02, 0.07, -0.01], [0.0, 0.0, 0.0])
    info: dict = {}
    T = point_to_plane_icp(pts, np.full(len(pts), 1e4), pts, nrm, guess,
                           IcpParams(distances=(0.15, 0.05), degenerate_ratio=0.02, hold_m=0.0), info=info)
    assert info["frozen"] == 1
    # (to first order: the held eigenvector of a random sampling is y up to a trace of rotation)
    assert T[1, 3] == pytest.approx(0.07, abs=1e-6)
    # x and z to a tenth of a millimetre (of the 2 and 1 cm offsets: points near an edge may pair
    # with the other plane's samples)
    np.testing.assert_allclose(T[[0, 2], 3], 0.0, atol=1e-4)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-4)
    # hold_at puts the held direction where another pose has it and keeps the rest
    T2 = hold_at(T, np.eye(4), info["held"])
    assert T2[1, 3] == pytest.approx(0.0, abs=1e-6) and np.allclose(T2[[0, 2], 3], T[[0, 2], 3], atol=1e-6)


def test_step_coordinates_about_a_centre_and_about_the_origin():
    """centred_offset is the motion of the centre with the rotation scaled by the lever;
    about_origin converts a small motion of those coordinates to (rotation vector, translation)
    about the origin (first order: t = t_c - ω × c)."""
    T0 = _pose([1.0, 2.0, 0.5], [0.0, 0.0, 30.0])
    D = _pose([0.02, -0.01, 0.03], [0.2, -0.1, 0.3])
    c, L = np.array([3.0, -1.0, 1.0]), 4.0
    y = centred_offset(D @ T0, T0, c, L)
    np.testing.assert_allclose(y[:3], Rotation.from_matrix(D[:3, :3]).as_rotvec() * L, atol=1e-15)
    np.testing.assert_allclose(y[3:], D[:3, :3] @ c + D[:3, 3] - c, atol=1e-15)
    x = about_origin(y, c, L)
    np.testing.assert_allclose(x[:3], Rotation.from_matrix(D[:3, :3]).as_rotvec(), atol=1e-15)
    np.testing.assert_allclose(moved_by(T0, x), D @ T0, atol=1e-4)     # second-order remainder
    assert not np.allclose(centred_offset(T0, T0, c, L), 1.0) and np.allclose(centred_offset(T0, T0, c, L), 0.0)


def test_plain_step_is_none_when_ill_conditioned():
    """Points on one plane fix only three of six directions: the plain step refuses (cond > max_cond)."""
    p = _plane_points(np.array([0.0, 0.0, 1.0]), 0.0, 200)
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    assert gauss_newton_step(p, n, np.full(len(p), 0.01), np.ones(len(p)), np.zeros(3),
                             rule=StepRule(max_cond=1e8)) is None
