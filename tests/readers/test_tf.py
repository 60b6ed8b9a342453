"""TF buffer: static chains, inverse edges, interpolated dynamic edges, gaps, roots."""
from __future__ import annotations

import numpy as np
from _recordings import store_for, tf_msg
from scipy.spatial.transform import Rotation

from holodata.readers.tf import TransformBuffer, transform_matrix


def _T(xyz, yaw_deg=0.0):
    M = np.eye(4)
    M[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    M[:3, 3] = xyz
    return M


def test_static_chain_and_inverse():
    b = TransformBuffer()
    A, B = _T([1, 0, 0], 90), _T([0, 2, 0.5], -30)
    b.add("base_link", "radar", A, static=True)
    b.add("base_link", "/lidar", B, static=True)     # leading slash (ROS 1) is ignored
    np.testing.assert_allclose(b.lookup("base_link", "radar"), A)
    np.testing.assert_allclose(b.lookup("radar", "base_link"), np.linalg.inv(A))
    np.testing.assert_allclose(b.lookup("lidar", "radar"), np.linalg.inv(B) @ A, atol=1e-12)
    assert b.lookup("radar", "nowhere") is None
    assert b.root("radar") == "base_link"


def test_dynamic_interpolation_gap_and_message_roundtrip():
    T = store_for("mcap").types
    b = TransformBuffer(max_gap_ns=100)
    t0 = 1_000_000_000
    msgs = [tf_msg(T, "mcap", [(t0 + k * 1000, "odom", "base_link", _T([k * 1.0, 0, 0], 10 * k))]) for k in range(5)]
    for m in msgs:
        assert b.add_message(m) == 1
    b.add_message(tf_msg(T, "mcap", [(0, "map", "odom", _T([0, 0, 1]))]), static=True)
    b.add("base_link", "radar", _T([0.1, 0, 0]), static=True)
    M = b.lookup("map", "radar", t0 + 2500)
    expect = _T([0, 0, 1]) @ _T([2.5, 0, 0], 25) @ _T([0.1, 0, 0])
    np.testing.assert_allclose(M, expect, atol=1e-9)
    assert b.lookup("map", "radar", t0 + 4000 + 101) is None       # beyond the gap
    assert b.lookup("map", "radar", t0 + 4000 + 99) is not None
    assert b.lookup("map", "radar", None) is None                  # dynamic edge needs a time
    assert b.lookup("map", "radar", None, static_only=True) is None
    assert b.root("radar") == "map"
    q = msgs[1].transforms[0].transform
    np.testing.assert_allclose(transform_matrix(q), _T([1, 0, 0], 10), atol=1e-12)


def test_quaternion_matrix_and_lookup_many_agree():
    from holodata.readers.tf import quat_matrix

    q = np.random.default_rng(0).normal(size=(50, 4))
    for qq in q:
        np.testing.assert_allclose(quat_matrix(*qq), Rotation.from_quat(qq / np.linalg.norm(qq)).as_matrix(), atol=1e-12)
    np.testing.assert_array_equal(quat_matrix(0, 0, 0, 0), np.eye(3))
    b = TransformBuffer(max_gap_ns=10)
    for k in range(6):
        b.add("odom", "base", _T([k, 0.5 * k, 0], 15 * k), t_ns=100 * k)
    b.add("base", "radar", _T([0.1, 0, 0.3], 5), static=True)
    t = np.array([0, 50, 333, 500, 509, 511])
    P, ok = b.lookup_many("odom", "radar", t)
    np.testing.assert_array_equal(ok, [True, True, True, True, True, False])
    for k in range(5):
        np.testing.assert_allclose(P[k], b.lookup("odom", "radar", int(t[k])), atol=1e-12)
    assert b.lookup_many("odom", "elsewhere", t) is None
