"""The registered person seen from a camera mounted above them and walking across its view (issue 43
point 4): analytic bodies, no recording.

A camera high on a wall (2.4 m) sees a standing body's feet 0.6 m farther (3-D range) than its torso;
body_only's depth cut must be horizontal, or the legs go and the solid's centre rises 20 cm. A person
walking across the view shows their side: the far shoulder, arm and leg hide behind the near ones, and
the solid must be as deep as the body is broad (side_back), where it was as deep as the chest."""
import numpy as np

from holodata.mapping.register import RegisterConfig
from holodata.mapping.register.humans import ColumnShape, body_columns, column_centroid
from holodata.mapping.register.steps import body_only
from holodata.mapping.register.tracks import side_back, track_heading_velocity

CFG = RegisterConfig()


def test_body_only_keeps_the_legs_under_a_high_camera():
    """A 1.75 m column of points 0.3 m across, 2.5 m (plan) from a camera 2.4 m up: every point above
    the floor margin stays; a stereo streak 0.8 m behind the body along its ray still goes. The 3-D range
    cut (before) kept nothing below 0.4 m: the feet are 0.6 m farther than the torso."""
    eye = np.array([0.0, 0.0, 2.4])
    rng = np.random.default_rng(0)
    z = rng.uniform(0.0, 1.75, 4000)
    ang = rng.uniform(-np.pi / 2, np.pi / 2, len(z))          # the half facing the camera
    body = np.stack([2.5 - 0.15 * np.cos(ang), 0.15 * np.sin(ang), z], 1)
    ray = body[0] - eye
    streak = body[0] + 0.8 * ray / np.linalg.norm(ray)          # along the ray, behind the body
    qw = np.vstack([body, streak])
    keep = body_only(qw, np.ones(len(qw), bool), eye, 0.0, CFG)
    above = body[:, 2] > CFG.floor_margin_m
    assert keep[:-1][above].all()
    assert not keep[:-1][~above].any()                       # the floor margin still applies
    assert not keep[-1]                                      # and the streak still goes


def _side_on_torso(cx: float, breadth: float, depth: float, fx: float = 300.0, eye_z: float = 1.2):
    """The returns a pinhole camera at (0, 0, ``eye_z``) looking along +x sees on an elliptic cylinder
    (z 0.9-1.5 m) centred at (``cx``, 0), ``breadth`` m along x (across the heading: the person walks
    along y, across the view) and ``depth`` m along y: world points (N,3), rows, cols, optical depths."""
    v, u = np.mgrid[0:200, 0:200]
    d = np.stack([np.ones(v.shape), -(u - 99.5) / fx, -(v - 99.5) / fx], -1).reshape(-1, 3)
    ax, ay = breadth / 2, depth / 2
    # ((t dx - cx)/ax)^2 + (t dy / ay)^2 = 1
    a = (d[:, 0] / ax) ** 2 + (d[:, 1] / ay) ** 2
    b = -2 * cx * d[:, 0] / ax ** 2
    c = (cx / ax) ** 2 - 1
    disc = b * b - 4 * a * c
    hit = disc > 0
    t = np.where(hit, (-b - np.sqrt(np.where(hit, disc, 0))) / (2 * a), np.nan)
    p = t[:, None] * d + np.array([0.0, 0.0, eye_z])
    hit &= (p[:, 2] > 0.9) & (p[:, 2] < 1.5)
    rows, cols = v.reshape(-1)[hit], u.reshape(-1)[hit]
    return p[hit], rows, cols, t[hit] * d[hit, 0]


def test_side_back_is_the_breadth_seen_across_the_heading():
    """Walking across the view: the ratio less 1; along it, or standing: nothing."""
    t = np.arange(21) * 100_000_000
    eye = np.array([0.0, 0.0, 1.2])
    across = np.stack([np.full(21, 3.0), 0.7 * t / 1e9 - 0.7, np.full(21, 1.0)], 1)
    along = np.stack([2.0 + 0.7 * t / 1e9, np.zeros(21), np.full(21, 1.0)], 1)
    still = np.array([3.0, 0.0, 1.0]) + 0.01 * np.random.default_rng(1).normal(size=(21, 3))
    r = CFG.breadth_m / CFG.thickness_m
    np.testing.assert_allclose(track_heading_velocity(across, t)[10], [0.0, 0.7], atol=1e-9)
    assert abs(side_back(across, t, eye, r)[10] - (r - 1)) < 0.01
    assert abs(side_back(along, t, eye, r)[10]) < 1e-9
    assert side_back(still, t, eye, r).max() < 0.1 * (r - 1)


def test_side_on_torso_solid_is_centred_on_the_body():
    """A torso 0.45 m broad and 0.22 m deep seen side-on 3 m away: the columns' centre of mass lies on
    the ellipse's centre along the view within 2 cm; modelled as deep as the chest (before), 11 cm
    toward the camera."""
    cx, breadth, depth = 3.0, CFG.breadth_m, CFG.thickness_m
    p, rows, cols, dz = _side_on_torso(cx, breadth, depth)
    eye = np.array([0.0, 0.0, 1.2])
    side = CFG.breadth_m / CFG.thickness_m - 1.0
    span, px, down = body_columns(p, rows, cols, dz, eye, 300.0,
                                  ColumnShape(CFG.min_thickness_m, CFG.thickness_m, side_frac=side))
    c = column_centroid(p, eye, span, px, down)
    assert abs(c[0] - cx) < 0.02
    span0, px0, down0 = body_columns(p, rows, cols, dz, eye, 300.0, ColumnShape(CFG.min_thickness_m, CFG.thickness_m))
    assert column_centroid(p, eye, span0, px0, down0)[0] < cx - 0.08


def test_limbs_side_by_side_are_not_deepened():
    """Two legs apart in stride (two runs in each row) are each seen whole: their columns are as deep
    as the legs are wide, side_frac or not; one leg alone in its rows (the other hidden behind it) is
    deepened."""
    eye = np.array([0.0, 0.0, 1.2])
    legs = [_side_on_torso(3.0, 0.15, 0.15)]
    p1, r1, c1, d1 = legs[0]
    shift = 0.35                                                  # the second leg 35 cm to the side
    p2 = p1 + np.array([0.0, shift, 0.0])
    c2 = c1 - int(round(shift / 3.0 * 300.0))
    two = (np.vstack([p1, p2]), np.r_[r1, r1], np.r_[c1, c2], np.r_[d1, d1])
    span2, _, _ = body_columns(*two, eye, 300.0, ColumnShape(CFG.min_thickness_m, CFG.thickness_m, side_frac=1.0))
    assert np.abs(span2[:, 1] - span2[:, 0]).max() < 0.17
    span1, _, _ = body_columns(p1, r1, c1, d1, eye, 300.0, ColumnShape(CFG.min_thickness_m, CFG.thickness_m, side_frac=1.0))
    assert np.median(span1[:, 1] - span1[:, 0]) > 0.2
