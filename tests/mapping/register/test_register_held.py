"""register's held directions (issue 23, "a confident wrong answer"): along a direction the view
does not constrain the result is the guess's camera pose, never a slide the data did not measure
that the reported uncertainty leaves out."""
from __future__ import annotations

import numpy as np
import pytest
from _corridor import corridor as make_corridor

from holodata.conventions import transform_points


def _yawed(T: np.ndarray, deg: float) -> np.ndarray:
    """``T`` (4,4) turned ``deg`` about the vertical through its own position."""
    from scipy.spatial.transform import Rotation

    out = T.copy()
    out[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix() @ T[:3, :3]
    return out


@pytest.mark.parametrize("deg", [3.0, -3.0])
def test_a_measured_turn_does_not_carry_the_camera_along_a_held_direction(deg):
    """A camera near one wall of a corridor it sees end-on: along the corridor nothing is measured,
    the yaw is. The guess's camera position is exact, its yaw ``deg`` off: the ICP turns about the
    overlap's centroid, 0.8 m across the corridor from the camera, and holding that centroid at the
    guess moved the camera 0.8 m × 3° = 4.2 cm along the corridor while the result reported the
    guess's 1 cm (before: accepted 4.2 cm off)."""
    from holodata.mapping.register import RegisterConfig, register_extrinsic

    corridor = make_corridor(np.random.default_rng(1))
    T_true = np.eye(4)
    T_true[:3, 3] = [0.5, 0.8, 1.2]
    near = (corridor[:, 0] > 1.5) & (corridor[:, 0] < 4.5)
    cam = transform_points(np.linalg.inv(T_true), corridor[near])
    init = _yawed(T_true, deg)
    r = register_extrinsic(cam, corridor, init, RegisterConfig(mesh_target=False, guess_std_m=0.01),
                           allow_fallback=False)
    a = r.attempts[0]
    assert a["frozen_directions"] >= 1
    assert any(h.startswith("translation along (1.00, 0.0") for h in a["held_directions"]), a["held_directions"]
    # along the held direction the camera is where the guess put it, or the uncertainty says how far not
    moved = abs(r.T[0, 3] - init[0, 3])
    assert moved <= a["uncertainty_m"] - 0.01 + 1e-4, (moved, a)
    # the yaw was measured, and the guess's camera position (exact here) is kept along the corridor
    assert np.degrees(abs(np.arctan2(r.T[1, 0], r.T[0, 0]))) < 0.2
    assert r.accepted and np.linalg.norm(r.T[:3, 3] - T_true[:3, 3]) < 0.01, (r.T[:3, 3], a)
    # the same guess from TF onto a slam map anchored 10 m away across the corridor: the guess's 3° is
    # more than a map's turn (anchor_max_deg 0.5), so the turn was not read and may move the camera
    # along the corridor by up to 0.5° × 10 m: reported beside the uncertainty as that bound
    anchor = T_true[:3, 3] - [0.0, 10.0, 0.0]
    r = register_extrinsic(cam, corridor, init, RegisterConfig(mesh_target=False, guess_std_m=0.01),
                           allow_fallback=False, anchor=anchor)
    a = r.attempts[0]
    assert a["anchor_turn"]["applied"] is False
    assert a["map_turn_reach_m"] == pytest.approx([np.radians(0.5) * 10.0], rel=0.02)
    assert a["uncertainty_m"] == pytest.approx(0.01, rel=0.02)


def test_hold_at_guess_puts_the_camera_back_and_reports_what_it_could_not():
    """:func:`hold_at_guess` moves a pose along the held directions (given about a far centroid) to
    where the guess's camera lies along them, even from a pose turned 20° away; the slide it returns
    is how far the camera still lies from the guess along them (0 here)."""
    from scipy.spatial.transform import Rotation

    from holodata.mapping.register.extrinsic import hold_at_guess

    guess = np.eye(4)
    guess[:3, 3] = [0.5, 0.8, 1.2]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    T[:3, 3] = [0.62, 0.75, 1.25]
    V = np.zeros((6, 1))
    V[3, 0] = 1.0                                      # translation along x, about a centroid 3 m away
    held = (V, np.array([3.5, 0.0, 1.25]), 2.0)
    H, slide = hold_at_guess(T, guess, held)
    assert abs(H[0, 3] - guess[0, 3]) < 1e-5 and np.abs(slide).max() < 1e-5
    np.testing.assert_allclose(H[:3, :3], T[:3, :3], atol=1e-9)          # the turn is kept
    np.testing.assert_allclose(H[1:3, 3], T[1:3, 3], atol=1e-9)          # and the other directions
    assert hold_at_guess(T, guess, None)[0] is T


def test_map_turn_reach_is_the_turn_times_the_lever_across_the_held_direction():
    """A SLAM map anchored at a TF pose is the TF world turned about the anchor; where that turn was not
    read, the TF guess's camera is off in the map by up to anchor_max_deg × its distance from the
    anchor, along the held direction when the lever is across it, not at all when along it."""
    from holodata.mapping.register.extrinsic import map_turn_reach

    V = np.zeros((6, 1))
    V[3, 0] = 1.0                                      # translation along x, about a centroid 3 m away
    held = (V, np.array([3.0, 10.0, 1.2]), 2.0)
    across = map_turn_reach(held, np.array([0.0, 10.0, 1.2]), np.zeros(3), 0.5)
    assert across == pytest.approx([np.radians(0.5) * 10.0], rel=1e-6)
    along = map_turn_reach(held, np.array([10.0, 0.0, 1.2]), np.zeros(3), 0.5)
    assert along == pytest.approx([0.0], abs=1e-9)
