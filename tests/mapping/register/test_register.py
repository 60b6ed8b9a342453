"""Camera-to-map registration and human surfaces (holodata.mapping.register)."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from holodata.evaluate.register_accuracy import (
    aligned_extrinsic_error_poses,
    extrinsic_error,
    relative_extrinsic_error,
    solid_centroid,
)
from holodata.geometry import local_plane_projection
from holodata.mapping.register import (
    ColumnShape,
    RegisterConfig,
    body_columns,
    camera_points_world,
    closed_surface,
    map_normals,
    pick_human,
    radial_speed,
    register_extrinsic,
    track_jumps,
    track_prediction,
    track_velocity,
    velocity_shift,
    voxel_boundary,
)


def _room(rng, n=60000):
    """Points on a corner of a room with a few boxes (non-degenerate for ICP): floor z=0, walls x=0 and
    y=0, ceiling z=2.5, boxes. (N,3) world."""
    parts = []
    u = rng.uniform(size=(n // 6, 2))
    parts.append(np.c_[u[:, 0] * 4, u[:, 1] * 4, np.zeros(len(u))])
    parts.append(np.c_[np.zeros(len(u)), u[:, 0] * 4, u[:, 1] * 2.5])
    parts.append(np.c_[u[:, 0] * 4, np.zeros(len(u)), u[:, 1] * 2.5])
    parts.append(np.c_[u[:, 0] * 4, u[:, 1] * 4, np.full(len(u), 2.5)])
    for c, s in (((1.5, 1.0, 0.3), (0.6, 0.4, 0.6)), ((2.6, 2.4, 0.5), (0.5, 0.8, 1.0))):
        q = rng.uniform(-0.5, 0.5, size=(n // 12, 3)) * s
        ax = rng.integers(0, 3, len(q))
        q[np.arange(len(q)), ax] = np.sign(rng.uniform(-1, 1, len(q))) * np.asarray(s)[ax] / 2
        parts.append(q + c)
    return np.concatenate(parts)


def _pose(t, rotvec_deg):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.deg2rad(rotvec_deg)).as_matrix()
    T[:3, 3] = t
    return T


def test_icp_recovers_a_known_rigid_transform():
    rng = np.random.default_rng(0)
    world = _room(rng)
    T_true = _pose([3.2, 3.1, 1.4], [5.0, -8.0, 200.0])
    # the camera sees part of the room, with 3 mm noise, in its own frame
    seen = world[(world[:, 0] < 3.0) & (world[:, 1] < 3.0)]
    cam = (seen - T_true[:3, 3]) @ T_true[:3, :3] + rng.normal(0, 0.003, seen.shape)
    init = T_true @ _pose([0.06, -0.04, 0.03], [1.5, -2.0, 2.5])
    assert extrinsic_error(init, T_true)["trans_cm"] > 5
    reg = register_extrinsic(cam, world, init, RegisterConfig(min_overlap_points=100), allow_fallback=False)
    e = extrinsic_error(reg.T, T_true)
    assert reg.accepted and reg.method == "icp"
    assert e["trans_cm"] < 1.0 and e["rot_deg"] < 0.5, e


def _rings(world, spacing=0.3, band=0.01):
    """A sparse LiDAR-like map of ``world``: only points within ``band`` of horizontal planes every
    ``spacing`` m (walls and box faces become lines 30 cm apart, the floor stays whole)."""
    z = world[:, 2]
    return world[np.abs(z - np.round(z / spacing) * spacing) < band]


def test_sparse_ring_map_normals_check_and_icp():
    rng = np.random.default_rng(3)
    world = _room(rng, 120000)
    ring_map = _rings(world)
    cfg = RegisterConfig(min_overlap_points=100)
    # wall x=0 seen as lines 30 cm apart: fine neighbourhoods hold one line (arbitrary normal); the
    # coarse neighbourhood spans lines and finds the wall's normal
    pts, n = map_normals(ring_map, cfg)
    wall = (pts[:, 0] < 0.01) & (pts[:, 1] > 0.5) & (pts[:, 1] < 3.5) & (pts[:, 2] > 0.5) & (pts[:, 2] < 2.0)
    assert wall.sum() > 100 and np.mean(np.abs(n[wall, 0]) > 0.95) > 0.9
    T_true = _pose([3.2, 3.1, 1.4], [5.0, -8.0, 200.0])
    seen = world[(world[:, 0] < 3.0) & (world[:, 1] < 3.0)]
    cam = (seen - T_true[:3, 3]) @ T_true[:3, :3] + rng.normal(0, 0.003, seen.shape)
    # at the exact pose most camera points lie between the lines: far from every map point, on its surface
    from holodata.conventions import transform_points
    from holodata.mapping.register.extrinsic import _nn_distances

    d = _nn_distances(transform_points(T_true, cam), ring_map)
    assert np.mean(d[d < cfg.overlap_m] < cfg.inlier_m) < 0.6        # the old point-distance fitness
    exact = register_extrinsic(cam, ring_map, T_true, cfg, allow_fallback=False)
    assert exact.attempts[0]["fitness"] > 0.9 and exact.accepted    # surface distance
    init = T_true @ _pose([0.04, -0.03, 0.02], [1.0, -1.5, 2.0])
    reg = register_extrinsic(cam, ring_map, init, cfg, allow_fallback=False)
    e = extrinsic_error(reg.T, T_true)
    assert reg.accepted and e["trans_cm"] < 1.0 and e["rot_deg"] < 0.3, e


def test_relative_extrinsic_error_ignores_a_common_map_offset():
    T_true = _pose([5.0, 1.0, 1.2], [0, 10, 90])
    P_true = np.stack([_pose([x, 0.0, 0.5], [0, 0, 3 * x]) for x in range(5)])
    A = _pose([0.03, -0.02, 0.01], [0.2, 0.1, 0.4])     # the SLAM map sits a little off the world
    e = relative_extrinsic_error(A @ P_true, A @ T_true, P_true, T_true)
    assert e["trans_cm"] < 1e-9 and e["rot_deg"] < 1e-6 and e["scans"] == 5
    assert extrinsic_error(A @ T_true, T_true)["trans_cm"] > 2
    # a camera error relative to the robot is seen in full
    D = _pose([0.0, 0.02, 0.0], [0, 0, 0])
    e = relative_extrinsic_error(P_true, T_true @ D, P_true, T_true)
    assert e["trans_cm"] == pytest.approx(2.0, abs=1e-9)


def test_aligned_extrinsic_error_removes_a_map_offset_on_a_straight_path():
    rng = np.random.default_rng(5)
    T_true = _pose([4.0, 9.0, 1.2], [0, 10, 90])                 # camera 9 m off the robot's path
    n = 40
    stamps = np.arange(n, dtype=np.int64) * 100_000_000
    # a straight path along x (lateral wiggle 7 mm, constant height), as the synthetic corners drive
    P_true = np.stack([_pose([0.1 * k, 0.007 * np.sin(k / 3), 0.5], [0, 0, 0.1 * np.sin(k / 5)]) for k in range(n)])
    B = _pose([0.01, 0.0, 0.0], [0.0, 0.0, 0.25])                # the SLAM map is rotated 0.25 deg off the world
    P_est = B @ P_true
    P_est[:, :3, 3] += rng.normal(0, 0.003, (n, 3)) * [1, 1, 0]   # 3 mm position noise in the plane
    P_est[:, 1, 3] += 0.02 * np.arange(n) / n                     # and 2 cm of lateral drift along the 4 m path
    e = aligned_extrinsic_error_poses(stamps, P_est, B @ T_true, P_true, T_true)
    assert extrinsic_error(B @ T_true, T_true)["trans_cm"] > 3          # world frame: the map's offset
    assert e["trans_cm"] < 1.2 and e["rot_deg"] < 0.02, e           # what is left: the mean drift (1 cm)
    assert e["align_rot_deg"] == pytest.approx(0.25, abs=0.01)
    # position-only Umeyama takes its yaw from the lateral position errors of a straight path (0.3 deg here)
    assert e["umeyama_trans_cm"] > 3 * e["trans_cm"]
    # true poses: the alignment is the identity and the error is the plain one
    D = _pose([0.01, 0.0, 0.0], [0.0, 0.3, 0.0])
    e = aligned_extrinsic_error_poses(stamps, P_true, T_true @ D, P_true, T_true)
    plain = extrinsic_error(T_true @ D, T_true)
    assert e["trans_cm"] == pytest.approx(plain["trans_cm"], abs=1e-6) and e["align_rot_deg"] < 1e-6


def test_local_plane_projection_denoises_planes_and_keeps_edges():
    rng = np.random.default_rng(7)
    # a tilted plane z = 0.1 x + 0.2 y with 1 cm noise along z, and a box edge elsewhere
    xy = rng.uniform(0, 2, (6000, 2))
    plane = np.c_[xy, 0.1 * xy[:, 0] + 0.2 * xy[:, 1]]
    noisy = plane + np.c_[np.zeros((len(xy), 2)), rng.normal(0, 0.01, len(xy))]
    n = np.array([-0.1, -0.2, 1.0]) / np.linalg.norm([-0.1, -0.2, 1.0])
    out = local_plane_projection(noisy, 0.3)
    inner = (xy > 0.3).all(1) & (xy < 1.7).all(1)
    before = np.abs((noisy - plane) @ n)[inner]
    after = np.abs((out - plane) @ n)[inner]
    assert np.sqrt(np.mean(after ** 2)) < 0.25 * np.sqrt(np.mean(before ** 2))
    # points only move along the local normal (no tangential drift)
    move = out - noisy
    assert np.abs(move - (move @ n)[:, None] * n)[inner].max() < 2e-3
    # a right-angle edge (two perpendicular strips): corner neighbourhoods are not planar and stay
    u = rng.uniform(0, 1, (4000, 2))
    edge = np.concatenate([np.c_[u[:2000, 0], u[:2000, 1], np.zeros(2000)], np.c_[u[2000:, 0], np.zeros(2000), u[2000:, 1]]])
    e_out = local_plane_projection(edge, 0.3)
    corner = (edge[:, 1] < 0.02) & (edge[:, 2] < 0.02)
    assert corner.any() and np.allclose(e_out[corner], edge[corner])
    # only=: the others are untouched
    m = np.zeros(len(noisy), bool)
    m[::2] = True
    part = local_plane_projection(noisy, 0.3, only=m)
    assert np.array_equal(part[~m], noisy[~m]) and np.allclose(part[m], out[m])


def test_fallback_is_rejected_when_nothing_fits():
    rng = np.random.default_rng(1)
    world = _room(rng, 20000)
    junk = rng.uniform(-3, 3, size=(8000, 3)) * np.array([1, 1, 0.3])   # no structure of the map
    reg = register_extrinsic(junk, world, _pose([10.0, 10.0, 0.0], [0, 0, 30]), RegisterConfig(min_overlap_points=100))
    assert [a["method"] for a in reg.attempts] == ["icp", "fpfh+icp"]
    assert not reg.accepted
    assert all(not a["accepted"] for a in reg.attempts)


def test_fallback_far_from_the_informed_guess_is_rejected_even_when_it_fits():
    rng = np.random.default_rng(2)
    world = _room(rng, 30000)
    T_true = _pose([3.2, 3.1, 1.4], [5.0, -8.0, 200.0])
    seen = world[(world[:, 0] < 3.0) & (world[:, 1] < 3.0)]
    cam = (seen - T_true[:3, 3]) @ T_true[:3, :3] + rng.normal(0, 0.003, seen.shape)
    init = T_true @ _pose([2.5, -2.0, 0.5], [0, 0, 150])      # 3.2 m and 150 deg off: ICP cannot converge
    far = register_extrinsic(cam, world, init, RegisterConfig(min_overlap_points=100))
    fb = far.attempts[-1]
    assert fb["method"] == "fpfh+icp" and fb["prior_shift_m"] > 1.0 and not fb["accepted"]
    assert not far.accepted


def test_voxel_boundary_is_closed_and_outward():
    occ = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1], [3, 0, 0]])   # an L plus a separate cube
    v, f = voxel_boundary(occ, 0.1)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts % 2 == 0).all()                                   # closed: every edge paired
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert vol == pytest.approx(len(occ) * 0.1 ** 3, rel=1e-9)        # outward, exact volume
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    assert area == pytest.approx((4 * 6 - 2 * 3 + 6) * 0.01, rel=1e-9)  # 18 + 6 exposed unit faces
    # the enclosed solid's centre of mass is the mean of the voxel centres
    np.testing.assert_allclose(solid_centroid(v, f, 0.01), (occ + 0.5).mean(0) * 0.1, atol=2e-3)


def test_closed_surface_extrudes_away_from_the_camera():
    pts = np.stack(np.meshgrid(np.linspace(-0.2, 0.2, 21), [2.0], np.linspace(0.0, 1.6, 41)), -1).reshape(-1, 3)
    eye = np.array([0.0, 0.0, 1.0])
    v, f = closed_surface(pts, eye, 0.2, 0.04)
    assert len(f) and v[:, 1].min() == pytest.approx(2.0, abs=0.041) and v[:, 1].max() == pytest.approx(2.2, abs=0.081)
    # horizontal extrusion: the volume's height is the visible height (not pushed down the rays)
    assert v[:, 2].min() >= -0.04 and v[:, 2].max() <= 1.64 + 1e-9


def _pinhole_cylinder(radius=0.075, dist=3.0, height=1.0, f=300.0, sigma=0.0, seed=0):
    """A vertical cylinder (axis at plan (0, dist), z in [0.2, 0.2 + height]) seen by a level pinhole camera
    at the origin, 1 m high, looking along +y: the visible front's points (world), pixel rows/cols, optical
    depths (with Gaussian noise ``sigma`` m along the rays) and the camera centre."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(-60, 61), np.arange(-150, 151))
    d = np.stack([u / f, np.ones(u.shape), -v / f], -1).reshape(-1, 3)   # world rays (y forward, z up), optical z = 1
    # first hit of the ray with the infinite cylinder x^2 + (y - dist)^2 = r^2 (plan)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = -2 * d[:, 1] * dist
    c = dist ** 2 - radius ** 2
    disc = b * b - 4 * a * c
    ok = disc > 0
    t = np.where(ok, (-b - np.sqrt(np.where(ok, disc, 0))) / (2 * a), np.nan)
    eye = np.array([0.0, 0.0, 1.0])
    p = eye + d * t[:, None]
    ok &= (p[:, 2] > 0.2) & (p[:, 2] < 0.2 + height)
    t = t[ok] + rng.normal(0, sigma, ok.sum()) * np.linalg.norm(d[ok], axis=1) if sigma else t[ok]
    p = eye + d[ok] * t[:, None]
    return p, (v.ravel()[ok] + 150), (u.ravel()[ok] + 60), t, eye, f


