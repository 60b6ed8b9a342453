"""The mapping pass of ``holodata synth`` (issue 22): its own LiDAR + odometry recording of the empty
corner, driven through the approach corridor and the hidden branch before the data pass; truth in the
data pass's world frame; the smooth waypoint path it drives."""
import json

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from holodata.conventions import Grid, RangeBins, yaw_rad
from holodata.errors import InputError
from holodata.synth import MAPPING_TOPICS, SynthSpec, synthesize
from holodata.synth.motion import DriveProfile, path_trajectory
from holodata.synth.worlds import hidden_from, make_world
from holodata.trajectory import read_tum

SMALL = dict(frames=2, grid=Grid(8, 32), range_bins=RangeBins(64), lidar_shape=(8, 64), camera_shape=(12, 20))


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    return {c: synthesize(tmp_path_factory.mktemp(c) / "a", SynthSpec(corner=c, seed=5, mapping_pass=True, **SMALL),
                          quiet=True)
            for c in ("L", "oblique")}


@pytest.mark.parametrize("corner", ["L", "oblique"])
def test_mapping_pass_drives_both_legs_before_the_data_pass(mapped, corner):
    res = mapped[corner]
    assert res.mapping_recording is not None and res.mapping_recording.is_dir()
    scene = json.loads(res.scene_json.read_text())
    mp = scene["mapping_pass"]
    with AnyReader([res.mapping_recording]) as r:
        assert {c.topic: c.msgtype for c in r.connections} == MAPPING_TOPICS   # no radar, camera, person
        n_scans = sum(1 for _ in r.messages([c for c in r.connections if c.topic == "/ouster/points"]))
    assert n_scans == mp["scans"] >= 10
    base = read_tum(res.truth_dir / "mapping_trajectory_base.tum")
    lidar = read_tum(res.truth_dir / "mapping_trajectory_lidar.tum")
    assert len(lidar) == n_scans
    data = read_tum(res.truth_dir / "trajectory_base.tum")
    assert base.timestamp_ns[-1] < data.timestamp_ns[0]                  # map first, then record
    w = make_world(corner, None, 5)
    xy = base.poses[:, :2, 3]
    origin, u, L, bw = w.hidden_axis
    along = (xy - origin) @ u
    # it starts in the approach corridor, behind where the data pass starts ...
    assert xy[0, 0] < min(data.poses[0, 0, 3], -2.0) and abs(xy[0, 1]) < 0.05
    # ... and ends deep in the hidden branch, out of sight of every place of the data pass
    assert along[-1] > L - 2.0
    hidden_end = hidden_from(w.floor_polygon, data.poses[::20, :2, 3], xy[-1:])
    assert hidden_end.all()
    # scans from both legs: some with the LiDAR in the approach corridor, some in the hidden branch
    lx = lidar.poses[:, :2, 3]
    assert (lx[:, 0] < -1.0).sum() >= 3 and (((lx - origin) @ u) > 2.0).sum() >= 3
    # in the free space all along (inside the outline)
    from matplotlib.path import Path as MPath

    assert MPath(w.floor_polygon).contains_points(xy[::10]).all()


def test_mapping_pass_off_by_default_and_deterministic(tmp_path, mapped):
    res = synthesize(tmp_path / "b", SynthSpec(corner="L", seed=5, **SMALL), quiet=True)
    assert res.mapping_recording is None and not (tmp_path / "b" / "mapping").exists()
    assert "mapping_pass" not in json.loads(res.scene_json.read_text())
    again = synthesize(tmp_path / "c", SynthSpec(corner="L", seed=5, mapping_pass=True, **SMALL), quiet=True)
    a, b = mapped["L"].mapping_recording, again.mapping_recording
    assert (a / "mapping.mcap").read_bytes() == (b / "mapping.mcap").read_bytes()
    # the data pass is the same with or without the mapping pass
    assert (res.storage_file.read_bytes() == again.storage_file.read_bytes())
    with pytest.raises(InputError, match="mapping_scan_hz"):
        synthesize(tmp_path / "d", SynthSpec(corner="L", seed=5, mapping_pass=True, mapping_scan_hz=50.0, **SMALL),
                   quiet=True)


def test_path_trajectory_is_smooth_and_slows_in_turns():
    wp = np.array([[-3.0, 0.0], [0.5, 0.0], [0.5, 4.0]])
    traj, info = path_trajectory(wp, 0, np.random.default_rng(1), DriveProfile(speed=0.8, turn_radius=0.5, max_yaw_rate=0.4))
    P = traj.poses
    t = traj.timestamp_ns * 1e-9
    assert np.allclose(P[0, :2, 3], wp[0]) and np.allclose(P[-1, :2, 3], wp[-1], atol=1e-6)
    yaw = np.unwrap([yaw_rad(T) for T in P])
    rate = np.abs(np.diff(yaw) / np.diff(t))
    assert rate.max() < 0.4 * 1.05                                    # the yaw-rate limit holds
    v = np.linalg.norm(np.diff(P[:, :2, 3], axis=0), axis=1) / np.diff(t)
    assert v.max() < 0.8 * 1.01 and v[:5].max() < 1e-9 and v[-5:].max() < 1e-9  # at rest at both ends
    assert abs(np.degrees(yaw[-1] - yaw[0]) - 90.0) < 2.5              # the turn (plus a +-2 deg offset)
    assert info["length_m"] == pytest.approx(3.5 + 4.0 - (2 - np.pi / 2) * 0.5, abs=0.02)


def test_cli_records_the_mapping_pass_by_default(tmp_path):
    from click.testing import CliRunner

    from holodata.cli.main import cli

    args = ["synth", "--corner", "T", "--frames", "1", "--grid", "8x32", "--range-bins", "64", "--lidar", "8x64",
            "--camera", "12x20", "--quiet"]
    r = CliRunner().invoke(cli, args + ["--out", str(tmp_path / "a")], obj={})
    assert r.exit_code == 0, r.output
    assert (tmp_path / "a" / "mapping" / "mapping.mcap").is_file() and "mapping:" in r.output
    r = CliRunner().invoke(cli, args + ["--out", str(tmp_path / "b"), "--no-mapping-pass"], obj={})
    assert r.exit_code == 0 and not (tmp_path / "b" / "mapping").exists()
    r = CliRunner().invoke(cli, args + ["--out", str(tmp_path / "c"), "--mapping-scan-hz", "50"], obj={})
    assert r.exit_code == 2
