"""PanoRadar raw trajectory folders (raw FMCW samples + LiDAR + data_params.npz): detected from their
layout, beamformed on ingest with the parameters recorded in the scene, reflectors at the bins the
geometry predicts, and one-line errors for broken folders."""
from __future__ import annotations

import math
import shutil
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.conventions import Grid
from holodata.dataset import open_dataset, validate_dataset
from holodata.errors import RecordingError
from holodata.radar import BeamformParams
from holodata.radar.chirp import ChirpConfig
from holodata.readers import guess_reader, open_recording
from holodata.synth.panoradar_raw import BoxRoom, BoxRoomRun, box_room_trajectory

CHIRP = ChirpConfig(chirps_per_rotation=512)   # chirp spacing on the circle 1.3 mm < λ/2: no grating lobes
PARAMS = BeamformParams(grid=Grid(16, 64))
VELOCITY = (0.3, 0.1)
ROOM = BoxRoom(reflectors=((3.0, 0.6, 0.0),))


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    return box_room_trajectory(tmp_path_factory.mktemp("pr") / "walk_01",
                               BoxRoomRun(n_rotations=3, velocity=VELOCITY, lidar_yaw_deg=30.0), chirp=CHIRP, room=ROOM)


def _heatmaps(rec):
    out = []
    for raw in rec.raw_messages(["/panoradar/radar"]):
        m = rec.decode(raw)
        out.append((m, np.frombuffer(m.data, "<f4").reshape(m.n_range, m.n_elevation, m.n_azimuth)))
    return out


def _expected_cell(m, k: int, j: int, velocity=VELOCITY):
    """(range bin, row, column) of the reflector seen from the rotation centre at column j's time of
    rotation k (the beamformer's motion_reference 'beam'), on the heatmap's grid."""
    N = CHIRP.chirps_per_rotation
    n = k * N + j * N / m.n_azimuth                           # chirp index of column j (chirp 0 = first rotation)
    c = np.array([velocity[0], velocity[1], 0.0]) * n * CHIRP.chirp_period_s
    d = np.asarray(ROOM.reflectors[0]) - c
    r = float(np.linalg.norm(d))
    el = math.asin(d[2] / r)
    az = math.atan2(d[1], d[0])
    col = (-az / (2 * math.pi) * m.n_azimuth) % m.n_azimuth
    row = (math.radians(45.0) - el) / (math.radians(90.0) / (m.n_elevation - 1))
    return r / m.range_resolution - 0.5, row, col


def test_a_raw_trajectory_is_detected_and_its_reflector_lands_at_the_predicted_cell(moving):
    assert guess_reader(moving.folder) == "panoradar-raw"
    rec = open_recording(moving.folder, beamform=PARAMS)
    assert rec.problems == []
    hms = _heatmaps(rec)
    assert len(hms) == 3
    for k, (m, hm) in enumerate(hms):
        assert hm.shape == (256, 16, 64) and m.range_origin == "rotation_centre"
        b, row, col = np.unravel_index(np.argmax(hm), hm.shape)
        eb, erow, ecol = _expected_cell(m, k, int(col))
        assert abs(b - eb) <= 1.0 and abs(row - erow) <= 1.0, (k, (b, row, col), (eb, erow, ecol))
        assert min(abs(col - ecol), m.n_azimuth - abs(col - ecol)) <= 1.0, (k, col, ecol)


def test_ingest_records_how_the_heatmaps_were_made_and_the_lidar_extrinsic(moving, tmp_path, monkeypatch):
    from holodata.ingest import IngestOptions, ingest
    from holodata.readers import panoradar_raw

    calls = []
    real = panoradar_raw.beamform
    monkeypatch.setattr(panoradar_raw, "beamform", lambda *a, **k: calls.append(1) or real(*a, **k))
    url = str(tmp_path / "ds.zarr")
    ingest([moving.folder], url, IngestOptions(beamform=PARAMS))
    assert validate_dataset(url)["ok"]
    # each rotation is imaged once (the index pass checks raw samples), plus one for the grid
    assert len(calls) <= 3 + 1, len(calls)
    sc = open_dataset(url).scene("walk_01")
    bf = sc.attrs["source"]["beamform"]
    assert bf["params"]["n_elevation"] == 16 and bf["params"]["n_azimuth"] == 64
    assert bf["chirp"]["chirps_per_rotation"] == 512 and bf["chirp"]["rotation_radius_m"] == CHIRP.rotation_radius_m
    assert bf["motion_compensation"] == "motion_output.npz" and bf["range_origin"] == "rotation_centre"
    assert bf["n_syn"] == PARAMS.syn_count(512)
    assert sc["radar/heatmap"].shape == (3, 256, 16, 64)
    # LiDAR frames and the 2x2 transform as the LiDAR's extrinsic (yaw 30 deg, relative to the radar)
    T = np.asarray(sc.attrs["extrinsics"]["lidar"])
    assert math.degrees(math.atan2(T[1, 0], T[0, 0])) == pytest.approx(30.0, abs=1e-6)
    assert np.allclose(sc.attrs["extrinsics"]["radar"], np.eye(4))
    assert "lidar/points" in sc and "pose/T_world_radar" not in sc   # static TF only: no world to place it in


