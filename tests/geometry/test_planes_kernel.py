"""The compiled window plane normals (holodata.geometry._planes_kernel behind
holodata.geometry.planes.window_plane_normals) against the numpy version they replace, and exact on
an analytic plane."""
import numpy as np
import pytest

from holodata.geometry.planes import _window_plane_normals_numpy, window_plane_normals


def directions(H, W, el=(-0.4, 0.5)):
    """(H,W,3) unit beam directions of a range image: rows from high to low elevation (rad), columns
    a full azimuth ring."""
    e = np.linspace(el[1], el[0], H)[:, None]
    a = np.linspace(0, 2 * np.pi, W, endpoint=False)[None, :]
    return np.stack(np.broadcast_arrays(np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)), -1)


def difference_normals(P):
    """Finite-difference normals (…,H,W,3) of a point image (NaN propagates), facing the origin."""
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.cross(np.gradient(P, axis=-2), np.gradient(P, axis=-3))
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
        return np.where(np.sum(n * P, -1, keepdims=True) > 0, -n, n)


def scene(batch, H, W, seed):
    """Point images (*batch,H,W,3) of random smooth range images with depth edges, range noise and
    NaN holes, and their finite-difference normals with a few extra NaN."""
    rng = np.random.default_rng(seed)
    d = directions(H, W)
    e = np.linspace(0, 1, H)[:, None]
    a = np.linspace(0, 2 * np.pi, W, endpoint=False)[None, :]
    R = np.empty(batch + (H, W))
    for idx in np.ndindex(*batch):
        r = 2.0 + rng.uniform(-0.5, 0.5) * e + rng.uniform(0, 0.6) * np.cos(a + rng.uniform(0, 6))
        r = r + 0.3 * np.sin(2 * a + rng.uniform(0, 6)) * e ** 2
        cut = rng.uniform(0, 2 * np.pi, 2)
        r = np.where((a > cut.min()) & (a < cut.max()), r + rng.uniform(0.5, 2.0), r)    # a depth edge
        R[idx] = r
    R += rng.normal(0, 0.01, R.shape)
    R[rng.random(R.shape) < 0.08] = np.nan                                                 # no return
    P = R[..., None] * d
    n0 = difference_normals(P)
    n0[rng.random(R.shape) < 0.03] = np.nan
    P[rng.random(R.shape) < 0.01, 1] = np.nan                                              # one coordinate
    return P, n0


@pytest.mark.parametrize("shape", [(3, 8, 32), (2, 3, 5, 17)])
@pytest.mark.parametrize("rows, cols, sigma, iterations",
                         [(1, 4, 0.03, 3), (0, 2, 0.03, 3), (2, 3, 0.05, 2), (1, 9, 0.02, 4), (1, 1, 0.03, 0)])
def test_kernel_matches_numpy(shape, rows, cols, sigma, iterations):
    P, n0 = scene(shape[:-2], shape[-2], shape[-1], seed=sum(shape) + 7 * rows + cols)
    ref = _window_plane_normals_numpy(P, n0, rows, cols, sigma, iterations)
    out = window_plane_normals(P, n0, rows, cols, sigma, iterations)
    assert out.shape == ref.shape == P.shape and out.dtype == np.float64
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-9, equal_nan=True)
    fin = np.isfinite(out).all(-1)
    assert fin.mean() > 0.5                                           # NaN holes widen by the differences
    if iterations:
        assert not np.array_equal(out[fin], n0[fin])                 # it did refit


def test_kernel_broadcasts_like_numpy():
    P, n0 = scene((2,), 6, 20, seed=3)
    n0 = n0[0]                                                        # one normal image for both point images
    ref = _window_plane_normals_numpy(P, n0)
    out = window_plane_normals(P, n0)
    assert out.shape == (2, 6, 20, 3)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-9, equal_nan=True)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_points_on_a_plane_give_its_normal(sign):
    """z = 0.3x − 0.2y + 1 seen from the origin by an up-looking ring of beams (every beam hits it):
    every pixel's fitted normal is the plane's, with the side of n0."""
    d = directions(16, 256, el=(0.6, 1.0))
    t = 1.0 / (d[..., 2] - 0.3 * d[..., 0] + 0.2 * d[..., 1])
    assert np.all(t > 0)
    P = t[..., None] * d
    true = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
    rng = np.random.default_rng(5)
    n0 = sign * true + rng.normal(0, 0.02, P.shape)                 # a rough start, on the side of sign
    n0 /= np.linalg.norm(n0, axis=-1, keepdims=True)
    assert np.all(np.sum(n0 * true, -1) * sign > 0)
    for rows, cols in [(1, 4), (0, 2), (2, 3)]:
        n = window_plane_normals(P, n0, rows, cols)
        np.testing.assert_allclose(n, np.broadcast_to(sign * true, P.shape), rtol=0, atol=1e-9)


@pytest.mark.parametrize("gap", [1e-6, 1e-3, 1e-2, 2e-2, 0.3, 1.0])
def test_eigen_solver_matches_lapack(gap):
    """The 3×3 solver's smallest eigenvector (closed form, Jacobi where the two smallest eigenvalues
    are close) against numpy's eigh, up to sign, for gaps between the two smallest eigenvalues from
    near-degenerate to wide, the largest two sometimes equal."""
    from holodata.geometry._planes_kernel import smallest_eigenvector3

    rng = np.random.default_rng(int(gap * 1e6) % 1000)
    a, v = np.empty((3, 3)), np.empty((3, 3))
    for _ in range(300):
        Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        l1 = rng.uniform(0, 0.3)
        l2 = l1 + gap
        lam = np.array([l1, l2, l2 if rng.random() < 0.3 else max(l2, 1.0)]) * 10.0 ** rng.uniform(-6, 4)
        C = Q @ np.diag(lam) @ Q.T
        C = 0.5 * (C + C.T)
        ref = np.linalg.eigh(C)[1][:, 0]
        e = np.array(smallest_eigenvector3(C[0, 0], C[1, 0], C[1, 1], C[2, 0], C[2, 1], C[2, 2], a, v))
        assert abs(np.linalg.norm(e) - 1) < 1e-14
        e = e if e @ ref >= 0 else -e
        assert np.abs(e - ref).max() < max(1e-12, 1e-14 / gap)
