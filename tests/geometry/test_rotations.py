"""holodata.geometry.rotations against scipy's Rotation and Slerp (an independent implementation)."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from holodata.geometry.rotations import matrix_from_quat, quat_from_matrix, quat_multiply, slerp


def test_quaternions_and_matrices_match_scipy_including_half_turns():
    r = Rotation.concatenate([Rotation.random(500, random_state=0),
                              Rotation.from_rotvec([[np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi], [0, 0, 0],
                                                    [1e-9, 0, 0], [0, 0, np.pi - 1e-9]])])
    M = r.as_matrix()
    assert np.abs(quat_from_matrix(M) - Rotation.from_matrix(M).as_quat()).max() < 1e-14   # the same sign too
    assert np.abs(matrix_from_quat(r.as_quat()) - M).max() < 1e-14
    assert quat_from_matrix(M[:4].reshape(2, 2, 3, 3)).shape == (2, 2, 4)
    a, b = Rotation.random(2, random_state=1)
    assert np.allclose(matrix_from_quat(quat_multiply(a.as_quat(), b.as_quat())), (a * b).as_matrix(), atol=1e-14)


def test_slerp_matches_scipy_on_large_and_small_steps():
    rng = np.random.default_rng(2)
    ts = np.cumsum(rng.uniform(0.1, 1.0, 100))
    big = Rotation.random(100, random_state=3)                                  # up to half turns apart
    small = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.01, (100, 3)), 0))   # a trajectory's steps
    t = np.r_[ts[0], ts[-1], ts[7], rng.uniform(ts[0], ts[-1], 3000)]
    for r in (big, small):
        ref = Slerp(ts, r)(t).as_matrix()
        got = matrix_from_quat(slerp(ts, r.as_quat(), t))
        assert np.abs(got - ref).max() < 1e-13
    # equal keyframes and the shorter way round (a keyframe's quaternion given with the other sign)
    q = np.array([[0, 0, np.sin(0.1), np.cos(0.1)], [0, 0, -np.sin(0.3), -np.cos(0.3)]])
    mid = slerp(np.array([0.0, 1.0]), q, np.array([0.5]))
    assert np.allclose(matrix_from_quat(mid)[0], Rotation.from_rotvec([0, 0, 0.4]).as_matrix(), atol=1e-14)
    same = slerp(np.array([0.0, 1.0]), np.array([[0, 0, 0, 1.0], [0, 0, 0, 1.0]]), np.array([0.3]))
    assert np.allclose(same, [[0, 0, 0, 1]])