def test_motion_compensation_focuses_a_moving_trajectory(moving, tmp_path):
    """The same samples without motion_output.npz are imaged as if at rest (and the recording says so):
    the reflector's peak drops and smears."""
    bare = tmp_path / "walk_02"
    shutil.copytree(moving.folder, bare)
    (bare / "motion_output.npz").unlink()
    rec = open_recording(bare, beamform=PARAMS)
    assert any("as if at rest" in p for p in rec.problems)
    assert rec.attrs["beamform"]["motion_compensation"].startswith("none")
    still = max(hm.max() for _, hm in _heatmaps(rec))
    comp = max(hm.max() for _, hm in _heatmaps(open_recording(moving.folder, beamform=PARAMS)))
    assert comp > 1.5 * still


def test_a_static_folder_pads_circularly_and_images_every_rotation(tmp_path):
    tr = box_room_trajectory(tmp_path / "static_01", BoxRoomRun(n_rotations=2, pad=0), chirp=CHIRP, room=ROOM)
    rec = open_recording(tr.folder, beamform=PARAMS)
    assert rec.attrs["beamform"]["padding"] == "circular" and rec.attrs["beamform"]["rotations_imaged"] == 2
    (m, hm), _ = _heatmaps(rec)
    b, row, col = np.unravel_index(np.argmax(hm), hm.shape)
    eb, erow, ecol = _expected_cell(m, 0, int(col), velocity=(0.0, 0.0))
    assert abs(b - eb) <= 1.0 and abs(row - erow) <= 1.0 and abs(col - ecol) <= 1.0


