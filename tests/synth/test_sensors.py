"""LiDAR and depth camera models: the hidden human stays hidden, noise levels, layouts."""
import numpy as np
import pytest

from holodata.conventions import Grid
from holodata.raytrace import RayScene
from holodata.synth.camera import T_LINK_OPTICAL, CameraConfig, CameraModel, look_at
from holodata.synth.human import HumanWalk
from holodata.synth.lidar import OUSTER_DTYPE, LidarConfig, LidarModel, beam_angles
from holodata.synth.scenario import SceneSpec, Sensors, build_scenario
from holodata.synth.worlds import CLASS_ID, CORNER_TYPES, MATERIAL_ID, MATERIALS


def test_ouster_point_layout():
    assert OUSTER_DTYPE.itemsize == 48
    offs = {n: OUSTER_DTYPE.fields[n][1] for n in OUSTER_DTYPE.names}
    assert offs == {"x": 0, "y": 4, "z": 8, "intensity": 16, "t": 20, "reflectivity": 24, "ring": 26, "ambient": 28, "range": 32}
    alt, az = beam_angles(LidarConfig(), np.random.default_rng(0))
    assert np.all(np.diff(alt) < 0) and np.ptp(np.diff(alt)) > 0.01  # descending, unequal spacing


@pytest.mark.parametrize("corner", CORNER_TYPES)
def test_lidar_never_sees_the_hidden_human(corner):
    sc = build_scenario(SceneSpec(corner, frames=4, seed=11, grid=Grid(8, 32), lidar_shape=(32, 512), camera_shape=(24, 42)))
    s = Sensors(sc)
    start = sc.t0_ns
    hits = []
    for i in range(0, 24, 2):  # scans over the whole drive, up to the closest approach
        pts, st = s.lidar_scan(i, start + i * 100_000_000)
        hits.append(st["human_hits"])
        assert st["returns"] > 0.8 * pts.size
    assert sum(hits) == 0
    # ...while the camera, placed on the hidden side, does see the human
    _, cst = s.camera_frame(0, start + 1_000_000_000)
    assert cst["human_pixels"] > 0.01 * 24 * 42


def test_lidar_sees_a_human_in_line_of_sight():
    # negative control: the same check does fire when the human stands in front of the robot
    sc = build_scenario(SceneSpec("L", frames=2, seed=11, grid=Grid(8, 32), lidar_shape=(32, 512), camera_shape=(8, 16)))
    p = sc.truth.poses[0, :2, 3]
    sc.walk = HumanWalk(p + np.array([2.0, 0.0]), p + np.array([2.0, 0.3]), 0.0, 1.75)
    s = Sensors(sc)
    _, st = s.lidar_scan(0, sc.t0_ns)
    assert st["human_hits"] > 20


def test_lidar_range_noise_is_1_to_3_cm():
    # a closed box room: compare noisy ranges with the exact cast
    from holodata.synth.worlds import box_mesh

    v, f = box_mesh([0, 0, 1.5], [10, 8, 3])
    f = f[:, [0, 2, 1]]  # inward
    scene = RayScene(v, f)
    cfg = LidarConfig(rows=16, cols=256, dropout=0.0)
    alt, az = beam_angles(cfg, np.random.default_rng(0))
    fm = np.full(len(f), MATERIAL_ID["concrete"], np.uint8)
    fc = np.full(len(f), CLASS_ID["wall"], np.uint8)
    model = LidarModel(cfg, alt, az, fm, fc, MATERIALS, MATERIAL_ID["human"], CLASS_ID["ceiling"])
    T = np.tile(np.eye(4), (cfg.cols, 1, 1))
    T[:, 2, 3] = 1.0
    pts, st = model.scan(scene, T, None, np.random.default_rng(1))
    exact = scene.cast(np.broadcast_to(T[None, :, :3, 3] + model.offsets, (16, 256, 3)).reshape(-1, 3),
                       model.dirs.reshape(-1, 3)).t.reshape(16, 256)
    ok = pts["range"] > 0
    err = pts["range"][ok] / 1000.0 - exact[ok]
    assert 0.01 <= np.std(err) <= 0.03 and abs(np.mean(err)) < 0.003
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], -1)[ok]
    assert np.allclose(np.linalg.norm(xyz - model.offsets[ok], axis=1), pts["range"][ok] / 1000.0, atol=2e-3)
    assert np.all(pts["ring"] == np.arange(16)[:, None]) and np.all(np.diff(pts["t"][0].astype(np.int64)) > 0)
    assert np.all(pts["x"][~ok] == 0) and np.all(pts["reflectivity"][ok] > 0)