@pytest.mark.parametrize("sigma", [0.0, 0.03])
def test_body_columns_cylinder_volume_and_centroid(sigma):
    """A 15 cm limb at 3 m: the solid's volume is the cylinder's (pi r^2 h) within 12 %, its centre of mass
    on the axis within 1 cm in plan and 1.5 cm in height, its front within a voxel of the true front — also
    with 3 cm depth noise (the old per-point extrusion over the run width into every touched voxel: > 1.4x)."""
    r, dist, h, vox = 0.075, 3.0, 1.0, 0.04
    p, rows, cols, t, eye, f = _pinhole_cylinder(r, dist, h, sigma=sigma)
    span, px, down = body_columns(p, rows, cols, t, eye, f, ColumnShape(0.06, 0.22))
    assert np.isnan(down).all() and np.allclose(px, t / f)
    v, fc = closed_surface(p, eye, span, vox, pixel_m=px)
    a, b, c = v[fc[:, 0]], v[fc[:, 1]], v[fc[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert vol == pytest.approx(np.pi * r * r * h, rel=0.12)
    cen = solid_centroid(v, fc, 0.01)
    assert np.linalg.norm(cen[:2] - [0.0, dist]) < 0.01 and abs(cen[2] - (0.2 + h / 2)) < 0.015, cen
    front = v[(np.abs(v[:, 0]) < 0.03) & (np.abs(v[:, 2] - 0.7) < 0.3), 1].min()
    assert abs(front - (dist - r)) <= vox / 2 + 1e-9, front
    # the old model: every point extruded by the run's width (2r here, clipped to 0.22), every touched
    # voxel occupied
    vo, fo = closed_surface(p, eye, 2 * r, vox)
    ao, bo, co = vo[fo[:, 0]], vo[fo[:, 1]], vo[fo[:, 2]]
    assert np.einsum("ij,ij->i", ao, np.cross(bo, co)).sum() / 6.0 > 1.4 * np.pi * r * r * h


@pytest.mark.parametrize("dist", [5.0, 7.0])
def test_body_columns_coarse_camera_keeps_the_volume(dist):
    """A 20 cm limb 5-7 m from a 160-column camera (f 84 px: pixels 6-8 cm, wider than the 4 cm voxel):
    each pixel's column is split across its footprint, so the solid keeps the cylinder's volume within
    20 % and its centre of mass within 3 cm (one line of voxels per pixel kept 0.38-0.44 of it)."""
    r, h, vox = 0.1, 1.2, 0.04
    p, rows, cols, t, eye, f = _pinhole_cylinder(r, dist, h, f=84.0)
    span, px, _ = body_columns(p, rows, cols, t, eye, f, ColumnShape(0.06, 0.22))
    assert px.min() > vox
    v, fc = closed_surface(p, eye, span, vox, pixel_m=px)
    a, b, c = v[fc[:, 0]], v[fc[:, 1]], v[fc[:, 2]]
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0 == pytest.approx(np.pi * r * r * h, rel=0.2)
    assert np.linalg.norm(solid_centroid(v, fc, 0.01) - [0.0, dist, 0.2 + h / 2]) < 0.03


def test_pick_human_far_person_on_a_coarse_camera():
    """A 50 cm x 1.5 m person 7 m from a 160-column camera (pixels 8.3 cm apart, a fifth of them lost):
    ~85 returns, fewer than ``min_points`` and farther apart than ``cluster_m``. Given the pixel
    footprints, the person is one cluster with enough surface and is picked whole; a 10-return blob at
    the same depth is not; without footprints neither is (the fixed counts)."""
    rng = np.random.default_rng(3)
    fp = 7.0 / 84.0
    x, z = np.meshgrid(np.arange(-0.25, 0.25, fp), np.arange(0.1, 1.6, fp))
    body = np.c_[x.ravel(), np.full(x.size, 7.0), z.ravel()][rng.random(x.size) > 0.2]
    blob = np.c_[rng.uniform(1.5, 1.7, 10), np.full(10, 7.0), rng.uniform(0.5, 0.8, 10)]
    pts = np.concatenate([body, blob])
    cfg = RegisterConfig()
    assert len(body) < cfg.min_points and fp > cfg.cluster_m
    m = pick_human(pts, cfg, footprint=np.full(len(pts), fp))
    assert m[:len(body)].mean() > 0.9 and not m[len(body):].any()
    assert not pick_human(pts, cfg).any()
    assert not pick_human(blob, cfg, footprint=np.full(len(blob), fp)).any()


def test_closed_surface_half_filled_voxels_closed_outward_and_feet_reach_the_floor():
    """The volume-weighted voxelisation is closed and outward (every edge paired, the signed volume the
    occupied voxels'); a box of columns aligned with the voxels keeps its size; the lowest pixels' columns
    reach ``down_to``."""
    vox = 0.04
    # a 0.2 x 0.2 x 0.4 m block of horizontal columns along +y, pixels 1 cm, from y = 2.01 to 2.21 (off the
    # voxel grid by a quarter voxel)
    x, z = np.meshgrid(np.arange(0.015, 0.21, 0.01), np.arange(0.215, 0.61, 0.01))
    p = np.c_[x.ravel(), np.full(x.size, 2.01), z.ravel()]
    eye = np.array([0.1, 0.0, 0.4])
    span = np.tile([0.0, 0.2], (len(p), 1))
    v, fc = closed_surface(p, eye, span, vox, horizontal=True, pixel_m=0.01)
    edges = np.sort(np.concatenate([fc[:, [0, 1]], fc[:, [1, 2]], fc[:, [2, 0]]]), axis=1)
    assert (np.unique(edges, axis=0, return_counts=True)[1] % 2 == 0).all()
    a, b, c = v[fc[:, 0]], v[fc[:, 1]], v[fc[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert vol == pytest.approx(0.2 * 0.2 * 0.4, rel=0.25)   # the columns fan out slightly from the eye
    assert v[:, 2].min() == pytest.approx(0.21, abs=vox / 2) and v[:, 2].max() == pytest.approx(0.61, abs=vox / 2)
    # the old touched-voxel rule grows every side by up to a voxel
    vt, ft = closed_surface(p, eye, span, vox)
    at, bt, ct = vt[ft[:, 0]], vt[ft[:, 1]], vt[ft[:, 2]]
    assert np.einsum("ij,ij->i", at, np.cross(bt, ct)).sum() / 6.0 > 1.3 * vol
    # feet: the bottom row's columns reach the floor at z = 0
    down = np.where(p[:, 2] < 0.22, 0.0, np.nan)
    vf, ff = closed_surface(p, eye, span, vox, pixel_m=0.01, down_to=down)
    assert vf[:, 2].min() == pytest.approx(0.0, abs=vox / 2 + 1e-9)


def test_body_columns_lowest_pixels_reach_the_floor():
    p, rows, cols, t, eye, f = _pinhole_cylinder(0.075, 3.0, 1.0)
    _, _, down = body_columns(p, rows, cols, t, eye, f, ColumnShape(0.06, 0.22, floor_reach_m=0.12), floor_z=0.12)
    low = np.isfinite(down)
    assert low.any() and (down[low] == 0.12).all()
    # one per image column, the lowest (largest row) one
    assert len(np.unique(cols[low])) == low.sum() == len(np.unique(cols))
    for c in np.unique(cols)[:5]:
        assert rows[low & (cols == c)][0] == rows[cols == c].max()
    _, _, none = body_columns(p, rows, cols, t, eye, f, ColumnShape(0.06, 0.22, floor_reach_m=0.12), floor_z=-0.5)
    assert np.isnan(none).all()


def test_velocity_shift():
    c = np.array([[0.0, 0, 1], [0.5, 0, 1], [1.0, 0, 1], [np.nan, np.nan, np.nan]])
    cam = np.array([1000, 1500, 2000, 2500]) * 1_000_000   # 0 would mean "no camera frame"
    fr = cam + 50_000_000
    s = velocity_shift(c, cam, fr)
    np.testing.assert_allclose(s[:3], [[0.05, 0, 0]] * 3)     # 1 m/s for 50 ms
    np.testing.assert_allclose(s[3], 0)
    c[1, 0] = 5.0                                              # implausible jump: no shift
    assert np.abs(velocity_shift(c, cam, fr)[0]).sum() == 0



def test_radial_speed_and_deeper_columns():
    """The speed along the view is one-sided (a turn keeps its walking speed), 0 across the view or
    standing; back_frac deepens the columns behind, the front stays."""
    eye = np.zeros(3)
    cam = np.arange(5) * 500_000_000 + 1_000_000_000
    toward = np.array([[0.0, 4.0, 1], [0, 3.5, 1], [0, 3.0, 1], [0, 3.5, 1], [0, 4.0, 1]])   # 1 m/s, turns at 3 m
    np.testing.assert_allclose(radial_speed(toward, cam, eye), 1.0)
    across = np.array([[-1.0, 3.0, 1], [-0.5, 3.0, 1], [0, 3.0, 1], [0.5, 3.0, 1], [1.0, 3.0, 1]])
    assert radial_speed(across, cam, eye)[2] == pytest.approx(0.0, abs=1e-12)
    still = np.tile([0.0, 3.0, 1.0], (5, 1))
    still[3] = np.nan
    np.testing.assert_allclose(radial_speed(still, cam, eye), 0.0)
    jump = toward.copy()
    jump[2, 1] = 9.0                                    # 11 m/s: not a walk
    assert radial_speed(jump, cam, eye)[2] == 0.0
    p, rows, cols, t, eye, f = _pinhole_cylinder(0.075, 3.0, 1.0)
    s0, _, _ = body_columns(p, rows, cols, t, eye, f, ColumnShape(0.06, 0.22))
    s1, _, _ = body_columns(p, rows, cols, t, eye, f, ColumnShape(0.06, 0.22, back_frac=0.4))
    np.testing.assert_allclose(s1[:, 0], s0[:, 0])
    extra = s1[:, 1] - s0[:, 1]
    assert np.median(extra) == pytest.approx(0.4 * 0.15, abs=0.005)          # D = the 15 cm run width
    assert (extra >= 0.4 * 0.06 - 1e-12).all() and (extra <= 0.4 * 0.22 + 1e-12).all()


def test_track_velocity_is_the_shift_per_second():
    c = np.array([[0.0, 0, 1], [0.5, 0.2, 1.3], [1.0, 0.4, 1], [np.nan, np.nan, np.nan]])
    cam = np.array([1000, 1500, 2000, 2500]) * 1_000_000
    v = track_velocity(c, cam)
    np.testing.assert_allclose(v[:3], [[1.0, 0.4, 0.0]] * 3)   # plan velocity (z dropped)
    np.testing.assert_allclose(v[3], 0)
    np.testing.assert_allclose(velocity_shift(c, cam, cam + 50_000_000), v * 0.05)

def test_track_jumps_and_prediction():
    # a person walking 1.1 m/s along y, one frame picks a wall fragment 1.4 m away, one frame has none
    t = np.arange(8) * 500_000_000
    c = np.stack([np.full(8, 0.7), -6.0 + 0.55 * np.arange(8), np.full(8, 1.0)], 1)
    c[4] = [0.7 - 1.4, -6.0 + 0.55 * 4, 0.85]
    c[6] = np.nan
    jumped = track_jumps(c, t, jump_m=0.4, speed_mps=1.5)
    np.testing.assert_array_equal(np.flatnonzero(jumped), [4])          # walking 0.55 m per frame is fine
    pred = track_prediction(np.where(jumped[:, None], np.nan, c), t)
    np.testing.assert_allclose(pred[4], [0.7, -6.0 + 0.55 * 4, 1.0])     # linear between frames 3 and 5
    np.testing.assert_allclose(pred[6], [0.7, -6.0 + 0.55 * 6, 1.0])
    np.testing.assert_allclose(pred[7], c[5])                           # one side only: its centroid
    assert not track_jumps(c[:1], t[:1]).any()
    # one value per concept: the function's defaults are the settings register passes it
    import inspect

    par = inspect.signature(track_jumps).parameters
    assert (par["jump_m"].default, par["speed_mps"].default) == (RegisterConfig().track_jump_m,
                                                                 RegisterConfig().walk_speed_mps)
    assert np.array_equal(track_jumps(c, t), jumped)


@pytest.mark.slow
def test_register_scene_end_to_end_and_raytrace_reads_the_human():
    from _mapping_synth import small_corner

    from holodata import open_dataset
    from holodata.evaluate.register_accuracy import human_centroid_errors, truth_camera_extrinsic
    from holodata.groundtruth import HumanDataset
    from holodata.mapping.register import register_scene

    url, truth = small_corner()
    res = register_scene(url, "recording", cfg=RegisterConfig(segment_lidar=False))
    sc = open_dataset(url).scene("recording")
    T = np.asarray(sc["calib/T_world_camera"][...])
    e = extrinsic_error(T, truth_camera_extrinsic(truth))
    assert res["extrinsic"]["accepted"] and e["trans_cm"] < 5 and e["rot_deg"] < 1, e
    assert res["frames_with_human"] >= sc.n_frames // 2
    h = human_centroid_errors(url, "recording", truth)
    assert h["median_cm"] < 15, h
    ha = human_centroid_errors(url, "recording", truth, frame="aligned")    # true poses: no alignment
    np.testing.assert_allclose(ha["per_frame_cm"], h["per_frame_cm"], atol=1e-6)
    src = HumanDataset(url, "recording", sc)
    assert src.kind == "dataset:human/vertices+faces"
    k = int(np.flatnonzero([len(sc.ragged("human/faces", i)) for i in range(sc.n_frames)])[0])
    v, f = src(k)
    assert f.max() < len(v) and np.isfinite(v).all()
    # no map-frame copy by default: camera_points_world maps camera/points through calib/T_world_camera
    assert "camera/points_world" not in sc.arrays()
    cw = camera_points_world(sc, k)
    pc = np.asarray(sc.ragged("camera/points", k), np.float64)
    assert cw.dtype == np.float32 and len(cw) == len(pc)
    np.testing.assert_allclose(cw, pc @ T[:3, :3].T + T[:3, 3], atol=1e-4)


def _copy_small_corner(tmp_path):
    """(url, scene writer, truth dir) of a copy of the shared small corner without lidar/instance (the
    segmentation tests may leave theirs there, made with their own settings)."""
    import shutil

    from _mapping_synth import small_corner

    import holodata.dataset as hds

    src, truth = small_corner()
    url = str(tmp_path / "ds.zarr")
    shutil.copytree(src, url)
    ds = hds.open_dataset(url)
    sw = hds.create_dataset(url, grid=ds.grid, range_bins=ds.range_bins).scene("recording")
    if "lidar/instance" in sw.arrays():
        sw.remove("lidar/instance")
    return url, sw, truth


@pytest.mark.slow
def test_cli_truth_report(tmp_path):
    """``holodata register --truth --report``: one line of accuracy, register_accuracy.json with the
    same numbers as the evaluation functions give, and the centroid PNG."""
    import json

    from holodata import open_dataset
    from holodata.cli.main import cli
    from holodata.evaluate.register_accuracy import truth_camera_extrinsic

    url, _, truth = _copy_small_corner(tmp_path)     # register's own segmentation is what is scored
    r = CliRunner().invoke(cli, ["register", url, "--truth", truth, "--report", str(tmp_path / "rep"), "--quiet"])
    assert r.exit_code == 0, r.output
    assert "trajectory-aligned" in r.output and "human centroid mean/median/max" in r.output and "AP50" in r.output
    rep = json.loads((tmp_path / "rep" / "register_accuracy.json").read_text())
    T = np.asarray(open_dataset(url).scene("recording")["calib/T_world_camera"][...])
    assert rep["extrinsic"] == pytest.approx(extrinsic_error(T, truth_camera_extrinsic(truth)))
    assert rep["extrinsic_aligned"]["trans_cm"] == pytest.approx(rep["extrinsic"]["trans_cm"], abs=1e-6)  # true poses
    assert rep["extrinsic"]["trans_cm"] < 5 and rep["segmentation"]["ap"] >= 0.5
    assert len(rep["human_centroid"]["per_frame_cm"]) == open_dataset(url).scene("recording").n_frames
    assert (tmp_path / "rep" / "human_centroid.png").stat().st_size > 5000
    r = CliRunner().invoke(cli, ["register", url, "--report", str(tmp_path / "rep2")])
    assert r.exit_code == 2 and "--report needs --truth" in r.output


def test_cli_bad_input_one_line_exit_1(tmp_path):
    from holodata.cli.main import cli

    r = CliRunner().invoke(cli, ["register", str(tmp_path / "missing.zarr")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1 and "missing.zarr" in r.output
    r = CliRunner().invoke(cli, ["register", str(tmp_path / "missing.zarr"), "--init", "1,2,3"])
    assert r.exit_code == 2 and "--init" in r.output
    # a dataset without poses: one line naming the problem
    from holodata.dataset import create_dataset

    w = create_dataset(str(tmp_path / "d.zarr"))
    w.scene("s", n_frames=2)
    r = CliRunner().invoke(cli, ["register", str(tmp_path / "d.zarr")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1 and "camera/points" in r.output


class _StackFrames:
    """A :class:`CameraFrames` stand-in for :func:`static_depth`: frame k's depth image is ``stack[k]``."""

    def __init__(self, stack):
        self.stack = stack

    def depth(self, k):
        return self.stack[k].astype(np.float32)


def test_static_depth_keeps_the_wall_behind_a_person_seen_in_most_frames():
    """A person walking along the camera's line of sight covers the same pixels in 8 of 12 frames:
    the static depth there must still be the wall behind (the plain median gave the person), within
    the stereo noise, and the moving person stays in front of it by far more than its spread."""
    from holodata.mapping.register import static_depth

    rng = np.random.default_rng(0)
    H, W, a = 40, 60, 0.002                       # stereo noise sigma = a z^2 (3 cm at 4 m)
    person = np.zeros((12, H, W), bool)
    person[:8, 10:30, 20:40] = True
    depth = np.where(person, 2.6 + 0.3 * rng.random((12, 1, 1)), 4.0)
    frames = depth + a * depth ** 2 * rng.standard_normal(depth.shape)

    mean, sigma, cnt = static_depth(_StackFrames(frames), list(range(12)))
    assert np.all(np.abs(mean - 4.0) < 0.08)                       # wall everywhere, person pixels too
    assert np.all(cnt[10:30, 20:40] <= 4) and np.median(cnt[:5]) >= 11  # only the frames that saw the wall
    assert np.median(sigma) == pytest.approx(a * 16, rel=0.4)
    assert np.all(frames[:8, 10:30, 20:40] < mean[10:30, 20:40] - 4 * np.median(sigma))


def test_static_depth_leaves_out_pixels_a_person_covers_in_every_frame():
    """A person walking back and forth along the line of sight covers some pixels in all 40 frames
    (depths 1.9-3.1 m, 30 % of the frames at the far end): no static depth there (the far end of the
    walk is not background; before, it was), while the wall around keeps its depth."""
    from holodata.mapping.register import static_depth

    rng = np.random.default_rng(1)
    H, W, a, F = 30, 40, 0.002, 40
    walk = rng.uniform(1.9, 3.1, F)               # anywhere along the walk ...
    walk[rng.permutation(F)[:12]] = 3.1            # ... and 30 % of the frames at its far end
    depth = np.full((F, H, W), 4.0)
    depth[:, 10:20, 15:25] = walk[:, None, None]
    frames = depth + a * depth ** 2 * rng.standard_normal(depth.shape)

    mean, _, cnt = static_depth(_StackFrames(frames), list(range(F)))
    assert np.isnan(mean[10:20, 15:25]).mean() >= 0.9    # (a chance gap in the sampled walk leaves a few)
    assert np.median(cnt[10:20, 15:25]) >= 8             # (the far end holds many frames)
    wall = np.ones((H, W), bool)
    wall[10:20, 15:25] = False
    assert np.all(np.abs(mean[wall] - 4.0) < 0.08)


def test_camera_frames_depth_puts_each_point_back_on_its_pixel():
    """camera/points made from a depth image (one point per valid pixel along its ray, as ingest
    stores a depth camera's cloud) project back onto the same image in float32; points with NaN, z <= 0
    or outside the image go nowhere."""
    from holodata.mapping.register import CameraFrames

    rng = np.random.default_rng(3)
    h, w = 47, 83
    K = np.array([[61.3, 0, 41.2], [0, 60.9, 23.7], [0, 0, 1]])
    D = rng.uniform(0.3, 15.0, (h, w)).astype(np.float32)
    D[rng.random((h, w)) < 0.2] = np.nan
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)
    ok = np.isfinite(D)
    pts = (rays * D[..., None].astype(np.float64))[ok].astype(np.float32)
    junk = np.array([[np.nan, 0, 1], [0, np.nan, 1], [0, 0, np.nan], [0.1, 0.1, -2.0], [100.0, 0, 1.0],
                     [np.inf, 0, 1], [0, 0, 0]], np.float32)

    class Scene:
        def ragged(self, name, k):
            assert name == "camera/points"
            return np.concatenate([pts, junk]) if k == 0 else np.zeros((0, 3), np.float32)

    cam = CameraFrames(Scene(), K, (h, w))
    got = cam.depth(0)
    assert got.dtype == np.float32 and got.shape == (h, w)
    np.testing.assert_array_equal(np.isfinite(got), ok)
    np.testing.assert_allclose(got[ok], D[ok], rtol=1e-6)
    assert not np.isfinite(cam.depth(1)).any()


def nan_quantile(stack, q):
    """``np.nanquantile(stack, q, axis=0)`` of a (F,H,W) stack through register's ``_sorted_quantile``
    (one sort; ``q`` a number, or a tuple of numbers for a tuple of results): what static_depth_of
    used until 2026-12-02, checked against numpy below."""
    from holodata.mapping.register.camera import _sorted_quantile

    s = np.sort(stack, axis=0)                               # NaN sort last
    n = np.isfinite(stack).sum(0)
    out = [_sorted_quantile(s, n, qi) for qi in np.atleast_1d(q)]
    return tuple(out) if isinstance(q, tuple) else out[0]


def _static_depth_plain(stack, far_quantile=0.8):
    """The plain formulation of :func:`static_depth_of` (a temporary per step; its code until
    2026-12-02; since 2026-12-05 only the inliers inside the background window count as background):
    the reference it must equal."""
    from holodata.mapping.register import depth_noise_model

    n = np.isfinite(stack).sum(0)
    with np.errstate(all="ignore"):
        med, far = nan_quantile(stack, (0.5, far_quantile))
        mad = 1.4826 * nan_quantile(np.abs(stack - med[None]), 0.5)
        window = np.maximum(3 * depth_noise_model(far, mad), 0.02)
        background = np.where(np.abs(stack - far[None]) <= window[None], stack, np.nan)
        med = nan_quantile(background, 0.5)
        mad = 1.4826 * nan_quantile(np.abs(background - med[None]), 0.5)
        inl = np.abs(stack - med[None]) <= np.maximum(3 * mad, 0.005)[None]
        cnt = inl.sum(0)
        cnt_bg = (inl & (np.abs(stack - far[None]) <= window[None])).sum(0)
        mean = np.where(cnt > 0, np.nansum(np.where(inl, stack, 0.0), axis=0) / np.maximum(cnt, 1), np.nan)
        below = np.max(np.where(stack < (far - window)[None], stack, -np.inf), axis=0)
        apart = (far - window) - below >= window
    mean = np.where((n * 2 >= len(stack)) & ((cnt_bg * 2 >= n) | apart), mean, np.nan).astype(np.float32)
    return mean, mad.astype(np.float32), cnt.astype(np.int32)


def test_static_depth_of_equals_its_plain_formulation():
    """Read off one sorted copy of the stack, the static depth is the plain formulation's to the bit:
    walls with stereo noise, a person in front in some frames, one walking along the line of sight,
    missing samples, pixels without any, a sample at infinity and tied samples."""
    from holodata.mapping.register import static_depth_of

    rng = np.random.default_rng(7)
    F, h, w = 21, 30, 40
    wall = rng.uniform(2.0, 9.0, (h, w))
    stack = (wall[None] + rng.normal(0, 0.004, (F, h, w)) * wall[None] ** 2).astype(np.float32)
    person = rng.random((F, h, w)) < 0.25
    stack[person] = (wall[None] - rng.uniform(0.3, 1.5, (F, h, w)))[person]
    stack[:, :5, :5] = np.linspace(1.0, 6.0, F, dtype=np.float32)[:, None, None]   # walking along the view
    stack[rng.random(stack.shape) < 0.2] = np.nan
    stack[:, -1, -1] = np.nan                          # never a return
    stack[3, -1, 0] = np.inf
    stack[:, 0, -1] = np.float32(4.0)                  # every sample the same
    for fq in (0.8, 0.5):
        got = static_depth_of(stack, fq)
        ref = _static_depth_plain(stack, fq)
        for g, r in zip(got, ref):
            assert g.dtype == r.dtype
            np.testing.assert_array_equal(g, r)
    assert np.isfinite(got[0]).mean() > 0.5 and not np.isfinite(got[0][:5, :5]).all()


def test_nan_quantile_matches_numpy():
    rng = np.random.default_rng(3)
    stack = rng.normal(4.0, 0.5, (13, 9, 11))
    stack[rng.random(stack.shape) < 0.3] = np.nan
    stack[:, 0, 0] = np.nan                                   # a pixel without any sample
    stack[1:, 0, 1] = np.nan                                  # ... and one with a single sample
    for q in (0.0, 0.5, 0.8, 1.0):
        with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
            ref = np.nanquantile(stack, q, axis=0)
        np.testing.assert_allclose(nan_quantile(stack, q), ref, rtol=0, atol=1e-12, equal_nan=True)
    lo, hi = nan_quantile(stack, (0.2, 0.8))                  # several quantiles from the one sort
    np.testing.assert_array_equal(lo, nan_quantile(stack, 0.2))
    np.testing.assert_array_equal(hi, nan_quantile(stack, 0.8))
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        med = np.nanmedian(stack, axis=0)
    np.testing.assert_allclose(nan_quantile(stack, 0.5), med, rtol=0, atol=1e-12, equal_nan=True)
    even = stack[:12]                                         # an even count of samples: mean of the middle two
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        np.testing.assert_allclose(nan_quantile(even, 0.5), np.nanmedian(even, axis=0), rtol=0, atol=1e-12, equal_nan=True)


def test_local_plane_projection_of_some_points_is_theirs_of_all():
    """``only=``: the chosen points move as they do when every point is projected (their
    neighbourhoods still span all points), onto the plane; the others stay."""
    rng = np.random.default_rng(5)
    X = np.c_[rng.uniform(0, 2, 3000), rng.uniform(0, 2, 3000), rng.normal(0, 0.005, 3000)]
    only = X[:, 0] > 0.7
    a = local_plane_projection(X, 0.3, only=only)
    b = local_plane_projection(X, 0.3)
    assert np.array_equal(a[only], b[only])
    assert np.abs(a[only, 2]).max() < 0.5 * np.abs(X[only, 2]).max() and np.array_equal(a[~only], X[~only])


def test_voxel_average_is_open3d_voxel_down_sample():
    """Independent check: the same voxel means as open3d's voxel_down_sample (order aside)."""
    import open3d as o3d

    from holodata.geometry import voxel_average

    rng = np.random.default_rng(3)
    p = np.concatenate([rng.uniform(-5, 5, (20000, 3)), rng.normal(1.0, 0.02, (5000, 3))])   # sparse + dense voxels
    for voxel in (0.04, 0.15):
        ref = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(voxel).points)
        got = voxel_average(p, voxel)
        assert got.shape == ref.shape
        np.testing.assert_allclose(got[np.lexsort(got.T)], ref[np.lexsort(ref.T)], rtol=0, atol=1e-12)
    assert voxel_average(np.zeros((0, 3)), 0.1).shape == (0, 3)


@pytest.mark.slow
def test_register_in_two_processes_writes_what_one_process_writes(tmp_path):
    """processes=2 (LiDAR half, camera/points_world and half the surfaces in forked processes) gives
    the same extrinsic, humans, surfaces, camera cloud and LiDAR segmentation as processes=1; the
    stored camera/points_world is what camera_points_world computes without it."""
    from holodata import open_dataset
    from holodata.mapping.register import register_scene

    url, sw, _ = _copy_small_corner(tmp_path)
    names = ("human/points", "human/vertices", "human/faces", "camera/points_world")
    outs = []
    for processes in (1, 2):
        for name in ("lidar/instance",) + names:
            if name in sw.arrays():
                sw.remove(name)
        res = register_scene(url, "recording", cfg=RegisterConfig(processes=processes, write_camera_world=True))
        assert res["segment"]["frames"] > 0
        sc = open_dataset(url).scene("recording")
        outs.append((np.asarray(sc["calib/T_world_camera"][...]), np.asarray(sc["lidar/instance"][...]),
                     {n: [np.asarray(sc.ragged(n, k)) for k in range(sc.n_frames)] for n in names}))
    (T1, i1, r1), (T2, i2, r2) = outs
    assert np.array_equal(T1, T2) and np.array_equal(i1, i2) and i1.any()
    for n in names:
        assert all(np.array_equal(a, b) for a, b in zip(r1[n], r2[n])), n
    assert sum(len(f) for f in r1["human/faces"]) > 0
    sw.remove("camera/points_world")
    sc = open_dataset(url).scene("recording")
    for k in (0, sc.n_frames - 1):
        np.testing.assert_array_equal(camera_points_world(sc, k), r2["camera/points_world"][k])


def _killed(*args, **kwargs):
    import os
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def test_register_process_killed_is_a_one_line_error(tmp_path, monkeypatch):
    from holodata.mapping import register as R

    url, _, _ = _copy_small_corner(tmp_path)
    monkeypatch.setattr("holodata.mapping.register.lidar_side.lidar_map", _killed)   # where lidar_half forks it
    from holodata.parallel import WorkerError

    with pytest.raises(WorkerError, match="LiDAR map: its worker process died .*--processes 1"):
        R.register_scene(url, "recording", cfg=RegisterConfig(processes=2))



def test_ransac_plane_finds_the_largest_plane_and_is_deterministic():
    """Analytic check: a tilted plane holding 60 % of the points (2 mm noise) among uniform outliers is
    recovered (normal within 0.5 deg, offset within 5 mm); the same seed gives the same plane; and
    static_residual keeps only a standing person's box between a floor and a wall."""
    from holodata.geometry import ransac_plane
    from holodata.mapping.register import static_residual

    rng = np.random.default_rng(0)
    nrm = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])
    uv = rng.uniform(-3, 3, (6000, 2))
    e1 = np.cross(nrm, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nrm, e1)
    on = uv[:, :1] * e1 + uv[:, 1:] * e2 + 0.7 * nrm + rng.normal(0, 0.002, (6000, 1)) * nrm
    pts = np.concatenate([on, rng.uniform(-3, 3, (4000, 3))])
    n1, d1, k1 = ransac_plane(pts, 0.02, 200, np.random.default_rng(5))
    n2, d2, k2 = ransac_plane(pts, 0.02, 200, np.random.default_rng(5))
    assert np.array_equal(n1, n2) and d1 == d2 and k1 == k2
    s = np.sign(n1 @ nrm)
    assert np.degrees(np.arccos(min(1.0, abs(n1 @ nrm)))) < 0.5 and abs(-s * d1 - 0.7) < 0.005
    assert 6000 <= k1 < 6200
    floor = np.c_[rng.uniform(0, 6, (20000, 2)), np.zeros(20000)]     # a person is a small part of a room
    wall = np.c_[np.zeros(12000), rng.uniform(0, 6, 12000), rng.uniform(0, 2.5, 12000)]
    a, z = rng.uniform(0, np.pi, 800), rng.uniform(0.1, 1.7, 800)      # the front half of a standing body
    person = np.c_[2.2 + 0.2 * np.cos(a), 2.2 - 0.2 * np.sin(a), z]
    cloud = np.concatenate([floor, wall, person])
    resid = static_residual(cloud, RegisterConfig())
    assert resid[-800:].mean() > 0.9 and resid[:-800].mean() < 0.01


def _quad(o, a, b):
    """Two triangles of the parallelogram o, o+a, o+a+b, o+b: (4,3) vertices, (2,3) faces."""
    o, a, b = (np.asarray(x, float) for x in (o, a, b))
    return np.array([o, o + a, o + a + b, o + b]), np.array([[0, 1, 2], [0, 2, 3]])


def _room_mesh():
    """The surfaces of :func:`_room` as a triangle mesh (big quads, two triangles each)."""
    quads = [((0, 0, 0), (4, 0, 0), (0, 4, 0)), ((0, 0, 0), (0, 4, 0), (0, 0, 2.5)),
             ((0, 0, 0), (4, 0, 0), (0, 0, 2.5)), ((0, 0, 2.5), (4, 0, 0), (0, 4, 0))]
    for c, s in (((1.5, 1.0, 0.3), (0.6, 0.4, 0.6)), ((2.6, 2.4, 0.5), (0.5, 0.8, 1.0))):
        lo, s = np.asarray(c) - np.asarray(s) / 2, np.asarray(s)
        ex, ey, ez = np.diag(s)
        for o, a, b in ((lo, ex, ey), (lo, ey, ez), (lo, ex, ez)):
            quads.append((o, a, b))
            far = lo + s - np.asarray(a) - np.asarray(b)     # the opposite face
            quads.append((far, a, b))
    V, F = [], []
    for q in quads:
        v, f = _quad(*q)
        F.append(f + 4 * len(V))
        V.append(v)
    return np.concatenate(V), np.concatenate(F)


def test_mesh_surface_samples_lie_on_their_faces_and_cover_them():
    from holodata.mapping.register import mesh_surface_samples

    n = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    a = np.cross(n, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    V, F = _quad([1.0, 2.0, 0.5], 2 * a, 1.5 * b)                    # a tilted 2 x 1.5 m rectangle
    p, pn = mesh_surface_samples(V, F, spacing=0.05)
    assert len(p) == pytest.approx(3.0 / 0.05 ** 2, rel=0.01)          # area / spacing²
    assert np.abs((p - V[0]) @ n).max() < 1e-9                          # on the plane
    uv = np.linalg.lstsq(np.c_[2 * a, 1.5 * b], (p - V[0]).T, rcond=None)[0]
    assert (uv > -1e-9).all() and (uv < 1 + 1e-9).all()                 # inside the rectangle
    assert np.allclose(np.abs(pn @ n), 1.0)
    # uniform: each half of the rectangle holds half the samples (binomial sd ~0.6 %)
    assert np.mean(uv[0] < 0.5) == pytest.approx(0.5, abs=0.03)
    # cropped to within reach of a point: only samples within reach, about the disc's share
    c = V[0] + a + 0.75 * b
    q, _ = mesh_surface_samples(V, F, near=c[None], reach=0.3, spacing=0.05)
    assert np.linalg.norm(q - c, axis=1).max() <= 0.3
    assert len(q) == pytest.approx(np.pi * 0.3 ** 2 / 0.05 ** 2, rel=0.1)
    assert len(mesh_surface_samples(V, F, near=c[None] + 10, reach=0.3)[0]) == 0


@pytest.mark.slow
def test_mesh_target_recovers_the_pose_where_a_biased_map_does_not():
    rng = np.random.default_rng(5)
    world = _room(rng, 60000)
    V, F = _room_mesh()
    T_true = _pose([3.2, 3.1, 1.4], [5.0, -8.0, 200.0])
    seen = world[(world[:, 0] < 3.0) & (world[:, 1] < 3.0)]
    cam = (seen - T_true[:3, 3]) @ T_true[:3, :3] + rng.normal(0, 0.003, seen.shape)
    # the LiDAR map: the room with a smooth 2 cm bias field (a spatially correlated range error the
    # local plane fits cannot remove) and 5 mm noise
    bias = 0.02 * np.sin(2 * np.pi * world[:, 0] / 1.7 + 0.4) * np.cos(2 * np.pi * world[:, 1] / 2.3)
    noisy_map = world + bias[:, None] * np.array([0.3, 0.5, 0.8]) + rng.normal(0, 0.005, world.shape)
    init = T_true @ _pose([0.04, -0.03, 0.02], [1.0, -1.5, 2.0])
    cfg = RegisterConfig(min_overlap_points=100)
    on_map = register_extrinsic(cam, noisy_map, init, cfg, allow_fallback=False)
    on_mesh = register_extrinsic(cam, noisy_map, init, cfg, allow_fallback=False, mesh=(V, F))
    e_map, e_mesh = extrinsic_error(on_map.T, T_true), extrinsic_error(on_mesh.T, T_true)
    assert on_mesh.accepted and on_mesh.method == "icp" and on_mesh.attempts[0]["target"] == "map+mesh"
    assert e_mesh["trans_cm"] < 0.1 and e_mesh["rot_deg"] < 0.03, e_mesh     # 0.06 cm; 0.37 cm on the map alone
    assert e_map["trans_cm"] > 2 * e_mesh["trans_cm"], (e_map, e_mesh)
    # a mesh nowhere near the camera cloud is no target: the point map is used as without one
    away = register_extrinsic(cam, noisy_map, init, cfg, allow_fallback=False, mesh=(V + 50.0, F))
    assert np.array_equal(away.T, on_map.T) and away.attempts[0]["target"] == on_map.attempts[0]["target"] == "map"


def test_scene_mesh_only_when_built_from_the_scene_poses():
    from holodata.mapping.register import scene_map, scene_mesh

    V, F = _room_mesh()

    class FakeScene:
        def __init__(self, sources):
            self._nodes = {n: ("array", {"attributes": {"source": s}}) for n, s in sources.items()}
            self._data = {"mesh/vertices": V, "mesh/faces": F, "map/points": V[:5]}

        def nodes(self):
            return self._nodes

        def __getitem__(self, name):
            return self._data[name]

    got = scene_mesh(FakeScene({"mesh/vertices": "slam", "mesh/faces": "slam", "pose/T_world_lidar": "slam"}))
    assert got is not None and np.array_equal(got[0], V) and np.array_equal(got[1], F)
    # the poses were replaced (e.g. by the true ones) after slam built the mesh: not this map's surface
    assert scene_mesh(FakeScene({"mesh/vertices": "slam", "mesh/faces": "slam", "pose/T_world_lidar": "truth"})) is None
    assert scene_mesh(FakeScene({"mesh/vertices": "slam", "mesh/faces": "slam"})) is None
    assert scene_mesh(FakeScene({"pose/T_world_lidar": "slam"})) is None
    assert np.array_equal(scene_map(FakeScene({"map/points": "slam", "pose/T_world_lidar": "slam"})), V[:5])
    assert scene_map(FakeScene({"map/points": "slam", "pose/T_world_lidar": "truth"})) is None
    assert scene_map(FakeScene({"map/points": None, "pose/T_world_lidar": None})) is None
    assert scene_map(FakeScene({"mesh/vertices": "slam", "pose/T_world_lidar": "slam"})) is None


@pytest.mark.slow
def test_register_takes_the_static_map_slam_built_from_the_scene_poses(tmp_path):
    """With ``map/points`` + ``mesh/*`` written by slam's static-map step from the poses the scene holds
    (same ``source``), register registers onto that map (its LiDAR process only segments), in one
    process and in two alike; the extrinsic holds; with the poses' source changed it builds its own."""
    from holodata import open_dataset
    from holodata.evaluate.register_accuracy import truth_camera_extrinsic
    from holodata.mapping.register import register_scene, scene_map
    from holodata.mapping.slam import SlamConfig, data_max_range, load_scans, static_mesh, write_static_map

    url, sw, truth = _copy_small_corner(tmp_path)
    sc = open_dataset(url).scene("recording")
    scans = load_scans(sc)
    poses = np.asarray(sc["pose/T_world_lidar"][...], float)[scans.frames]
    sm = static_mesh(scans, poses, SlamConfig(), data_max_range(scans))
    source = (sc.nodes()["pose/T_world_lidar"][1].get("attributes") or {}).get("source")
    assert source
    write_static_map(sw, sm.vertices, sm.faces, sm.points, source)
    assert np.allclose(scene_map(open_dataset(url).scene("recording")), sm.points, atol=1e-5)
    Ts, insts = [], []
    for processes in (1, 2):
        if "lidar/instance" in sw.arrays():
            sw.remove("lidar/instance")
        res = register_scene(url, "recording", cfg=RegisterConfig(processes=processes, write_camera_world=True))
        assert res["map"].startswith("slam") and res["segment"]["frames"] > 0
        assert "map_s" not in res["timings"] or res["timings"]["map_s"] < 0.5
        sc = open_dataset(url).scene("recording")
        Ts.append(np.asarray(sc["calib/T_world_camera"][...]))
        insts.append(np.asarray(sc["lidar/instance"][...]))
        e = extrinsic_error(Ts[-1], truth_camera_extrinsic(truth))
        assert res["extrinsic"]["accepted"] and e["trans_cm"] < 5 and e["rot_deg"] < 1, e
        assert res["frames_with_human"] >= sc.n_frames // 2
    assert np.array_equal(Ts[0], Ts[1]) and np.array_equal(insts[0], insts[1]) and insts[0].any()
    write_static_map(sw, sm.vertices, sm.faces, sm.points, source + "-other")
    res = register_scene(url, "recording", cfg=RegisterConfig(segment_lidar=False))
    assert res["map"] == "built from the LiDAR scans"


def _corridor(seed: int):
    """A corridor along y (walls x = +-1, floor and ceiling; nothing fixes a shift along y): world
    points (N,3), their normals, a camera pose looking along it and the points in that camera."""
    u = np.random.default_rng(seed).uniform(size=(8000, 2))
    world = np.concatenate([np.c_[np.full(len(u), s), u[:, 0] * 10, u[:, 1] * 2.5] for s in (-1.0, 1.0)]
                           + [np.c_[u[:, 0] * 2 - 1, u[:, 1] * 10, np.full(len(u), z)] for z in (0.0, 2.5)])
    normals = np.zeros_like(world)
    normals[: 2 * len(u), 0] = 1.0
    normals[2 * len(u):, 2] = 1.0
    T_true = _pose([0.0, 1.0, 1.2], [-90.0, 0.0, 0.0])
    return world, normals, T_true, (world - T_true[:3, 3]) @ T_true[:3, :3]


def test_point_to_plane_icp_holds_a_corridor_seen_end_on_at_the_guess():
    from holodata.geometry import IcpParams, point_to_plane_icp

    world, normals, T_true, cam = _corridor(2)
    guess = _pose([0.03, 0.05, -0.02], [0.0, 0.0, 0.0]) @ T_true
    info = {}
    T = point_to_plane_icp(cam, np.full(len(cam), 1e4), world, normals, guess,
                           IcpParams(distances=(0.15, 0.05), degenerate_ratio=0.02), info=info)
    assert info["frozen"] == 1
    assert abs(T[0, 3] - T_true[0, 3]) < 2e-3 and abs(T[2, 3] - T_true[2, 3]) < 2e-3   # walls and floor fix x, z
    assert abs(T[1, 3] - guess[1, 3]) < 2e-3                                             # y stays at the guess


def test_held_direction_follows_a_map_turned_about_its_anchor():
    """A SLAM map anchored at a TF pose that was 0.3 deg off is the true world turned about the
    anchor scan's position: the camera, 10 m from it, moves 4 cm along the corridor it sees end-on
    (held by the ICP) and 3 cm across it. The yaw correction and the shift across the corridor both
    show the turn; anchored_guess + hold_at put the held direction where the turned map has it
    (without them it stays at the TF guess). A TF pose off in yaw alone turns the camera without
    moving it: no turn is read from that."""
    from holodata.geometry import IcpParams, hold_at, point_to_plane_icp
    from holodata.mapping.register import anchored_guess

    world, normals, T_true, cam = _corridor(4)
    anchor = np.array([-8.0, -5.0, 0.5])
    turn = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.3])
    turn[:3, 3] = anchor - turn[:3, :3] @ anchor              # 0.3 deg about the vertical through the anchor
    map_pts, map_n = world @ turn[:3, :3].T + turn[:3, 3], normals @ turn[:3, :3].T
    T_map = turn @ T_true                                    # the camera in the map's frame
    info = {}
    T = point_to_plane_icp(cam, np.full(len(cam), 1e4), map_pts, map_n, T_true,
                           IcpParams(distances=(0.15, 0.05), degenerate_ratio=0.02), info=info)
    assert info["frozen"] == 1
    assert abs(T[1, 3] - T_true[1, 3]) < 2e-3               # held at the TF guess: 4 cm off the map's
    assert abs(T_map[1, 3] - T_true[1, 3]) > 0.035
    held = info["held"][0][3:, 0]
    target, seen = anchored_guess(T, T_true, anchor, held, 0.5, 0.1)
    assert seen["yaw_deg"] == pytest.approx(0.3, abs=0.02) and seen["shift_deg"] == pytest.approx(0.3, abs=0.05)
    T2 = hold_at(T, target, info["held"])
    np.testing.assert_allclose(T2[:3, 3], T_map[:3, 3], atol=3e-3)
    assert abs(T2[0, 3] - T[0, 3]) < 1e-3 and abs(T2[2, 3] - T[2, 3]) < 1e-3   # determined directions kept
    assert anchored_guess(T, T_true, anchor, held, 0.1, 0.1)[0] is None     # more than map drift
    # the TF pose 0.3 deg off in yaw about the camera, on the unturned world: yaw without shift
    T_tf = T_true.copy()
    T_tf[:3, :3] = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.3])[:3, :3] @ T_true[:3, :3]
    info = {}
    T3 = point_to_plane_icp(cam, np.full(len(cam), 1e4), world, normals, T_tf,
                            IcpParams(distances=(0.15, 0.05), degenerate_ratio=0.02), info=info)
    target, seen = anchored_guess(T3, T_tf, anchor, info["held"][0][3:, 0], 0.5, 0.1)
    assert target is None and abs(seen["yaw_deg"]) > 0.25 and abs(seen["shift_deg"]) < 0.1, seen


@pytest.mark.slow
def test_register_rerun_skips_unless_inputs_settings_or_force_change(tmp_path):
    """A second register with the same inputs and settings returns the stored report (``skipped``) and
    leaves the outputs as they were; ``processes`` changes no result and no fingerprint; another
    setting, a changed slam map, or ``force`` recomputes."""
    from holodata import open_dataset
    from holodata.mapping.register import register_fingerprint, register_scene

    url, sw, _ = _copy_small_corner(tmp_path)
    cfg = RegisterConfig(segment_lidar=False, processes=1)
    first = register_scene(url, "recording", cfg=cfg, force=True)   # (the shared corner may be registered already)
    assert "skipped" not in first
    sc = open_dataset(url).scene("recording")
    T = np.asarray(sc["calib/T_world_camera"][...])
    fp = sc.attrs["register"]["fingerprint"]
    again = register_scene(url, "recording", cfg=RegisterConfig(segment_lidar=False, processes=2))
    assert again["skipped"].startswith("already done") and again["frames_with_human"] == first["frames_with_human"]
    assert np.array_equal(np.asarray(open_dataset(url).scene("recording")["calib/T_world_camera"][...]), T)
    assert "skipped" not in register_scene(url, "recording", cfg=cfg, force=True)
    assert register_fingerprint(sc, RegisterConfig(segment_lidar=False, min_points=99), None) != fp
    assert register_fingerprint(sc, cfg, [0, 0, 1, 0, 0, 0]) != fp
    P = np.asarray(sc["pose/T_world_lidar"][...]).copy()
    P[:, 0, 3] += 0.01
    sw.write_array("pose/T_world_lidar", P, dims=["frame", "row", "col"], units="m",
                   attrs=dict(sc["pose/T_world_lidar"].attrs))
    assert register_fingerprint(open_dataset(url).scene("recording"), cfg, None) != fp



def test_retired_switches_are_hashed_at_their_only_value_and_are_no_longer_settings():
    """register's fingerprint still carries the deleted switches (so scenes registered before keep
    theirs), and no field of today's configs is shadowed by them."""
    from dataclasses import fields

    from holodata.mapping.register import RETIRED_PARAMS, RETIRED_SEGMENT_PARAMS
    from holodata.mapping.segment import SegmentConfig

    assert not set(RETIRED_PARAMS) & {f.name for f in fields(RegisterConfig)}
    assert not set(RETIRED_SEGMENT_PARAMS) & {f.name for f in fields(SegmentConfig)}
    assert set(RETIRED_PARAMS) == {"noise_weights", "max_std_m", "search_m", "mesh_keep_map_m"}