def _break(folder, how: str):
    if how == "no data_params.npz":
        (folder / "data_params.npz").unlink()
    elif how == "float samples":
        a = np.load(folder / "radar_data.npy")
        np.save(folder / "radar_data.npy", a.real.astype(np.float32))
    elif how == "truncated npy":
        b = (folder / "radar_data.npy").read_bytes()
        (folder / "radar_data.npy").write_bytes(b[: len(b) // 2])
    elif how in ("separators out of order", "separators beyond the data"):
        with np.load(folder / "data_params.npz") as z:
            d = {k: z[k] for k in z.files}
        d["radar_sep"] = d["radar_sep"][::-1].copy() if how == "separators out of order" else d["radar_sep"] + 10_000
        np.savez(folder / "data_params.npz", **d)
    elif how == "stamps missing":
        t = np.loadtxt(folder / "radar_ts.txt")
        np.savetxt(folder / "radar_ts.txt", t[:-5])
    elif how == "motion file short":
        np.savez(folder / "motion_output.npz", v_esti=[0.3], theta_v_esti=[0.0], delta_s0_esti=[1e-4])


@pytest.mark.parametrize("how, file, words", [
    ("no data_params.npz", "data_params.npz", "missing"),
    ("float samples", "radar_data.npy", "complex"),
    ("truncated npy", "radar_data.npy", "truncated"),
    ("separators out of order", "data_params.npz", "out of order"),
    ("separators beyond the data", "data_params.npz", "beyond the data"),
    ("stamps missing", "radar_ts.txt", "stamps for"),
    ("motion file short", "motion_output.npz", "rotations"),
])
def test_broken_raw_folders_are_one_line_errors_and_leave_nothing_that_validates(moving, tmp_path, how, file, words):
    bad = tmp_path / "walk_bad"
    shutil.copytree(moving.folder, bad)
    _break(bad, how)
    with pytest.raises(RecordingError, match=words) as e:
        open_recording(bad, beamform=PARAMS)
    assert str(bad / file) in str(e.value) and "\n" not in str(e.value)
    url = tmp_path / "ds.zarr"
    r = CliRunner().invoke(cli, ["ingest", str(bad), "--out", str(url), "--beamform-grid", "16x64", "--quiet"])
    assert r.exit_code == 1 and str(bad / file) in r.output and "Traceback" not in r.output, r.output
    assert not url.exists() or not validate_dataset(str(url))["ok"]


def test_keep_iq_then_beamform_reimages_and_resumes(moving, tmp_path):
    """ingest --keep-iq stores each rotation's raw samples with their neighbours; `holodata beamform`
    with the recorded motion reproduces ingest's heatmaps, with --motion none the moving reflector
    smears (lower peak), with --motion slam it takes the motion from pose/T_world_radar, and every
    run says so in source.beamform; an interrupted run resumes."""
    import importlib

    from holodata.dataset import create_dataset
    from holodata.ingest import IngestOptions, ingest
    from holodata.reimage import beamform_scene, motion_from_poses

    url = str(tmp_path / "ds.zarr")
    ingest([moving.folder], url, IngestOptions(beamform=PARAMS, keep_iq=True))
    assert validate_dataset(url)["ok"]
    sc = open_dataset(url).scene("walk_01")
    span = sc["radar/iq_span"][...]
    h = (PARAMS.syn_count(512) - 1) // 2
    assert span.tolist() == [[h, 512, h]] * 3 and sc["radar/iq"].shape == (3, 512 + 2 * h, 8, 256)
    first = np.asarray(sc["radar/heatmap"][...])
    r = CliRunner().invoke(cli, ["beamform", url, "--quiet"])
    assert r.exit_code == 0, r.output
    again = open_dataset(url).scene("walk_01")
    assert again.attrs["source"]["beamform"]["rebeamformed"]["motion"] == "recorded"
    np.testing.assert_allclose(np.asarray(again["radar/heatmap"][...]), first, rtol=1e-4, atol=1e-3 * first.max())
    assert "already imaged" in CliRunner().invoke(cli, ["beamform", url]).output
    beamform_scene(url, "walk_01", motion="none")
    still = np.asarray(open_dataset(url).scene("walk_01")["radar/heatmap"][...])
    assert still.max() < first.max() / 1.5
    # slam's poses: the true trajectory written as pose/T_world_radar gives the recorded motion back
    t = sc["time/timestamp_ns"][...]
    P = np.repeat(np.eye(4)[None], 3, axis=0)
    P[:, :2, 3] = np.asarray(VELOCITY)[None] * ((t - t[0]) * 1e-9 + 0.25)[:, None]
    w = create_dataset(url).scene("walk_01")
    pw = w.frame_array("pose/T_world_radar", (4, 4), "float64", ["frame", "row", "col"], "m")
    pw.write_shard(0, P)
    mot = motion_from_poses(P, t, sc["radar/cycle_ns"][...], span[:, 1])
    np.testing.assert_allclose(mot, sc["radar/iq_motion"][...], rtol=1e-6, atol=1e-9)
    # interrupted after the first shard of a new imaging: validate says so, the rerun finishes
    bf = importlib.import_module("holodata.radar.beamform")
    calls = {"n": 0}
    real = bf.beamform

    def boom(*a, **k):
        calls["n"] += 1
        if calls["n"] > 1:
            raise KeyboardInterrupt
        return real(*a, **k)

    import holodata.reimage as stage
    stage.beamform, orig = boom, stage.beamform
    try:
        with pytest.raises(KeyboardInterrupt):
            beamform_scene(url, "walk_01", motion="slam")
    finally:
        stage.beamform = orig
    assert not validate_dataset(url)["ok"]
    beamform_scene(url, "walk_01", motion="slam")
    assert validate_dataset(url)["ok"]
    np.testing.assert_allclose(np.asarray(open_dataset(url).scene("walk_01")["radar/heatmap"][...]), first,
                               rtol=1e-3, atol=2e-3 * first.max())


@pytest.mark.slow
def test_beamform_runs_as_dask_tasks_per_shard_with_the_local_result(moving, tmp_path):
    from holodata.distributed import cluster
    from holodata.ingest import IngestOptions, ingest
    from holodata.reimage import beamform_scene

    urls = [str(tmp_path / n) for n in ("a.zarr", "b.zarr")]
    for u in urls:
        ingest([moving.folder], u, IngestOptions(beamform=PARAMS, keep_iq=True, shard_frames=1))
    wide = replace(PARAMS, azimuth_fov_deg=60.0)
    beamform_scene(urls[0], "walk_01", wide)
    with cluster(2, None) as client:
        r = beamform_scene(urls[1], "walk_01", wide, client=client)
    assert r["n_syn"] == wide.syn_count(512) and validate_dataset(urls[1])["ok"]
    a, b = (np.asarray(open_dataset(u).scene("walk_01")["radar/heatmap"][...]) for u in urls)
    np.testing.assert_array_equal(a, b)


def test_a_turning_robot_s_rotations_end_after_one_turn_relative_to_the_world(moving, tmp_path):
    """With the IMU's yaw rate ω the radar turns by dθ0 − dt·ω per chirp relative to the world, so one
    rotation takes round(2π / (dθ0 − dt·ω)) chirps (PanoRadar's rotation ends), not the next radar_sep."""
    turning = tmp_path / "walk_turn"
    shutil.copytree(moving.folder, turning)
    imu = np.load(turning / "imu_data.npy")
    np.save(turning / "imu_data.npy", np.full_like(imu, 30.0))           # 30 deg/s counter-clockwise
    rec = open_recording(turning, beamform=PARAMS)
    dtheta0, dt = 2 * np.pi / 512, CHIRP.chirp_period_s
    n = int(round(2 * np.pi / (dtheta0 - dt * np.deg2rad(30.0))))
    assert n == 534
    assert [int(rec.end[k] - rec.sep[k]) for k in rec.rotations] == [n] * len(rec.rotations)
    assert rec.attrs["beamform"]["rotation_end"].startswith("one turn relative to the world")
    h = (PARAMS.syn_count(n) - 1) // 2            # a longer rotation's beams reach further into its neighbours
    C = rec.radar.shape[0]
    assert rec.rotations == [k for k in range(3) if rec.sep[k] - h >= 0 and rec.end[k] + h <= C] == [1]
    assert any("left out" in p for p in rec.problems)
    m = rec.heatmap(1)
    assert m.cycle_end_ns - m.cycle_start_ns == pytest.approx(n * dt * 1e9, rel=1e-6)


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1"])
def test_raw_rotations_in_a_bag_are_beamformed_by_ingest_like_the_folder(moving, tmp_path, fmt):
    """The same rotations as holodata_msgs/msg/RadarRawRotation messages (definition embedded) ingest to
    the heatmaps the folder reader makes (both with each rotation's own static reflection), keep their
    samples with --keep-iq, and say how they were imaged."""
    from holodata.ingest import IngestOptions, ingest
    from holodata.synth.panoradar_raw import write_raw_bag

    bag = write_raw_bag(moving.folder, tmp_path / "walk_bag", fmt=fmt)
    params = replace(PARAMS, static_removal="rotation")
    a, b = str(tmp_path / "bag.zarr"), str(tmp_path / "dir.zarr")
    ingest([bag], a, IngestOptions(beamform=params, keep_iq=True), scene_ids=["bag"])
    ingest([moving.folder], b, IngestOptions(beamform=params), scene_ids=["dir"])
    assert validate_dataset(a)["ok"]
    sa, sb = open_dataset(a).scene("bag"), open_dataset(b).scene("dir")
    np.testing.assert_allclose(np.asarray(sa["radar/heatmap"][...]), np.asarray(sb["radar/heatmap"][...]),
                               rtol=1e-5, atol=1e-6 * float(np.asarray(sb["radar/heatmap"][...]).max()))
    bf = sa.attrs["source"]["beamform"]
    assert bf["params"]["static_removal"] == "rotation" and bf["chirp"]["n_samples"] == 256
    assert "radar/iq" in sa and "radar/iq_static" not in sa
    from holodata.reimage import beamform_scene

    beamform_scene(a, "bag", motion="recorded")                        # re-imaged from the kept samples
    np.testing.assert_allclose(np.asarray(open_dataset(a).scene("bag")["radar/heatmap"][...]),
                               np.asarray(sb["radar/heatmap"][...]), rtol=1e-4,
                               atol=1e-5 * float(np.asarray(sb["radar/heatmap"][...]).max()))


def test_a_bag_without_its_chirp_configuration_is_a_one_line_error(moving, tmp_path):
    from holodata.synth.panoradar_raw import write_raw_bag

    bag = write_raw_bag(moving.folder, tmp_path / "nochirp", chirp_config=False)
    url = tmp_path / "ds.zarr"
    r = CliRunner().invoke(cli, ["ingest", str(bag), "--out", str(url), "--quiet"])
    assert r.exit_code == 1 and "/radar/raw" in r.output and "chirp configuration" in r.output, r.output
    assert "Traceback" not in r.output
    assert not url.exists() or not validate_dataset(str(url))["ok"]


def test_beamform_focus_near_is_recorded_and_reimages(moving, tmp_path):
    """`holodata beamform --focus near` re-images the stored samples with near-field focusing and says so
    in source.beamform (params.focus and the focus description); ingest's own run was the far field."""
    from holodata.ingest import IngestOptions, ingest

    url = str(tmp_path / "ds.zarr")
    ingest([moving.folder], url, IngestOptions(beamform=PARAMS, keep_iq=True))
    sc = open_dataset(url).scene("walk_01")
    assert sc.attrs["source"]["beamform"]["params"]["focus"] == "far"
    first = np.asarray(sc["radar/heatmap"][...])
    r = CliRunner().invoke(cli, ["beamform", url, "--focus", "near", "--quiet"])
    assert r.exit_code == 0, r.output
    again = open_dataset(url).scene("walk_01")
    bf = again.attrs["source"]["beamform"]
    assert bf["params"]["focus"] == "near" and bf["focus"].startswith("near field")
    assert validate_dataset(url)["ok"]
    near = np.asarray(again["radar/heatmap"][...])
    assert near.shape == first.shape and not np.allclose(near, first, rtol=1e-2)


def test_a_static_building_folder_makes_its_trajectories_static_and_an_override_reads_others(tmp_path):
    """PanoRadar decides static vs moving from the building folder holding the trajectories
    (process_raw_data.py: ``'static' in in_building_folder.name``): ``bldg_static/exp-000`` (2 rotations
    with no chirps beyond them, a robot at rest) ingests as static, ``--list`` names the rule, and a
    folder named otherwise needs ``--beamform-motion static`` (without it: a one-line error that says so)."""
    tr = box_room_trajectory(tmp_path / "bldg_static" / "exp-000", BoxRoomRun(n_rotations=2, pad=0), chirp=CHIRP,
                             room=ROOM)
    odd = tmp_path / "lab_run" / "exp-001"
    shutil.copytree(tr.folder, odd)
    run = CliRunner().invoke
    r = run(cli, ["ingest", "--list", str(tr.folder), "--beamform-grid", "16x64"])
    assert r.exit_code == 0, r.output
    assert "Motion:    static: parent folder 'bldg_static'" in r.output and "Ingest:    yes" in r.output, r.output
    url = str(tmp_path / "ds.zarr")
    r = run(cli, ["ingest", str(tr.folder), "--out", url, "--beamform-grid", "16x64", "--quiet"])
    assert r.exit_code == 0, r.output
    sc = open_dataset(url).scene("exp-000")
    bf = sc.attrs["source"]["beamform"]
    assert bf["padding"] == "circular" and bf["rotations_imaged"] == 2 and bf["motion"].startswith("static: parent")
    assert sc["radar/heatmap"].shape == (2, 256, 16, 64)
    # the same samples under a name that says nothing: moving, refused, then static when told
    moving = "moving: neither folder 'exp-001' nor its parent 'lab_run' names 'static'"
    for args in (["--list"], ["--out", str(tmp_path / "bad.zarr"), "--quiet"]):
        r = run(cli, ["ingest", *args, str(odd), "--beamform-grid", "16x64"])
        assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
        assert "no rotation can be imaged" in r.output and moving in r.output, r.output
        assert "a robot at rest: --beamform-motion static" in r.output, r.output
    r = run(cli, ["ingest", "--list", str(odd), "--beamform-grid", "16x64", "--beamform-motion", "static"])
    assert "Motion:    static: given (--beamform-motion static)" in r.output, r.output
    url2 = str(tmp_path / "odd.zarr")
    r = run(cli, ["ingest", str(odd), "--out", url2, "--beamform-grid", "16x64", "--beamform-motion", "static",
                  "--quiet"])
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(np.asarray(open_dataset(url2).scene("exp-001")["radar/heatmap"][...]),
                                  np.asarray(sc["radar/heatmap"][...]))
