"""The motion cue's numeric core (holodata.evaluate.motion): analytic cases."""
import numpy as np

from holodata.evaluate.motion import MotionCue, change_at_returns, merge_centres, moving_person, persistence


def test_change_at_returns_reads_the_bin_of_each_return_and_gates_noise():
    R, H, W, dr = 40, 2, 3, 0.1
    db = np.full((R, H, W), -60.0)
    db[10, 0, 0] = 0.0                 # a strong return at 1.0-1.1 m in beam (0, 0)
    other = db.copy()
    other[11, 0, 0] = -30.0            # the neighbouring bin changed by 30 dB in the other rotation
    other[25, 1, 2] = 0.0              # a change where this rotation has only noise
    ranges = np.full((3, H, W), np.nan)
    ranges[1, 0, 0] = 1.05             # bin 10: its ±1 bins hold the 30 dB change
    ranges[2, 1, 2] = 2.55             # bin 25: changed, but under the SNR gate in this rotation
    ranges[0, 0, 1] = 1.05             # nothing changed there
    c = change_at_returns(db, other, ranges, dr, min_snr_db=15.0)
    assert c.shape == (3, H, W)
    assert c[1, 0, 0] == 30.0
    assert c[2, 1, 2] == 0.0 and c[0, 0, 1] == 0.0
    assert (c[np.isnan(ranges)] == 0).all()


def test_persistence_is_the_capped_nearest_distance():
    a = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]])
    b = np.array([[0.0, 0, 0.1], [1.3, 0, 0]])
    np.testing.assert_allclose(persistence(a, b, cap=0.5), [0.1, 0.3, 0.5])
    np.testing.assert_allclose(persistence(a, np.zeros((0, 3)), cap=0.5), [0.5] * 3)
    assert persistence(np.zeros((0, 3)), b, 0.5).shape == (0,)


def test_moving_person_picks_the_moving_cluster_over_walls_and_noise():
    rng = np.random.default_rng(0)
    person = np.array([3.0, 2.0, 1.0]) + rng.normal(0, 0.08, (30, 3))        # a walking person: changed, moved
    wall = np.c_[np.full(400, 5.0), rng.uniform(-3, 3, 400), rng.uniform(0, 2.5, 400)]  # changed a little, persists
    noise = rng.uniform(-6, 6, (60, 3))                                      # changed, moved, but scattered
    P = np.vstack([person, wall, noise])
    change = np.r_[np.full(30, 35.0), np.full(400, 30.0), np.full(60, 40.0)]
    persist = np.r_[np.full(30, 0.4), np.full(400, 0.01), np.full(60, 0.5)]
    c = moving_person(P, change, persist, MotionCue())
    assert c.shape == (1, 3) and np.linalg.norm(c[0] - [3.0, 2.0, 1.0]) < 0.1
    # a person standing still (no persistence change) is not found, nor a weak cluster
    assert moving_person(P, change, np.r_[np.full(30, 0.01), persist[30:]], MotionCue()).shape == (0, 3)
    assert moving_person(P, change, persist, MotionCue(min_score=1e6)).shape == (0, 3)


def test_merge_centres_adds_only_new_people():
    base = np.array([[0.0, 0, 0]])
    out = merge_centres(base, np.array([[0.2, 0, 0], [2.0, 0, 0]]))
    np.testing.assert_allclose(out, [[0, 0, 0], [2, 0, 0]])
    assert merge_centres(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)
