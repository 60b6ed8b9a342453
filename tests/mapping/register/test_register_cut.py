"""A person partly hidden behind a corner (issue 43 point 4): the visible part's centre is not the
person's, so such a frame is placed on the line through the track's whole frames. Analytic images and
tracks, no recording."""
import numpy as np

from holodata.mapping.register import RegisterConfig
from holodata.mapping.register.humans import silhouette_cut
from holodata.mapping.register.steps import track_smoothing
from holodata.mapping.register.tracks import cut_prediction


def _person(c0: int, c1: int, rows=range(10, 30), depth: float = 4.0):
    r, c = np.meshgrid(np.arange(rows.start, rows.stop), np.arange(c0, c1 + 1), indexing="ij")
    return r.ravel(), c.ravel(), np.full(r.size, depth)


def test_silhouette_cut_by_a_nearer_wall_not_by_a_farther_one():
    """A person at 4 m before a wall at 6 m: not cut. A corner at 2 m right of the silhouette on the
    upper half of its rows: half the rows are cut; next to the image's edge: all."""
    static = np.full((40, 60), 6.0)
    r, c, d = _person(20, 27)
    assert silhouette_cut(r, c, d, static, 3, 0.12) == 0.0
    occ = static.copy()
    occ[:20, 28:] = 2.0                        # a corner in front of the person's right side, rows 0-19
    assert silhouette_cut(r, c, d, occ, 3, 0.12) == 0.5
    occ2 = static.copy()
    occ2[:, 30:] = 2.0                         # two pixels of background, then the corner: within reach 3
    assert silhouette_cut(r, c, d, occ2, 3, 0.12) == 1.0
    assert silhouette_cut(r, c, d, occ2, 2, 0.12) == 0.0
    occ3 = static.copy()
    occ3[:, 28:] = 3.95                        # nearer, but within the margin: the person's own depth
    assert silhouette_cut(r, c, d, occ3, 3, 0.12) == 0.0
    r, c, d = _person(0, 5)
    assert silhouette_cut(r, c, d, static, 3, 0.12) == 1.0     # the image's left side
    assert silhouette_cut(r[:0], c[:0], d[:0], static, 3, 0.12) == 0.0


def test_cut_prediction_extrapolates_the_walk_into_the_corner():
    """A walk at 1.2 m/s along y, 10 Hz; the last 4 frames are cut and their visible centres lag 0.3 m
    behind: predicted on the line through the whole frames (one-sided), to 1e-9; the whole frames and a
    cut frame with too few whole ones around it get NaN."""
    t = np.arange(30) * 100_000_000
    truth = np.stack([np.full(30, 3.0), 1.2 * t / 1e9, np.full(30, 0.9)], 1)
    cut = np.zeros(30, bool)
    cut[26:] = True
    seen = truth.copy()
    seen[cut, 1] -= 0.3
    p = cut_prediction(seen, t, cut, 1.0)
    assert np.allclose(p[cut], truth[cut], atol=1e-9)
    assert np.isnan(p[~cut]).all()
    lone = np.zeros(30, bool)
    lone[[0, 1, 2, 3, 5]] = True               # frame 4 the only whole one near frames 0-3
    seen2 = truth.copy()
    seen2[6:] = np.nan
    assert np.isnan(cut_prediction(seen2, t, lone, 0.3)[:4]).all()


def test_track_smoothing_moves_a_cut_frame_onto_the_track():
    """Frames of one point each; the cut frames' shifts move them onto the walk's line, the whole
    frames are not moved by the cut ones (no smoothing: a straight walk, no noise)."""
    cfg = RegisterConfig()
    t = np.arange(20) * 100_000_000
    truth = np.stack([np.full(20, 3.0), 1.0 * t / 1e9, np.full(20, 0.9)], 1)
    pts = [truth[k][None] for k in range(20)]
    pts[18] = pts[18] + [0, -0.25, -0.2]
    pts[19] = pts[19] + [0, -0.4, -0.3]
    cols = [(np.zeros((1, 2)), np.array([0.05]), None)] * 20
    cuts = np.zeros(20)
    cuts[18:] = [0.6, 0.9]
    sh = track_smoothing(pts, cols, np.zeros((20, 3)), np.array([0.0, 0.0, 1.5]), t, cfg, cuts)
    assert np.allclose(pts[18][0] + sh[18], truth[18], atol=1e-6)
    assert np.allclose(pts[19][0] + sh[19], truth[19], atol=1e-6)
    assert np.allclose(sh[:18], 0.0, atol=1e-6)
    sh0 = track_smoothing(pts, cols, np.zeros((20, 3)), np.array([0.0, 0.0, 1.5]), t, cfg, np.zeros(20))
    assert np.linalg.norm(pts[19][0] + sh0[19] - truth[19]) > 0.1      # without the cut: left where seen


def test_frame_cuts_ignore_a_nearer_static_depth_within_the_depth_noise():
    """A far person (8 m) on a noisy camera (σ = 0.005 z² = 0.32 m there): a static depth 0.3 m nearer
    beside them is noise, not a corner (with the noise model: not cut; without it, fg_min_m alone: cut);
    a corner 3 m nearer cuts with either."""
    from holodata.mapping.register.steps import Picks, frame_cuts

    cfg = RegisterConfig()
    r, c, d = _person(20, 27, depth=8.0)
    near = np.full((40, 60), 9.0)
    near[:, 28:] = 7.7
    corner = np.full((40, 60), 9.0)
    corner[:, 28:] = 5.0
    picks = Picks([np.zeros((len(r), 3))], [(np.zeros((len(r), 3)), r, c, d)], None, 0)
    assert frame_cuts(picks, near, cfg, 0.005)[0] == 0.0
    assert frame_cuts(picks, near, cfg, None)[0] == 1.0
    assert frame_cuts(picks, corner, cfg, 0.005)[0] == 1.0
