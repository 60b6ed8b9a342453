"""Multi-bounce ray tracing against analytic truth derived here (not by the tracer)."""
from __future__ import annotations

import numpy as np
import pytest
from _scenes import HUMAN, box, l_corridor, merge, quad

from holodata.conventions import Label
from holodata.raytrace import RayScene, available_backends, trace
from holodata.raytrace.labels import CEILING, FLOOR, WALL

BACKENDS = available_backends()


def grid_plane(z, half, n):
    """Plane z=const over [-half, half]^2 as an n x n grid of coplanar quads (2n^2 triangles)."""
    xs = np.linspace(-half, half, n + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    v = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
    idx = np.arange(X.size).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_dirs(n, seed):
    return unit(np.random.default_rng(seed).normal(size=(n, 3)))


# ---------------------------------------------------------------- box room (unfolded mirrors)
LO, HI = np.array([-2.0, -1.5, -1.0]), np.array([2.5, 1.7, 1.6])


def unfolded_truth(o, d, nb):
    """b-th bounce distance = b-th smallest crossing of the mirrored wall lattice; point = folded
    mirror point; normal = axis of that crossing."""
    L = HI - LO
    ts, axes = [], []
    for k in range(3):
        m = np.arange(nb + 1)
        planes = HI[k] + m * L[k] if d[k] > 0 else LO[k] - m * L[k]
        ts.append((planes - o[k]) / d[k])
        axes.append(np.full(nb + 1, k))
    ts, axes = np.concatenate(ts), np.concatenate(axes)
    order = np.argsort(ts)[:nb]
    R = ts[order]
    pm = o + R[:, None] * d  # mirrored points
    u = np.mod(pm - LO, 2 * L)
    pts = LO + np.where(u > L, 2 * L - u, u)
    return R, pts, axes[order]


@pytest.mark.parametrize("backend", BACKENDS)
def test_box_room_matches_unfolded_mirror_lattice(backend):
    v, f = box(LO, HI)
    o = np.array([0.3, -0.2, 0.1])
    d = random_dirs(400, 1)
    res = trace(v, f, np.broadcast_to(o, d.shape), d, max_bounces=3, max_range=100.0, backend=backend)
    for i in range(len(d)):
        R, pts, ax = unfolded_truth(o, d[i], 3)
        np.testing.assert_allclose(res["range"][i], R, atol=2e-5, rtol=0)
        np.testing.assert_allclose(res["point"][i], pts, atol=2e-5)
        assert np.all(np.abs(res["normal"][i][np.arange(3), ax]) > 0.999999)
    # normals face the incoming ray: bounce 1 normal points back towards the origin
    assert np.all(np.einsum("ij,ij->i", res["normal"][:, 0], d) < 0)
    assert np.all(np.diff(res["range"], axis=1) > 0)


def test_box_room_max_range_cuts_this_and_later_bounces():
    v, f = box(LO, HI)
    o = np.zeros((300, 3))
    d = random_dirs(300, 2)
    res = trace(v, f, o, d, max_bounces=3, max_range=4.0)
    for i in range(len(d)):
        R, _, _ = unfolded_truth(o[i], d[i], 3)
        first_out = np.argmax(np.append(R, np.inf) > 4.0)
        assert np.all(np.isfinite(res["range"][i, :first_out]))
        assert np.all(np.isnan(res["range"][i, first_out:]))
        assert np.all(res["face"][i, first_out:] == -1)
        assert np.all(res["label"][i, first_out:] == 0)


def test_geometric_semantic_classes_in_box_room():
    v, f = box(LO, HI)
    sc = RayScene(v, f)
    d = np.array([[0, 0, -1.0], [0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]])
    res = sc.trace(np.zeros((4, 3)), d, max_bounces=1)
    assert res.semantic[:, 0].tolist() == [FLOOR, CEILING, WALL, WALL]
    assert sc.class_names[FLOOR] == "floor" and sc.class_names[sc.human_class] == "human"


def test_face_class_overrides_geometric_classes():
    v, f = box(LO, HI)
    fc = np.arange(len(f), dtype=np.uint8) + 10
    sc = RayScene(v, f, face_class=fc, class_names={int(k): f"part{k}" for k in fc})
    res = sc.trace(np.zeros((300, 3)), random_dirs(300, 3), max_bounces=2, max_range=100)
    hit = res.face >= 0
    assert np.array_equal(res.semantic[hit], fc[res.face[hit]])
    assert sc.human_class not in set(fc.tolist()) and sc.class_names[sc.human_class] == "human"


# ---------------------------------------------------------------- corner reflector
@pytest.mark.parametrize("backend", BACKENDS)
def test_corner_reflector_returns_antiparallel(backend):
    s = 10.0
    mesh = merge(quad([0, 0, 0], [s, 0, 0], [s, s, 0], [0, s, 0]),
                 quad([0, 0, 0], [0, s, 0], [0, s, s], [0, 0, s]),
                 quad([0, 0, 0], [0, 0, s], [s, 0, s], [s, 0, 0]))
    rng = np.random.default_rng(4)
    o = rng.uniform(1.0, 2.0, size=(200, 3))
    d = -unit(rng.uniform(0.3, 1.0, size=(200, 3)))  # into the corner
    res = trace(*mesh, o, d, max_bounces=4, max_range=100.0, backend=backend)
    # truth: crossings of the three coordinate planes, t_k = o_k / |d_k|
    R = np.sort(o / np.abs(d), axis=1)
    np.testing.assert_allclose(res["range"][:, :3], R, atol=2e-5)
    assert np.all(np.isnan(res["range"][:, 3]))  # the retro-reflected ray leaves the scene
    p2, p3, n3 = res["point"][:, 1], res["point"][:, 2], res["normal"][:, 2].astype(float)
    d3 = unit(p3 - p2)
    d4 = d3 - 2 * np.einsum("ij,ij->i", d3, n3)[:, None] * n3
    np.testing.assert_allclose(d4, -d, atol=1e-4)
    # mirrored point of bounce 3 lies on the beam: p'_3 = o + R_3 d and |p3| folds it through the corner
    np.testing.assert_allclose(np.abs(o + R[:, 2:3] * d), p3, atol=1e-4)


# ---------------------------------------------------------------- single plane, grazing, misses
@pytest.mark.parametrize("backend", BACKENDS)
def test_grazing_plane_no_self_hits(backend):
    v, f = grid_plane(0.0, 400.0, 40)  # many coplanar triangles
    h = 0.5
    eps = np.deg2rad([0.2, 0.5, 1.0, 2.0, 5.0, 30.0, 89.0])
    az = np.linspace(0, 2 * np.pi, len(eps), endpoint=False)
    d = np.stack([np.cos(eps) * np.cos(az), np.cos(eps) * np.sin(az), -np.sin(eps)], 1)
    o = np.tile([[3.0, -2.0, h]], (len(d), 1))
    res = trace(v, f, o, d, max_bounces=3, max_range=1000.0, backend=backend)
    np.testing.assert_allclose(res["range"][:, 0], h / np.sin(eps), rtol=4e-7)  # float32 output
    np.testing.assert_allclose(res["normal"][:, 0], np.tile([0, 0, 1.0], (len(d), 1)), atol=1e-7)
    assert np.all(np.isnan(res["range"][:, 1:])) and np.all(res["face"][:, 1:] == -1)
    # from below the normal is flipped to face the ray
    res2 = trace(v, f, o * [1, 1, -1], d * [1, 1, -1], max_bounces=1, max_range=1000.0, backend=backend)
    np.testing.assert_allclose(res2["normal"][:, 0, 2], -1.0, atol=1e-7)


@pytest.mark.parametrize("backend", BACKENDS)
def test_beams_that_hit_nothing(backend):
    v, f = grid_plane(0.0, 10.0, 2)
    d = unit([[0, 0, 1.0], [1, 0, 0.0], [1, 1, 0.3], [0.2, 0, -0.01]])
    o = np.tile([[0, 0, 1.0]], (4, 1))
    res = trace(v, f, o, d, max_bounces=3, backend=backend)
    assert np.all(np.isnan(res["range"][:3])) and np.all(res["face"][:3] == -1)
    assert np.all(res["label"][:3] == 0) and np.all(res["semantic"][:3] == 0)
    assert np.all(np.isnan(res["point"][:3])) and np.all(np.isnan(res["normal"][:3]))
    assert np.isnan(res["range"][3, 0])  # 100 m away: beyond max_range 9.6
    hit = RayScene(v, f, backend=backend).cast(o, d)
    assert np.all(np.isinf(hit.t)) and np.all(hit.face == -1)


@pytest.mark.parametrize("backend", BACKENDS)
def test_thin_geometry_not_skipped(backend):
    # two parallel planes 1 mm apart: a beam between them bounces every 1 mm / sin(a) of path
    gap = 1e-3
    lower, upper = grid_plane(0.0, 5.0, 3), grid_plane(gap, 5.0, 3)
    v, f = merge(lower, upper)
    for a in (0.01, 0.5, 1.2):
        d = np.array([[np.cos(a), 0.0, np.sin(a)]])
        o = np.array([[0.0, 0.0, gap / 2]])
        res = trace(v, f, o, d, max_bounces=3, max_range=100.0, backend=backend)
        s = gap / np.sin(a)
        np.testing.assert_allclose(res["range"][0], [s / 2, 1.5 * s, 2.5 * s], rtol=1e-6)
        np.testing.assert_allclose(res["point"][0, :, 2], [gap, 0, gap], atol=1e-7)
    # a closed 1 mm slab: hit from above at 45 deg, reflected up, nothing else
    v, f = box([0, 0, 0], [1, 1, 1e-3])
    res = trace(v, f, [[0.2, 0.5, 0.3]], unit([[1, 0, -1.0]]), max_bounces=2, backend=backend)
    np.testing.assert_allclose(res["range"][0, 0], (0.3 - 1e-3) * np.sqrt(2), rtol=1e-6)
    assert np.isnan(res["range"][0, 1])


# ---------------------------------------------------------------- L corridor with a human
C30, S30 = np.cos(np.pi / 6), 0.5


@pytest.mark.parametrize("backend", BACKENDS)
def test_corridor_corner_nlos_structure(backend):
    # radar at (7,0.5) looks at 30 deg: far wall x=10 (LOS), then the inner wall x=8 of corridor B
    # at y=3.385 (hidden behind the corner at (8,2): NLOS), then x=10 again at y=4.54 (visible: LOS)
    sc = RayScene(*l_corridor(), backend=backend)
    o = np.array([[7.0, 0.5, 0.0]])
    d = np.array([[C30, S30, 0.0]])
    res = sc.trace(o, d, max_bounces=3)
    step = 2.0 / C30
    np.testing.assert_allclose(res.range[0], [3.0 / C30, 3.0 / C30 + step, 3.0 / C30 + 2 * step], atol=1e-5)
    np.testing.assert_allclose(res.point[0, :, :2], [[10, 0.5 + 3 * np.tan(np.pi / 6)],
                                                     [8, 0.5 + 5 * np.tan(np.pi / 6)],
                                                     [10, 0.5 + 7 * np.tan(np.pi / 6)]], atol=1e-5)
    assert res.label[0].tolist() == [Label.LOS_STRUCTURE, Label.NLOS_STRUCTURE, Label.LOS_STRUCTURE]
    assert not res.hit_dynamic.any()


@pytest.mark.parametrize("backend", BACKENDS)
def test_human_box_los_and_nlos(backend):
    sc = RayScene(*l_corridor(), backend=backend)
    o = np.array([[7.0, 0.5, 0.0], [8.4, 0.5, 0.0], [8.4, 0.5, 0.0]])
    d = np.array([[C30, S30, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    res = sc.trace(o, d, max_bounces=3, dynamic=HUMAN)
    # beam 0: wall x=10 at y=2.232 (LOS), then the human's face y=3.2 seen only via the wall (NLOS)
    t2 = (3.2 - (0.5 + 3 * np.tan(np.pi / 6))) / S30
    assert res.range[0, 1] == pytest.approx(3.0 / C30 + t2, abs=1e-5)
    assert res.label[0, :2].tolist() == [Label.LOS_STRUCTURE, Label.NLOS_HUMAN]
    assert res.hit_dynamic[0].tolist()[:2] == [False, True]
    assert res.semantic[0, 1] == sc.human_class
    # beam 1: straight at the human (LOS human), reflected back to the wall y=0 (seen: LOS structure)
    assert res.range[1, 0] == pytest.approx(2.7, abs=1e-5)
    assert res.label[1, :2].tolist() == [Label.LOS_HUMAN, Label.LOS_STRUCTURE]
    assert res.range[1, 1] == pytest.approx(2.7 + 3.2, abs=1e-5)
    # beam 2: wall y=0 first, then back up the corridor to the human: its face y=3.2 is in view
    assert res.label[2, :2].tolist() == [Label.LOS_STRUCTURE, Label.LOS_HUMAN]
    # the static scene is untouched: without the human beam 1 reaches the end wall y=10
    res0 = sc.trace(o[1:2], d[1:2], max_bounces=1)
    assert res0.range[0, 0] == pytest.approx(9.5, abs=1e-5) and res0.label[0, 0] == Label.LOS_STRUCTURE
    hit = sc.cast(o, d, dynamic=HUMAN)
    assert hit.hit_dynamic.tolist() == [False, True, False]
    assert hit.t[1] == pytest.approx(2.7, abs=1e-5)


def test_human_occludes_los_check():
    # radar sees its own bounce-2 point on wall y=0 only if the human does not stand in between
    v, f = l_corridor()
    sc = RayScene(v, f)
    o = np.array([[2.0, 1.0, 0.0]])
    d = unit([[1.0, 1.0, 0.0]])  # hits y=2 at x=3 (LOS), then y=0 at x=5
    res = sc.trace(o, d, max_bounces=2)
    assert res.label[0].tolist() == [Label.LOS_STRUCTURE, Label.LOS_STRUCTURE]
    blocker = box([3.4, 0.4, -1], [3.6, 0.6, 1])  # on the segment (2,1)->(5,0)? y=1-(x-2)/3 -> 0.53 at x=3.4
    res = sc.trace(o, d, max_bounces=2, dynamic=blocker)
    assert res.label[0].tolist() == [Label.LOS_STRUCTURE, Label.NLOS_STRUCTURE]


@pytest.mark.skipif(len(BACKENDS) < 2, reason="needs two backends")
def test_backends_agree():
    v, f = merge(l_corridor(), box([4.0, 0.8, -1], [4.3, 1.1, 0.2]))
    rng = np.random.default_rng(7)
    o = np.column_stack([rng.uniform(1, 9, 2000), rng.uniform(0.3, 1.7, 2000), rng.uniform(-0.5, 1.0, 2000)])
    d = random_dirs(2000, 8)
    res = {b: RayScene(v, f, backend=b).trace(o, d, max_bounces=3, dynamic=HUMAN) for b in BACKENDS[:2]}
    a, b = res[BACKENDS[0]], res[BACKENDS[1]]
    assert np.array_equal(np.isnan(a.range), np.isnan(b.range))
    assert np.nanmax(np.abs(a.range - b.range)) < 1e-5
    assert np.nanmax(np.abs(a.point - b.point)) < 1e-5
    assert np.array_equal(a.label, b.label) and np.array_equal(a.semantic, b.semantic)
    assert np.array_equal(a.face, b.face)


def test_los_tolerance_is_two_centimetres():
    # a thin plate in front of a wall point: an occluder 1 cm before the point is within the 2 cm
    # tolerance (LOS), one 5 cm before it is not (NLOS)
    wall = quad([5, -5, -5], [5, 5, -5], [5, 5, 5], [5, -5, 5])
    O, P = np.zeros((1, 3)), np.array([[5.0, 0.0, 0.0]])
    for gap, visible in ((0.01, True), (0.05, False)):
        plate = quad([5 - gap, -0.1, -0.1], [5 - gap, 0.1, -0.1], [5 - gap, 0.1, 0.1], [5 - gap, -0.1, 0.1])
        sc = RayScene(*merge(wall, plate))
        assert sc._visible(O, P, None).tolist() == [visible]


@pytest.mark.parametrize("backend", BACKENDS)
def test_dynamic_mesh_larger_than_static_scene(backend):
    # face ids of the dynamic mesh exceed the static face count: normals must come from the right mesh
    v, f = box(LO, HI)
    hv, hf = box([1.0, -0.3, -0.5], [1.4, 0.3, 0.9])
    reps = 50  # the same box 50 times (600 faces) -> hits land on faces >= 12
    dv = np.concatenate([hv] * reps)
    df = np.concatenate([hf + 8 * i for i in range(reps)])
    d = np.array([[1.0, 0, 0], [1.0, 0.1, 0.05], [-1.0, 0, 0]])
    res = RayScene(v, f, backend=backend).trace(np.zeros((3, 3)), unit(d), max_bounces=2, dynamic=(dv, df))
    assert res.hit_dynamic[:2, 0].all() and not res.hit_dynamic[2, 0]
    np.testing.assert_allclose(res.range[0], [1.0, 4.0], atol=1e-5)  # human face x=1, back to wall x=-2
    np.testing.assert_allclose(res.normal[0, 0], [-1, 0, 0], atol=1e-6)
    assert res.label[0].tolist() == [Label.LOS_HUMAN, Label.LOS_STRUCTURE]


def test_degenerate_faces_are_ignored_and_indices_kept():
    v, f = box(LO, HI)
    # prepend zero-area faces (repeated vertex, collinear points) in front of the real ones
    v2 = np.concatenate([v, [[0.5, 0, 0], [0.6, 0, 0], [0.7, 0, 0]]])
    bad = np.array([[8, 8, 9], [8, 9, 10]])
    f2 = np.concatenate([bad, f])
    d = random_dirs(200, 11)
    ref = trace(v, f, np.zeros((200, 3)), d, max_range=100)
    res = trace(v2, f2, np.zeros((200, 3)), d, max_range=100)
    np.testing.assert_array_equal(res["face"], np.where(ref["face"] >= 0, ref["face"] + 2, -1))
    np.testing.assert_allclose(res["range"], ref["range"], atol=1e-6)
    hit = res["face"] >= 0
    np.testing.assert_allclose(np.linalg.norm(res["normal"][hit], axis=-1), 1.0, atol=1e-6)


def _equal(a, b):
    """Same arrays to the bit (NaN where NaN)."""
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


@pytest.mark.parametrize("backend", BACKENDS)
def test_culled_human_casts_equal_the_straightforward_trace(backend):
    """Casting the human only for rays whose segment meets its grown box (the fast path) gives every
    array of the trace identical to casting every ray against it, on rays aimed at, past and along
    the human's box: origins inside it, axis-parallel directions (zero components), grazing rays."""
    rng = np.random.default_rng(7)
    hv, hf = box([3.3, 0.6, -0.8], [3.7, 1.0, 0.9])
    hv = hv + rng.normal(scale=0.02, size=hv.shape)  # not axis-aligned faces
    o = np.concatenate([rng.uniform([0.5, 0.3, -0.5], [9.5, 1.7, 0.5], size=(1500, 3)),
                        np.tile([3.5, 0.8, 0.0], (100, 1)),          # inside the human's box
                        np.tile([3.3 - 0.01, 0.6, 0.0], (100, 1))])  # on its grown face plane
    d = np.concatenate([random_dirs(1500, 8), random_dirs(100, 9), np.repeat(np.eye(3), 34, axis=0)[:100]])
    d[:300:3, 2] = 0.0  # horizontal rays: one zero component
    sc = RayScene(*l_corridor(), backend=backend)
    fast = sc.trace(o, d, max_bounces=3, dynamic=(hv, hf)).as_dict()
    assert fast["hit_dynamic"].any() and fast["hit_dynamic"][:, 1:].any()  # the human is seen, directly and via bounces
    assert (fast["label"] == Label.NLOS_HUMAN).any() or (fast["label"] == Label.NLOS_STRUCTURE).any()
    sc.cull_dynamic = False
    plain = sc.trace(o, d, max_bounces=3, dynamic=(hv, hf)).as_dict()
    for k in fast:
        assert _equal(fast[k], plain[k]), k


def test_meets_box_keeps_every_ray_that_hits_the_mesh_first():
    """Conservative culling: every ray whose dynamic hit comes before tmax is kept."""
    trm = __import__("holodata.raytrace.trace", fromlist=["_meets_box"])
    rng = np.random.default_rng(3)
    hv, hf = box([-0.3, -0.2, -0.9], [0.3, 0.2, 0.9])
    g = trm._Geometry(hv, hf, "open3d" if "open3d" in BACKENDS else BACKENDS[0], 0)
    rays = np.empty((20000, 6), np.float32)
    rays[:, :3] = rng.uniform(-3, 3, size=(20000, 3))
    rays[:, 3:] = random_dirs(20000, 4)
    rays[::2, 3:] = rng.uniform([-0.35, -0.25, -1.0], [0.35, 0.25, 1.0], size=(10000, 3)) - rays[::2, :3]  # at the box
    rays[::7, 3 + 0] = 0.0  # zero components
    rays[:, 3:] /= np.linalg.norm(rays[:, 3:], axis=1, keepdims=True)
    tmax = rng.uniform(0.0, 4.0, size=20000).astype(np.float32)
    t, _ = g.backend.cast6(rays)
    kept = np.zeros(len(rays), bool)
    kept[trm._meets_box(rays[:, :3].T, rays[:, 3:].T, tmax, g.box)] = True
    first = t < tmax
    assert first.sum() > 2000 and (~kept).sum() > 5000  # both cases occur
    assert not (first & ~kept).any()


def _both_paths(sc, o, d, **kw):
    """The trace by the compiled kernels and by the numpy reference path."""
    sc.compiled = True
    fast = sc.trace(o, d, **kw).as_dict()
    sc.compiled = False
    ref = sc.trace(o, d, **kw).as_dict()
    sc.compiled = True
    return fast, ref


@pytest.mark.parametrize("backend", BACKENDS)
def test_compiled_bounces_equal_the_numpy_path(backend):
    """The numba kernels (_kernels.py) give every array of the trace identical to the bit to the
    numpy reference path: random rays in a box room with a human (direct and culled human hits,
    NLOS labels), a max_range that cuts bounces, a float64 max_range (compared in float64), and
    grazing rays between coplanar grids (both paths share the float64 recast of self-hits, which
    these rays do not reach on this machine)."""
    rng = np.random.default_rng(11)
    room = box(LO, HI)
    hv, hf = box([0.8, -0.3, -1.0], [1.2, 0.1, 0.7])
    hv = hv + rng.normal(scale=0.02, size=hv.shape)
    sc = RayScene(*room, backend=backend)
    o = rng.uniform(LO + 0.1, HI - 0.1, size=(3000, 3))
    d = random_dirs(3000, 12)
    d[::5, 2] = 0.0
    for kw in (dict(max_bounces=3, dynamic=(hv, hf)), dict(max_bounces=4, max_range=7.5),
               dict(max_bounces=3, max_range=np.float64(6.100000001), dynamic=(hv, hf))):
        fast, ref = _both_paths(sc, o, d, **kw)
        if "dynamic" in kw:  # the human is seen and shadows walls (NLOS in the convex room)
            assert fast["hit_dynamic"].any() and (fast["label"] == Label.NLOS_STRUCTURE).any()
        assert np.isnan(fast["range"][:, -1]).any() and not np.isnan(fast["range"][:, -1]).all()
        for k in fast:
            assert _equal(fast[k], ref[k]), (k, kw)
    # grazing rays between two coplanar grids: the recast of float32 self-hits runs on both paths
    v, f = merge(grid_plane(0.0, 50.0, 60), grid_plane(0.3, 50.0, 60))
    sc = RayScene(v, f, backend=backend)
    eps = np.deg2rad(rng.uniform(0.05, 3.0, size=2000))
    az = rng.uniform(0, 2 * np.pi, size=2000)
    d = np.stack([np.cos(eps) * np.cos(az), np.cos(eps) * np.sin(az), -np.sin(eps)], 1)
    o = np.column_stack([rng.uniform(-5, 5, size=(2000, 2)), np.full(2000, 0.15)])
    fast, ref = _both_paths(sc, o, d, max_bounces=3, max_range=100.0)
    assert np.isfinite(fast["range"][:, 2]).sum() > 1000
    for k in fast:
        assert _equal(fast[k], ref[k]), k


def test_compiled_meets_box_equals_the_numpy_slab_test():
    """_kernels.meets_box keeps exactly the rays trace._meets_box keeps, with zero direction
    components, origins on the box's faces (0 * inf) and scalar or per-ray tmax."""
    from holodata.raytrace import _kernels
    from holodata.raytrace.trace import _meets_box

    rng = np.random.default_rng(5)
    box_ = np.array([[-0.3, -0.2, -0.9], [0.3, 0.2, 0.9]], np.float32)
    rays = np.empty((20000, 6), np.float32)
    rays[:, :3] = rng.uniform(-2, 2, size=(20000, 3))
    rays[:, 3:] = random_dirs(20000, 6)
    rays[::3, 3] = 0.0
    rays[1::5, 4:6] = 0.0
    rays[::11, 0] = box_[0, 0]  # on a face plane
    rays[::13, 1] = box_[1, 1]
    tmax = rng.uniform(0.0, 3.0, size=20000).astype(np.float32)
    for tm, tk in ((tmax, tmax), (np.float32(1), np.ones(1, np.float32))):
        ref = _meets_box(rays[:, :3].T, rays[:, 3:].T, tm, box_)
        got = _kernels.meets_box(rays, tk, box_)
        assert 300 < len(ref) < 19000
        assert np.array_equal(got, ref)


@pytest.mark.parametrize("backend", BACKENDS)
def test_fixed_rays_equal_a_full_cast_for_every_human_pose(backend):
    """A fixed camera's rays (:class:`FixedRays`: the static scene cast once, then only the rays that may
    meet the human's box) give exactly what casting every ray against scene + human gives, for a
    human walking across the view, touching the camera's origin, out of view, and none at all."""
    rng = np.random.default_rng(11)
    sc = RayScene(*l_corridor(), backend=backend)
    o = np.tile([1.0, 1.0, 0.2], (4000, 1))
    d = random_dirs(4000, 12)
    d[::5, 2] = 0.0                                    # horizontal rays: one zero component
    fixed = sc.fixed_rays(o, d)
    hv0, hf = box([-0.2, -0.2, -1.0], [0.2, 0.2, 0.8])
    seen = 0
    for x, y in ((3.0, 1.0), (5.5, 0.7), (8.9, 4.0), (1.1, 1.0), (40.0, 40.0)):
        hv = hv0 + [x, y, 0.0] + rng.normal(scale=0.02, size=hv0.shape)
        got, want = fixed.cast((hv, hf)), sc.cast(o, d, dynamic=(hv, hf))
        seen += int(want.hit_dynamic.sum())
        for k in ("t", "normal", "face", "hit_dynamic"):
            assert _equal(getattr(got, k), getattr(want, k)), (x, y, k)
    assert seen > 100                                  # the human was in view
    for k in ("t", "normal", "face", "hit_dynamic"):
        assert _equal(getattr(fixed.cast(None), k), getattr(sc.cast(o, d), k)), k
