"""Normals of a range image (holodata.geometry.planes window/plane fits behind
holodata.geometry.unmirror.normals_from_range): analytic box-room images, exact and noisy."""
import numpy as np

from holodata.conventions import Grid
from holodata.geometry.planes import agreeing_planes, window_plane_normals
from holodata.geometry.unmirror import normals_from_range

G = Grid(32, 128)
# a box room about the radar: walls x = 2.5 / -1.5, y = ±1.5, floor z = -0.4, ceiling z = 2.6
WALLS = [(0, 2.5), (0, -1.5), (1, 1.5), (1, -1.5), (2, 2.6), (2, -0.4)]


def box_room(noise=0.0, seed=0):
    """(range (H,W) m, true normal facing the radar (H,W,3))."""
    d = G.directions()
    t = np.full(d.shape[:2], np.inf)
    n = np.zeros(d.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, pos in WALLS:
            ti = np.where(d[..., axis] * pos > 0, pos / d[..., axis], np.inf)
            hit = ti < t
            t = np.where(hit, ti, t)
            n[hit] = 0.0
            n[hit, axis] = -np.sign(pos)
    return t + np.random.default_rng(seed).normal(0, noise, t.shape), n


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.abs(np.sum(a * b, -1)), 0, 1)))


def test_window_fit_is_exact_on_planes_and_averages_noise():
    R, n_true = box_room()
    d = G.directions()
    n0 = normals_from_range(R, G, method="difference")
    n = window_plane_normals(R[..., None] * d, n0)
    err = angle_deg(n, n_true)
    assert np.median(err) < 1e-6 and np.mean(err < 1e-3) > 0.85   # exact away from the room's edges
    Rn, _ = box_room(noise=0.02)
    e_diff = angle_deg(normals_from_range(Rn, G, method="difference"), n_true)
    e_win = angle_deg(window_plane_normals(Rn[..., None] * d, normals_from_range(Rn, G, method="difference")), n_true)
    assert np.median(e_win) < 0.5 * np.median(e_diff)


def test_image_planes_take_walls_to_a_fraction_of_a_degree():
    Rn, n_true = box_room(noise=0.02)
    e_diff = angle_deg(normals_from_range(Rn, G, method="difference"), n_true)
    n = normals_from_range(Rn, G)
    e = angle_deg(n, n_true)
    assert np.median(e_diff) > 2.0            # 2 cm noise: finite differences are degrees off
    assert np.median(e) < 0.3 and np.mean(e < 1.0) > 0.9
    np.testing.assert_array_equal(n, normals_from_range(Rn, G))  # deterministic
    assert np.all(np.sum(n * G.directions(), -1) <= 1e-9)          # facing the beam


def test_agreeing_planes_keep_crossed_surfaces():
    """A floor plane extended through a wall must not take the wall's points on its line: a point
    supports a plane only where its own normal agrees."""
    rng = np.random.default_rng(1)
    floor = np.c_[rng.uniform(0, 3, 400), rng.uniform(-1, 1, 400), np.zeros(400)]
    wall = np.c_[np.full(200, 3.0), rng.uniform(-1, 1, 200), rng.uniform(0, 0.03, 200)]  # its foot, within 3 cm of z=0
    X = np.r_[floor, wall]
    NL = np.r_[np.tile([0, 0, 1.0], (400, 1)), np.tile([-1.0, 0, 0], (200, 1))]
    NL = NL + rng.normal(0, 0.05, NL.shape)
    NL /= np.linalg.norm(NL, axis=1, keepdims=True)
    out = agreeing_planes(X, NL)
    assert angle_deg(out[:400], [0, 0, 1.0]).max() < 0.5
    assert angle_deg(out[400:], [1.0, 0, 0]).max() < 0.5
