"""The beam-origin model end to end: analytic beam geometry, what ingest records, what raytrace-gt
traces with, and the oracle (ground truth through evaluate's stage two) scoring perfectly for
both origin models on the demo's grids."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from holodata.beams import OriginModel, column_poses, column_times, frame_beams, gt_origin_model, scene_origin_model
from holodata.cli.main import cli
from holodata.conventions import Grid
from holodata.trajectory import Trajectory


def _yaw(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _moving(v=1.0, omega=0.4, n=5, dt_ns=500_000_000) -> Trajectory:
    """A radar moving along +x at v m/s while turning at omega rad/s (exact at the samples;
    linear/SLERP between them is exact too: constant velocity along x, constant yaw rate)."""
    ts = np.arange(n, dtype=np.int64) * dt_ns
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i, t in enumerate(ts / 1e9):
        poses[i, :3, :3] = _yaw(omega * t)
        poses[i, 0, 3] = v * t
    return Trajectory(ts, poses)


@pytest.mark.parametrize("radius", [0.0, 0.105])
def test_frame_beams_follow_the_column_times_and_origins(radius):
    g = Grid(4, 16)
    traj = _moving()
    om = OriginModel(rotation_radius=radius, column_time=True)
    k = 2
    cycle = (int(traj.timestamp_ns[k]) - 250_000_000, int(traj.timestamp_ns[k]) + 250_000_000)
    t = column_times(traj.timestamp_ns[k], g, om, cycle)
    np.testing.assert_array_equal(t, cycle[0] + np.round((np.arange(16) + 0.5) / 16 * 5e8).astype(np.int64))
    # without a cycle, the stamp is the middle of a rotation at rotation_hz (the same times here)
    np.testing.assert_array_equal(column_times(traj.timestamp_ns[k], g, om), t)
    o, d = frame_beams(g, traj.poses[k], om, column_poses(traj, k, g, om, cycle))
    dt = (t - traj.timestamp_ns[k]) / 1e9                       # column time from the frame's pose
    az = g.azimuths()
    for j in range(16):
        Rrel = _yaw(0.4 * dt[j])                                # column frame in the frame's radar frame
        t_world = np.array([1.0 * (traj.timestamp_ns[k] / 1e9 + dt[j]), 0, 0]) - np.array([traj.timestamp_ns[k] / 1e9, 0, 0])
        trel = _yaw(0.4 * traj.timestamp_ns[k] / 1e9).T @ t_world
        o_exp = trel + Rrel @ (radius * np.array([np.cos(az[j]), np.sin(az[j]), 0]))
        np.testing.assert_allclose(o[:, j], np.broadcast_to(o_exp, (4, 3)), atol=1e-9)
        np.testing.assert_allclose(d[:, j], g.directions()[:, j] @ Rrel.T, atol=1e-9)
    # one pose per frame: origins on the circle (or 0), the grid's own directions
    o1, d1 = frame_beams(g, traj.poses[k], OriginModel(radius, column_time=False))
    np.testing.assert_allclose(d1, g.directions())
    np.testing.assert_allclose(np.linalg.norm(o1[..., :2], axis=-1), radius, atol=1e-12)


def test_origin_model_attrs_and_precedence():
    for om in (OriginModel(), OriginModel(0.105, False, 4.0)):
        assert OriginModel.from_attrs(om.to_attrs()) == om
    rec = {"sensors": {"radar": {"beam_origin": OriginModel(0.105).to_attrs()}}}
    assert scene_origin_model({}) == (OriginModel(), "default")
    assert scene_origin_model(rec) == (OriginModel(0.105), "recording")
    assert scene_origin_model(rec, OriginModel(0.0, False)) == (OriginModel(0.0, False), "flags")
    assert gt_origin_model({}) is None
    with pytest.raises(ValueError, match="beam-origin type"):
        OriginModel.from_attrs({"type": "antenna_array"})


# ------------------------------------------------------------------------- synth → oracle
def _demo_scene(tmp, grid: Grid, origin: OriginModel | None, name: str):
    """One synthetic L corner (2 rotations) on ``grid`` ingested, mapped from its truth and traced
    with ``origin`` (None: the model the recording states)."""
    from holodata.dataset import create_dataset, open_dataset
    from holodata.demo import map_from_truth
    from holodata.groundtruth import GTConfig, raytrace_dataset
    from holodata.ingest import ingest
    from holodata.synth import SynthSpec, synthesize

    rec = tmp / f"rec_{grid.H}x{grid.W}"
    if not (rec / "truth" / "scene.json").is_file():
        synthesize(rec, SynthSpec(corner="L", frames=2, seed=16, grid=grid, lidar_shape=(16, 128), camera_shape=(24, 32)),
                   quiet=True)
    url = str(tmp / f"{name}.zarr")
    ingest([str(rec / "recording")], url, scene_ids=["L_16"], quiet=True)
    w = create_dataset(url, grid=grid, created_by="test")
    map_from_truth(w.scene("L_16"), rec / "truth")
    raytrace_dataset(url, ["L_16"], GTConfig(origin=origin), quiet=True)
    w.set_splits(train=["L_16"], test=["L_16"])
    return url, open_dataset(url).scene("L_16")


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("beams")


@pytest.mark.parametrize("grid", [Grid(32, 128), Grid(64, 512)], ids=["quick", "full"])
@pytest.mark.parametrize("origin", [None, OriginModel(rotation_radius=0.105)], ids=["recorded-centre", "circle"])
@pytest.mark.slow
def test_oracle_scores_perfectly_for_both_origin_models(synth_dir, grid, origin):
    pytest.importorskip("torch")
    from holodata.evaluate import Evaluation

    name = f"{grid.H}x{grid.W}_{'rec' if origin is None else 'circle'}"
    url, sc = _demo_scene(synth_dir, grid, origin, name)
    rec = sc.attrs["sensors"]["radar"]["beam_origin"]
    assert rec["type"] == "rotation_centre" and rec["column_time"]      # what the synthetic radar does
    gt = sc.attrs["gt"]
    if origin is None:
        assert gt["origin_source"] == "recording" and gt["origin_model"] == rec
        assert gt["column_times_from"] == "radar/cycle_ns"
    else:
        assert gt["origin_source"] == "flags" and gt["origin_model"]["rotation_radius_m"] == 0.105
    lab = np.asarray(sc["gt/label"][...])
    assert (lab == 2).sum() > 0 and ((lab == 3) | (lab == 4)).sum() > 0   # NLOS and human to score
    doc = Evaluation(url, None, synth_dir / f"rep_{name}", oracle=True, report=False, quiet=True).run()
    m = doc["methods"]["model"]
    for b in (1, 2, 3):
        assert m["range"][f"bounce_{b}"]["mean_cm"] == 0
    for part in ("los", "nlos"):
        # gt/normal is float16: a bounce-2/3 point moves by ~1e-3 rad x its path length
        assert m["points"][part]["f_score"] >= 0.99, (part, m["points"][part])
        assert m["points"][part]["cd"] < 0.02
    assert m["human"]["f_score"] == 1
    assert doc["settings"]["beam_origin"]["L_16"] == gt["origin_model"]


def test_oracle_cli_and_bad_input(synth_dir, tmp_path):
    pytest.importorskip("torch")
    url, _ = _demo_scene(synth_dir, Grid(32, 128), None, "cli")
    r = CliRunner().invoke(cli, ["evaluate", url, "--oracle", "--out", str(tmp_path / "rep"), "--quiet"])
    assert r.exit_code == 0, r.output
    assert "model" in r.output and (tmp_path / "rep" / "metrics.json").is_file()
    r = CliRunner().invoke(cli, ["evaluate", url, "--out", str(tmp_path / "rep2")])
    assert r.exit_code == 2 and "--oracle" in r.output
    # a dataset without gt/*: one line, exit 1
    from holodata.ingest import ingest

    bare = str(tmp_path / "bare.zarr")
    ingest([str(synth_dir / "rec_32x128" / "recording")], bare, scene_ids=["L_16"], quiet=True)
    r = CliRunner().invoke(cli, ["evaluate", bare, "--oracle", "--out", str(tmp_path / "rep3"), "--split", "all"])
    assert r.exit_code == 1 and "gt/range" in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_info_says_which_beam_origin_model_gt_was_traced_with(synth_dir):
    url, _ = _demo_scene(synth_dir, Grid(32, 128), OriginModel(rotation_radius=0.105), "info")
    r = CliRunner().invoke(cli, ["info", url])
    assert r.exit_code == 0, r.output
    assert "beams: radar rotation centre, per-column time; gt rotation circle r = 0.105 m, per-column time" in r.output
    assert "note: ground truth traced with another beam-origin model" in r.output
