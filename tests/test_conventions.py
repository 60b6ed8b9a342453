import numpy as np
import pytest

from holodata.conventions import Grid, Label, RangeBins, is_rigid, seconds_to_ns, transform_points


def test_grid_rows_and_columns_follow_design():
    g = Grid(64, 512)
    el = np.rad2deg(g.elevations())
    assert el[0] == pytest.approx(45.0) and el[-1] == pytest.approx(-45.0)
    assert np.all(np.diff(el) < 0)
    az = g.azimuths()
    assert az[0] == 0.0
    # column W/4 looks along -y (clockwise seen from above)
    d = g.directions()
    assert d.shape == (64, 512, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    row_horizontal = Grid(3, 4).directions()[1]  # elevation 0 for a symmetric 3-row grid
    np.testing.assert_allclose(row_horizontal, [[1, 0, 0], [0, -1, 0], [-1, 0, 0], [0, 1, 0]], atol=1e-12)


def test_grid_parse_and_attrs_round_trip():
    g = Grid.parse("16x64", "-30,20")
    assert (g.H, g.W, g.elev_max_deg, g.elev_min_deg) == (16, 64, 20.0, -30.0)
    assert Grid.from_attrs(g.to_attrs()) == g
    with pytest.raises(ValueError, match="64x512"):
        Grid.parse("64by512")
    with pytest.raises(ValueError):
        Grid(64, 512, -10.0, 10.0)


def test_range_bins_centres_and_index():
    rb = RangeBins()
    assert rb.max_range == pytest.approx(9.6)
    assert rb.centres()[0] == pytest.approx(0.01875)
    np.testing.assert_array_equal(rb.index([0.0, 0.0374, 0.0376, 9.599, 9.6, -0.1]), [0, 0, 1, 255, -1, -1])
    assert RangeBins.from_attrs(rb.to_attrs()) == rb


def test_labels_are_fixed():
    assert [int(v) for v in Label] == [0, 1, 2, 3, 4]


def test_is_rigid_and_transform():
    T = np.eye(4)
    c, s = np.cos(0.3), np.sin(0.3)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [1, 2, 3]
    assert is_rigid(T)
    bad = T.copy()
    bad[0, 0] *= 1.1
    assert not is_rigid(bad)
    bad = T.copy()
    bad[3, 0] = 1
    assert not is_rigid(bad)
    reflect = np.diag([1.0, 1.0, -1.0, 1.0])
    assert not is_rigid(reflect)
    np.testing.assert_allclose(transform_points(T, np.array([[1.0, 0, 0]])), [[1 + c, 2 + s, 3]])
    # against the matrix product, for (N,3), a single point, float32 in, and a stack of poses broadcast
    rng = np.random.default_rng(0)
    P = rng.normal(size=(1000, 3))
    np.testing.assert_allclose(transform_points(T, P), P @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(transform_points(T, P[0]), T[:3, :3] @ P[0] + T[:3, 3], atol=1e-12)
    assert transform_points(T, P.astype(np.float32)).dtype == np.float64
    Ts = np.stack([T, np.eye(4)])[None]                     # (1,2,4,4): one pose per column
    G = P[:10].reshape(5, 2, 3)
    out = transform_points(Ts, G)
    np.testing.assert_allclose(out[:, 0], G[:, 0] @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(out[:, 1], G[:, 1], atol=1e-12)


def test_seconds_to_ns_rounds():
    assert seconds_to_ns(1.5).item() == 1_500_000_000
    assert seconds_to_ns([0.1])[0] == 100_000_000


def test_yaw_rad_of_turns_and_of_tilted_rotations():
    from scipy.spatial.transform import Rotation

    from holodata.conventions import yaw_rad

    for deg in (-179.0, -90.0, -0.3, 0.0, 12.5, 135.0):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
        assert abs(np.degrees(yaw_rad(T)) - deg) < 1e-9 and abs(np.degrees(yaw_rad(T[:3, :3])) - deg) < 1e-9
    R = Rotation.from_euler("ZYX", [40.0, 10.0, -5.0], degrees=True).as_matrix()   # yaw of yaw-pitch-roll
    assert abs(np.degrees(yaw_rad(R)) - 40.0) < 1e-9


def test_rotation_angle_deg_analytic():
    from scipy.spatial.transform import Rotation

    from holodata.conventions import rotation_angle_deg

    for deg in (0.0, 0.05, 30.0, 179.9):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(np.deg2rad(deg) * np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1, 2, -0.5])).as_matrix()
        assert abs(rotation_angle_deg(T) - deg) < 1e-4 and abs(rotation_angle_deg(T[:3, :3]) - deg) < 1e-4


def test_label_predicates_follow_the_label_names():
    import torch

    from holodata.conventions import Label, is_human, is_los

    lab = np.array([int(v) for v in Label], np.uint8)
    assert is_los(lab).tolist() == [v.name.startswith("LOS") for v in Label]
    assert is_human(lab).tolist() == [v.name.endswith("HUMAN") for v in Label]
    assert is_human(torch.from_numpy(lab)).tolist() == is_human(lab).tolist()
