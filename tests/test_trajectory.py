import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from holodata.errors import InputError
from holodata.trajectory import Trajectory, read_tum, write_tum


def _traj():
    t = np.array([0, 1_000_000_000, 2_000_000_000], dtype=np.int64)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", [[0], [90], [180]], degrees=True).as_matrix()
    poses[:, :3, 3] = [[0, 0, 0], [1, 0, 0], [1, 1, 0]]
    return Trajectory(t, poses)


def test_tum_round_trip(tmp_path):
    tr = _traj()
    write_tum(tmp_path / "t.tum", tr)
    back = read_tum(tmp_path / "t.tum")
    np.testing.assert_array_equal(back.timestamp_ns, tr.timestamp_ns)
    np.testing.assert_allclose(back.poses, tr.poses, atol=1e-8)


def test_interpolate_slerp_midpoint():
    tr = _traj()
    mid = tr.interpolate(np.array([500_000_000, 1_500_000_000]))
    yaw = Rotation.from_matrix(mid[:, :3, :3]).as_euler("zyx", degrees=True)[:, 0]
    np.testing.assert_allclose(yaw, [45, 135], atol=1e-9)
    np.testing.assert_allclose(mid[:, :3, 3], [[0.5, 0, 0], [1, 0.5, 0]])
    # clamped outside the samples
    np.testing.assert_allclose(tr.interpolate(np.array([-5, 10**12]))[:, :3, 3], [[0, 0, 0], [1, 1, 0]])


@pytest.mark.parametrize(
    "content, where",
    [
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", ":2:"),
        ("0 0 0 0 0 0 0 1\n1 0 0 x 0 0 0 1\n", ":2:"),
        ("0 0 0 0 0 0 0 2\n", ":1:"),
        ("1 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", "not strictly increasing"),
        ("# only a comment\n", "no poses"),
    ],
)
def test_malformed_tum_names_the_line(tmp_path, content, where):
    p = tmp_path / "bad.tum"
    p.write_text(content)
    with pytest.raises(InputError, match=where) as err:
        read_tum(p)
    assert "bad.tum" in str(err.value) and "\n" not in str(err.value)


def test_missing_tum_file(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        read_tum(tmp_path / "nope.tum")


def test_tum_timestamps_keep_nanoseconds(tmp_path):
    p = tmp_path / "t.tum"
    p.write_text("1735693200.548947099 0 0 0 0 0 0 1\n1735693200.6 1 0 0 0 0 0 1\n1.5e0 2 0 0 0 0 0 1\n"
                 .replace("1.5e0", "1735693201.5e0"))
    t = read_tum(p).timestamp_ns
    assert t[0] == 1735693200548947099 and t[1] == 1735693200600000000
    assert abs(int(t[2]) - 1735693201500000000) < 1000