def test_camera_depth_noise_grows_with_z_squared():
    cfg = CameraConfig(width=40, height=30, fx=50.0, fy=50.0, cx=19.5, cy=14.5, holes=0.0)
    stds = []
    for z in (2.0, 4.0):
        v = np.array([[z, -50, -50], [z, 50, -50], [z, 50, 50], [z, -50, 50.0]])
        scene = RayScene(v, np.array([[0, 1, 2], [0, 2, 3]]))
        cam = CameraModel(cfg, look_at([0, 0, 0], [1, 0, 0]) @ T_LINK_OPTICAL)
        depth = np.concatenate([cam.frame(scene, None, np.random.default_rng(k))[0].ravel() for k in range(8)])
        assert abs(np.nanmean(depth) - z) < 0.01
        stds.append(np.nanstd(depth))
        expect = z ** 2 * cfg.sigma_disparity_px / (cfg.fx * cfg.baseline_m)
        assert stds[-1] == pytest.approx(expect, rel=0.1)
    assert stds[1] / stds[0] == pytest.approx(4.0, rel=0.15)
    # the cloud is the depth image back-projected into the REP-103 camera link frame (x forward)
    d, _ = cam.frame(scene, None, np.random.default_rng(0))
    pts = cam.cloud(d)
    assert np.allclose(pts[..., 0], d, equal_nan=True)


def test_stereo_pair_is_rectified_with_the_depth_cameras_disparity():
    """Right image at (u - fx·b/z) shows what the left image shows at u (rows aligned)."""
    sc = build_scenario(SceneSpec("L", seed=2, frames=2, grid=Grid(8, 32), lidar_shape=(8, 64), camera_shape=(94, 168),
                                  stereo_images=True))
    s = Sensors(sc)
    left, right = s.stereo_pair(0, sc.t0_ns)
    cfg, cam = sc.camera_cfg, s.camera
    d = cam.rays.reshape(-1, 3)
    n = np.linalg.norm(d, axis=1)
    dw = (d / n[:, None]) @ cam.T[:3, :3].T
    hit = s.scene.cast(np.broadcast_to(cam.T[:3, 3], dw.shape), dw, dynamic=sc.human_mesh(sc.t0_ns))
    z = (hit.t / n).reshape(cfg.height, cfg.width)
    disp = cfg.fx * cfg.baseline_m / z
    v, u = np.mgrid[0:cfg.height, 0:cfg.width]
    ur = np.rint(u - disp).astype(int)
    ok = np.isfinite(z) & (ur >= 0) & (ur < cfg.width)
    a = left[ok].astype(float)
    shifted = np.corrcoef(a, right[v[ok], ur[ok]].astype(float))[0, 1]
    unshifted = np.corrcoef(a, right[ok].astype(float))[0, 1]
    assert shifted > 0.9 and shifted > unshifted + 0.05
    assert left.dtype == np.uint8 and left.std() > 5  # textured, not flat


def test_lidar_vertical_fov_is_a_setting():
    from holodata.synth.lidar import LidarConfig, beam_angles

    alt, _ = beam_angles(LidarConfig(rows=32, vertical_fov_deg=90.0), np.random.default_rng(0))
    assert alt.max() == pytest.approx(45.0, abs=0.3) and alt.min() == pytest.approx(-45.0, abs=0.3)
    alt, _ = beam_angles(LidarConfig(rows=32), np.random.default_rng(0))
    assert alt.max() == pytest.approx(16.6, abs=0.3)
