"""Worlds, human, robot motion: geometry checks against analytic values."""
import numpy as np
import pytest

from holodata.synth.human import HumanWalk, human_mesh
from holodata.synth.motion import odometry, robot_trajectory
from holodata.synth.worlds import CLASS_ID, CORNER_TYPES, MATERIALS, hidden_from, make_world, polygon_area, triangulate_polygon


@pytest.mark.parametrize("corner", CORNER_TYPES)
def test_world_is_consistent_and_reproducible(corner):
    for seed in range(4):
        w = make_world(corner, seed=seed)
        assert w.vertices.dtype == np.float64 and w.faces.dtype == np.int32
        assert len(w.face_material) == len(w.face_class) == len(w.faces)
        assert w.face_material.max() < len(MATERIALS)
        assert 1.3 <= w.width <= 4.7 and 2.5 <= w.height <= 3.2
        for cls in ("floor", "ceiling", "wall"):
            assert (w.face_class == CLASS_ID[cls]).any()
        # floor triangles tile the outline exactly, all facing up
        fl = w.vertices[w.faces[w.face_class == CLASS_ID["floor"]]]
        up = 0.5 * np.cross(fl[:, 1] - fl[:, 0], fl[:, 2] - fl[:, 0])[:, 2]
        assert np.all(up > 0) and np.isclose(up.sum(), polygon_area(w.floor_polygon))
        ce = w.vertices[w.faces[w.face_class == CLASS_ID["ceiling"]]]
        assert np.allclose(ce[..., 2], w.height)
        w2 = make_world(corner, seed=seed)
        assert np.array_equal(w.vertices, w2.vertices) and np.array_equal(w.faces, w2.faces)
    assert make_world(corner, seed=0).width != make_world(corner, seed=1).width


def test_width_is_respected():
    w = make_world("T", width=3.3, seed=5)
    assert w.width == 3.3
    # the approach corridor walls are at y = ±width/2
    ys = np.abs(w.floor_polygon[w.floor_polygon[:, 0] < -3.0][:, 1])
    assert np.any(np.isclose(ys, 1.65))


def test_triangulation_of_concave_polygon():
    poly = np.array([[0, 0], [4, 0], [4, 4], [3, 4], [3, 1], [1, 1], [1, 4], [0, 4]], float)  # U shape, CCW
    tri = triangulate_polygon(poly)
    p = poly[tri]
    a = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    assert len(tri) == len(poly) - 2 and np.all(a > 0) and np.isclose(a.sum(), 4 * 4 - 2 * 3)


def test_plan_view_occlusion_of_an_L_corner():
    poly = np.array([[-8, -1], [2, -1], [2, 7], [0, 7], [0, 1], [-8, 1]], float)
    viewer = np.array([[-3.0, 0.0]])
    # the line from (-3,0) crosses x=0 at y = 3 * ty / (tx + 3); hidden iff that exceeds 1
    targets = np.array([[1.0, 5.0], [1.0, 1.2], [-1.0, 0.5], [1.5, 2.5]])
    expect = [True, False, False, True]
    assert hidden_from(poly, viewer, targets).tolist() == expect


def test_human_mesh_is_closed_and_sized():
    for h in (1.5, 1.95):
        v, f = human_mesh(h, 0.7)
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(e, axis=0, return_counts=True)
        assert np.all(counts == 2)  # every edge shared by exactly two triangles: closed
        tri = v[f]
        vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
        assert vol > 0  # outward orientation
        assert abs(v[:, 2].max() - h) < 0.03 * h and v[:, 2].min() < 0.1


def test_human_walk_stays_on_segment():
    w = HumanWalk(np.array([0.0, 2.0]), np.array([0.0, 4.0]), 1.0, 1.7)
    for t in np.linspace(0, 10, 41):
        p, _, _ = w.state(t)
        assert abs(p[0]) < 1e-9 and 2.0 - 1e-9 <= p[1] <= 4.0 + 1e-9
    assert np.allclose(w.state(1.0)[0], [0.0, 3.0]) and np.allclose(w.state(3.0)[0], [0.0, 3.0])


def test_robot_starts_at_rest_and_odometry_drifts():
    rng = np.random.default_rng(3)
    tr, info = robot_trajectory([-5.0, 0.0], [-1.0, 0.0], 10.0, 10**18, rng)
    xy = tr.poses[:, :2, 3]
    dt = np.diff(tr.timestamp_ns) / 1e9
    v = np.linalg.norm(np.diff(xy, axis=0), axis=1) / dt
    assert v[:10].max() < 0.05 and v.max() <= 0.5 + 1e-6 and v.max() > 0.25
    assert np.allclose(xy[-1], [-1.0, 0.0], atol=0.06)
    # the heading turns smoothly (no step where the weave fades in) and follows the path's tangent
    yaw = np.unwrap(np.arctan2(tr.poses[:, 1, 0], tr.poses[:, 0, 0]))
    assert np.degrees(np.abs(np.diff(yaw)) / dt).max() < 15.0
    moving = v > 0.1
    tangent = np.arctan2(np.diff(xy[:, 1]), np.diff(xy[:, 0]))
    off = np.median(yaw[1:][moving] - tangent[moving])            # the constant mounting offset
    assert np.abs(yaw[1:][moving] - tangent[moving] - off).max() < np.deg2rad(0.2)
    od, oinfo = odometry(tr, np.random.default_rng(4), scale_error=0.02, yaw_bias_dps=0.5)
    # odometry is relative to its start; compare travelled distance and heading drift
    T0 = tr.interpolate(od.timestamp_ns[:1])[0]
    est = T0 @ od.poses[-1]
    true = tr.interpolate(od.timestamp_ns[-1:])[0]
    err = np.linalg.norm(est[:2, 3] - true[:2, 3])
    assert 0.01 < err < 0.2 * info["distance_m"]
