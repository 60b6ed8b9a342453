"""raytrace-gt stage: beam origins, human sources, standalone CLI end to end, resume, bad input."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
from _paths import TESTS
from _scenes import HUMAN, box, l_corridor
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

import holodata.dataset as hds
from holodata.cli.main import cli
from holodata.conventions import Grid, Label
from holodata.errors import InputError
from holodata.groundtruth import (
    GTConfig,
    HumanDir,
    OriginModel,
    RaytraceStandalone,
    beam_rays,
    column_times,
    points_to_mesh,
)
from holodata.meshio import Mesh, write_ply
from holodata.raytrace import RayScene
from holodata.trajectory import Trajectory, write_tum

HAVE_DATASET = hasattr(hds, "create_dataset") and hasattr(hds, "open_dataset")
needs_dataset = pytest.mark.skipif(not HAVE_DATASET, reason="holodata.dataset API not available yet")


def pose(x, y, yaw=0.0):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:2, 3] = x, y
    return T


def test_beam_rays_centre_and_rotation_circle():
    g = Grid(4, 8)
    T = pose(1.0, 2.0, np.pi / 2)
    o, d = beam_rays(g, T)
    np.testing.assert_allclose(o, np.tile([1.0, 2.0, 0.0], (32, 1)))
    # yaw 90 deg: column 0 (radar +x) looks along world +y
    np.testing.assert_allclose(d.reshape(4, 8, 3)[:, 0, :2] / np.cos(g.elevations())[:, None], [[0, 1]] * 4, atol=1e-12)
    o, d = beam_rays(g, T, OriginModel(rotation_radius=0.105))
    o = o.reshape(4, 8, 3)
    r = o - [1.0, 2.0, 0.0]
    np.testing.assert_allclose(np.linalg.norm(r, axis=-1), 0.105)
    # the origin sits on the circle in the column's own azimuth (outward along the beam's plan direction)
    horiz = d.reshape(4, 8, 3)[..., :2]
    horiz = horiz / np.linalg.norm(horiz, axis=-1, keepdims=True)
    np.testing.assert_allclose(r[..., :2] / 0.105, horiz, atol=1e-12)


@pytest.mark.parametrize("radius", [0.0, 0.105])
@pytest.mark.parametrize("grid", ["64x512", "7x33"])
def test_column_rays_soa_equals_beam_rays_to_the_bit(grid, radius):
    """trace_frame's per-column beams (float32 (3,N), no einsum) are beam_rays's float64 beams cast
    to float32, bit for bit, so the traced ground truth does not change."""
    from holodata.groundtruth import column_rays_soa

    g = Grid.parse(grid, "-45,45")
    origin = OriginModel(rotation_radius=radius)
    for seed in range(4):
        col = np.tile(np.eye(4), (g.W, 1, 1))
        col[:, :3, :3] = Rotation.random(g.W, random_state=seed).as_matrix()
        col[:, :3, 3] = np.random.default_rng(seed).normal(scale=5.0, size=(g.W, 3))
        o, d = beam_rays(g, np.eye(4), origin, col)
        o32, d32 = column_rays_soa(g, origin, col)
        assert o32.dtype == d32.dtype == np.float32 and o32.shape == d32.shape == (3, g.H * g.W)
        assert np.array_equal(o32, o.T.astype(np.float32)) and np.array_equal(d32, d.T.astype(np.float32))


def test_column_time_uses_slerp_poses():
    g = Grid(2, 4)
    traj = Trajectory(np.array([0, 500_000_000]), np.stack([pose(0, 0, 0.0), pose(1.0, 0, np.pi / 2)]))
    om = OriginModel(column_time=True, rotation_hz=2.0)
    # frame stamped at the middle of its 0.5 s rotation (t = 0.25 s); column centres at 1/8, 3/8, ...
    ts = column_times(250_000_000, g, om)
    assert ts.tolist() == [62_500_000, 187_500_000, 312_500_000, 437_500_000]
    cols = traj.interpolate(ts)
    o, d = beam_rays(g, traj.poses[0], om, cols)
    o = o.reshape(2, 4, 3)
    np.testing.assert_allclose(o[0, :, 0], [0.125, 0.375, 0.625, 0.875])  # linear translation
    # column 2 at t=0.3125 s: yaw 56.25 deg; its azimuth is -pi in the radar frame
    d2 = d.reshape(2, 4, 3)[0, 2]
    assert np.arctan2(d2[1], d2[0]) == pytest.approx(np.deg2rad(56.25) - np.pi)


def test_points_to_mesh_is_hit_by_rays():
    pts = np.random.default_rng(0).normal([3.0, 0, 0], 0.2, size=(500, 3))
    v, f = points_to_mesh(pts)
    assert len(f) % 8 == 0 and len(f) <= 8 * 500
    sc = RayScene(*box([-10, -10, -10], [10, 10, 10]))
    hit = sc.cast(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), dynamic=(v, f))
    assert hit.hit_dynamic[0] and 2.0 < hit.t[0] < 3.0


@pytest.fixture
def inputs(tmp_path):
    v, f = l_corridor()
    write_ply(tmp_path / "scene.ply", Mesh(v, f))
    T = 10
    poses = np.stack([pose(x, 1.0) for x in np.linspace(5.0, 7.5, T)])
    write_tum(tmp_path / "radar.tum", Trajectory(np.arange(T) * 500_000_000 + 10**9, poses))
    hdir = tmp_path / "humans"
    hdir.mkdir()
    for k in range(T):  # the human steps along corridor B, 5 cm per frame
        write_ply(hdir / f"{k:06d}.ply", Mesh(HUMAN[0] + [0, 0.05 * k, 0], HUMAN[1]))
    return tmp_path


def test_human_dir_missing_frame_names_file(inputs):
    os.remove(inputs / "humans" / "000004.ply")
    with pytest.raises(InputError, match="000004.ply: human mesh for frame 4 is missing"):
        HumanDir(inputs / "humans", 10)


@pytest.mark.parametrize("case", ["empty_mesh", "bad_tum", "missing_human", "unreadable_mesh"])
def test_bad_input_exits_1_and_creates_nothing(inputs, case):
    args = ["raytrace-gt", "--mesh", str(inputs / "scene.ply"), "--poses", str(inputs / "radar.tum"),
            "--human-dir", str(inputs / "humans"), "--out", str(inputs / "out.zarr"), "--quiet"]
    expect = {"empty_mesh": "scene.ply: mesh has no triangles", "bad_tum": "radar.tum:3:",
              "missing_human": "000007.ply: human mesh for frame 7 is missing", "unreadable_mesh": "scene.ply: malformed"}[case]
    if case == "empty_mesh":
        write_ply(inputs / "scene.ply", Mesh(np.zeros((3, 3)), np.zeros((0, 3), int)))
    elif case == "bad_tum":
        lines = (inputs / "radar.tum").read_text().splitlines()
        lines[2] = "1.5 0 0 zero 0 0 0 1"
        (inputs / "radar.tum").write_text("\n".join(lines) + "\n")
    elif case == "missing_human":
        os.remove(inputs / "humans" / "000007.ply")
    else:
        (inputs / "scene.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n"
                                           b"property float x\nproperty float y\nproperty float z\nend_header\n\x00")
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 1, r.output
    assert expect in r.output and len(r.output.strip().splitlines()) == 1
    assert not (inputs / "out.zarr").exists()


def test_usage_errors_exit_2(inputs):
    r = CliRunner().invoke(cli, ["raytrace-gt", "--mesh", str(inputs / "scene.ply"), "--out", "x.zarr"])
    assert r.exit_code == 2
    r = CliRunner().invoke(cli, ["raytrace-gt"])
    assert r.exit_code == 2
    r = CliRunner().invoke(cli, ["raytrace-gt", "--help"])
    assert r.exit_code == 0 and "holodata raytrace-gt --mesh" in r.output


@needs_dataset
def test_standalone_end_to_end_matches_direct_trace_and_resumes(inputs):
    out = inputs / "out.zarr"
    args = ["raytrace-gt", "--mesh", str(inputs / "scene.ply"), "--poses", str(inputs / "radar.tum"),
            "--human-dir", str(inputs / "humans"), "--out", str(out), "--scene-id", "c1", "--grid", "8x32",
            "--shard-frames", "4", "--no-column-time", "--quiet", "--json"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output)
    assert summary["scenes"][0]["shards_written"] == 3 and summary["scenes"][0]["frames"] == 10
    ds = hds.open_dataset(str(out))
    s = ds.scene("c1")
    rng = np.asarray(s["gt/range"][...])
    lab = np.asarray(s["gt/label"][...])
    assert rng.shape == (10, 3, 8, 32) and lab.dtype == np.uint8
    assert np.asarray(s["gt/normal"][...]).shape == (10, 3, 8, 32, 3)
    assert np.asarray(s["time/timestamp_ns"][...]).tolist() == list(np.arange(10) * 500_000_000 + 10**9)
    assert s.attrs["gt"]["max_bounces"] == 3 and s.attrs["gt"]["origin_model"]["type"] == "rotation_centre"
    assert s.attrs["gt"]["origin_model"]["column_time"] is False and s.attrs["gt"]["origin_source"] == "flags"
    # frame 9 independently: same poses, same human, same grid
    g = Grid(8, 32)
    o, d = beam_rays(g, pose(7.5, 1.0))
    ref = RayScene(*l_corridor()).trace(o, d, dynamic=(HUMAN[0] + [0, 0.45, 0], HUMAN[1]))
    np.testing.assert_allclose(rng[9], ref.range.T.reshape(3, 8, 32), atol=1e-4)  # float32 beam rotation
    np.testing.assert_array_equal(lab[9], ref.label.T.reshape(3, 8, 32))
    assert set(np.unique(lab)) >= {Label.LOS_STRUCTURE, Label.NLOS_STRUCTURE}
    hc = np.asarray(s["gt/human_center"][...])
    np.testing.assert_allclose(hc[9, 0], (HUMAN[0] + [0, 0.45, 0]).mean(0), atol=1e-5)
    rep = hds.validate_dataset(str(out))
    assert rep["ok"], rep["problems"][:3]
    # rerun: everything done, nothing rewritten
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0 and json.loads(r.output)["scenes"][0]["shards_skipped"] == 3


@needs_dataset
def test_interrupted_run_resumes_only_missing_shards(inputs, monkeypatch):
    import holodata.raytrace.frames as gtm  # FrameTracer calls trace_frame from there

    out = str(inputs / "out.zarr")
    cfg = GTConfig(grid=Grid(4, 16), shard_frames=3)
    calls = []
    crash = [True]
    real = gtm.trace_frame

    def boom(scene, cfg_, traj, k, *a, **kw):
        calls.append(k)
        if k == 7 and crash[0]:
            raise RuntimeError("simulated crash")
        return real(scene, cfg_, traj, k, *a, **kw)

    monkeypatch.setattr(gtm, "trace_frame", boom)
    with pytest.raises(RuntimeError, match="simulated crash"):
        RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", out, human=inputs / "humans" / "000000.ply", cfg=cfg).run()
    calls.clear()
    crash[0] = False
    summary = RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", out, human=inputs / "humans" / "000000.ply",
                                 cfg=cfg).run()
    assert sorted(calls) == [6, 7, 8, 9]  # shards 0 and 1 (frames 0-5) were already written (two threads trace)
    assert summary["scenes"][0]["shards_skipped"] == 2
    rng = np.asarray(hds.open_dataset(out).scene("scene")["gt/range"][...])
    assert np.isfinite(rng[:, 0]).any(axis=(1, 2)).all()


@needs_dataset
def test_dataset_form_reads_mesh_poses_and_human(tmp_path):
    from holodata.conventions import RangeBins

    url = str(tmp_path / "ds.zarr")
    g = Grid(8, 32)
    T = 5
    v, f = l_corridor()
    w = hds.create_dataset(url, grid=g, range_bins=RangeBins(), created_by="test", provenance={}, shard_frames=4)
    sc = w.scene("c1", n_frames=T, attrs={"corner_type": "L", "width_m": 2.0})
    ta = sc.frame_array("time/timestamp_ns", per_frame_shape=(), dtype="int64", dims=["frame"], units="ns", fill_value=0)
    pa = sc.frame_array("pose/T_world_radar", per_frame_shape=(4, 4), dtype="float64", dims=["frame", "row", "col"],
                        units="m", fill_value=float("nan"))
    poses = np.stack([pose(7.0, 0.5) for _ in range(T)])
    for k in range(ta.n_shards):
        ta.write_shard(k, (np.arange(T) * 500_000_000)[ta.frames(k)])
        pa.write_shard(k, poses[pa.frames(k)])
    sc.write_array("mesh/vertices", v.astype(np.float32), dims=["vertex", "xyz"], units="m")
    sc.write_array("mesh/faces", f.astype(np.int32), dims=["face", "corner"], units="1")
    hv = sc.ragged_array("human/vertices", width=3, dtype="float32", units="m")
    hf = sc.ragged_array("human/faces", width=3, dtype="int32", units="1")
    for k in range(hv.n_shards if hasattr(hv, "n_shards") else 2):
        frames = range(T)[ta.frames(k)]
        hv.write_shard(k, [HUMAN[0].astype(np.float32) if i % 2 == 0 else np.zeros((0, 3), np.float32) for i in frames])
        hf.write_shard(k, [HUMAN[1].astype(np.int32) if i % 2 == 0 else np.zeros((0, 3), np.int32) for i in frames])
    r = CliRunner().invoke(cli, ["raytrace-gt", url, "--scene", "c1", "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    s = hds.open_dataset(url).scene("c1")
    lab = np.asarray(s["gt/label"][...])
    assert lab.shape == (T, 3, 8, 32)
    hc = np.asarray(s["gt/human_center"][...])
    assert np.isfinite(hc[0]).all() and np.isnan(hc[1]).all()
    # the human around the corner is seen only by reflection in even frames (label 4)
    assert (lab[0] == Label.NLOS_HUMAN).any() and not (lab[1] >= Label.LOS_HUMAN).any()
    assert s.attrs["gt"]["human"]["kind"] == "dataset:human/vertices+faces"


def test_dataset_human_uses_registered_points_never_raw_camera_points(tmp_path):
    from holodata.conventions import Grid, RangeBins
    from holodata.dataset import create_dataset
    from holodata.groundtruth import HumanDataset

    url = str(tmp_path / "h.zarr")
    w = create_dataset(url, grid=Grid(8, 32), range_bins=RangeBins(), created_by="test", shard_frames=2)
    sc = w.scene("s", n_frames=2)
    cam = sc.ragged_array("camera/points", 3)
    cam.write_shard(0, [np.ones((5, 3), np.float32), np.ones((5, 3), np.float32)])
    assert HumanDataset(url, "s").kind == "none"  # camera frame: not a human in the map
    hp = sc.ragged_array("human/points", 3)
    hp.write_shard(0, [np.zeros((0, 3), np.float32), np.array([[1.0, 2.0, 0.5]], np.float32)])
    src = HumanDataset(url, "s")
    assert src.kind == "dataset:human/points"
    assert src(0) is None
    v, f = src(1)
    assert len(f) > 0 and np.allclose(v.mean(axis=0), [1.0, 2.0, 0.5], atol=1e-6)


@pytest.mark.parametrize("have_mesh", [True, False])
def test_dataset_form_says_what_is_missing(tmp_path, have_mesh):
    """A scene without radar poses (LiDAR-only, no radar extrinsic) must not be told to 'run slam'
    when slam already ran; one without a mesh must be."""
    from holodata.conventions import RangeBins

    url = str(tmp_path / "ds.zarr")
    w = hds.create_dataset(url, grid=Grid(8, 32), range_bins=RangeBins(), created_by="test", provenance={},
                           shard_frames=4)
    sc = w.scene("c1", n_frames=2, attrs={"corner_type": "L", "width_m": 2.0})
    ta = sc.frame_array("time/timestamp_ns", per_frame_shape=(), dtype="int64", dims=["frame"], units="ns", fill_value=0)
    ta.write_shard(0, np.array([0, 500_000_000]))
    if have_mesh:
        v, f = l_corridor()
        sc.write_array("mesh/vertices", v.astype(np.float32), dims=["vertex", "xyz"], units="m")
        sc.write_array("mesh/faces", f.astype(np.int32), dims=["face", "corner"], units="1")
    r = CliRunner().invoke(cli, ["raytrace-gt", url, "--scene", "c1", "--quiet"])
    assert r.exit_code == 1 and "Traceback" not in r.output
    assert ("static TF" in r.output) == have_mesh and ("run holodata slam first" in r.output) != have_mesh
    assert "gt" not in "".join(hds.open_dataset(url).scene("c1").arrays())


def test_process_pool_matches_in_process(inputs):
    """``processes=2`` (spawned workers, results through shared memory) writes the same shards."""
    from holodata.groundtruth import RaytraceStandalone

    kw = dict(human_dir=inputs / "humans", cfg=GTConfig(grid=Grid(8, 32), shard_frames=4), quiet=True)
    RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", str(inputs / "a.zarr"), processes=1, **kw).run()
    RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", str(inputs / "b.zarr"), processes=2, **kw).run()
    a, b = hds.open_dataset(str(inputs / "a.zarr")).scene("scene"), hds.open_dataset(str(inputs / "b.zarr")).scene("scene")
    for name in ("gt/range", "gt/label", "gt/normal"):
        np.testing.assert_array_equal(np.asarray(a[name][...]), np.asarray(b[name][...]))



DIE_SCRIPT = '''
import os, signal, sys
import numpy as np
sys.path.insert(0, {tests!r})
import holodata.dataset as hds
from holodata.conventions import Grid, RangeBins
from holodata.groundtruth import GTConfig, HumanSource, TraceInputs, TracingError, write_scene_gt
from holodata.trajectory import Trajectory
from _scenes import l_corridor


class DieAt(HumanSource):
    """Kills the worker process that asks for frame ``frame`` (as a signal or the OOM killer would)."""

    def __init__(self, frame):
        self.frame, self.parent = frame, os.getpid()

    def __call__(self, k):
        if k == self.frame and os.getpid() != self.parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return None


if __name__ == "__main__":
    v, f = l_corridor()
    T = np.tile(np.eye(4), (12, 1, 1))
    T[:, :2, 3] = np.c_[np.linspace(5.0, 7.5, 12), np.ones(12)]
    traj = Trajectory(np.arange(12) * 500_000_000 + 10**9, T)
    cfg = GTConfig(grid=Grid(8, 32), shard_frames=4)
    w = hds.create_dataset(sys.argv[1], grid=cfg.grid, range_bins=RangeBins(), created_by="test", provenance={{}},
                           shard_frames=4)
    sc = w.scene("s", n_frames=12)
    try:
        write_scene_gt(sc, TraceInputs((v, f, None, None), cfg, traj, DieAt(int(sys.argv[2]))), {{}}, processes=2)
        print("finished")
    except TracingError as err:
        print("TracingError:", err)
'''


@pytest.mark.slow
def test_process_pool_dead_worker_raises_instead_of_hanging(tmp_path):
    """A tracing worker killed mid-run (SIGKILL, as by the OOM killer) stops the run with a
    TracingError naming the problem — multiprocessing.Pool would wait forever for its task — and the
    shards finished before it are kept."""
    import subprocess
    import sys

    script = tmp_path / "die.py"
    script.write_text(DIE_SCRIPT.format(tests=str(TESTS)))
    url = str(tmp_path / "ds.zarr")
    r = subprocess.run([sys.executable, str(script), url, "9"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "TracingError:" in r.stdout and "a tracing process died" in r.stdout and "rerun to resume" in r.stdout
    import re

    done, total = map(int, re.search(r"(\d+) of (\d+) shards are written", r.stdout).groups())
    assert total == 3 and done < 3  # frame 9 is in the last shard: that one is never written


def test_standalone_takes_a_human_source_object(inputs):
    """The Python API's ``human=`` also takes any HumanSource (e.g. a dataset's surfaces): the same GT as
    the per-frame files it serves."""
    cfg = GTConfig(grid=Grid(8, 32), shard_frames=4)
    RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", str(inputs / "files.zarr"),
                       human_dir=inputs / "humans", cfg=cfg).run()
    RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", str(inputs / "object.zarr"),
                       human=HumanDir(inputs / "humans", 10), cfg=cfg).run()
    a, b = (hds.open_dataset(str(inputs / n)).scene("scene") for n in ("files.zarr", "object.zarr"))
    lab = np.asarray(b["gt/label"][...])
    assert np.isin(lab, [Label.LOS_HUMAN, Label.NLOS_HUMAN]).any()
    np.testing.assert_array_equal(np.asarray(a["gt/range"][...]), np.asarray(b["gt/range"][...]))
    np.testing.assert_array_equal(np.asarray(a["gt/label"][...]), lab)


@needs_dataset
def test_standalone_columns_span_the_time_to_the_next_frame(tmp_path):
    """A TUM trajectory one frame per line 0.1 s apart (0.5 m per frame): each frame's columns span its
    stamp to the next one's, so the middle frame's column j sits at x_k + 0.5 m·(j + 0.5)/W, never
    beyond the next frame (the dataset form's 2 Hz default SLERPed the columns across five frames);
    the last frame keeps its own pose; --rotation-hz 20 spans 0.05 s; --rotation-hz 2 (0.5 s > 0.1 s)
    is a one-line error; the summary line names the model."""
    v, f = box((-3.0, -3.0, -1.5), (5.0, 3.0, 1.5))
    write_ply(tmp_path / "box.ply", Mesh(v, f))
    xs = 0.5 * np.arange(5)
    t0 = 10**9
    write_tum(tmp_path / "radar.tum", Trajectory(t0 + np.arange(5) * 100_000_000, np.stack([pose(x, 0.0) for x in xs])))
    g = Grid(8, 32)
    scene = RayScene(v, f)

    def run(name, *extra):
        return CliRunner().invoke(cli, ["raytrace-gt", "--mesh", str(tmp_path / "box.ply"), "--poses",
                                        str(tmp_path / "radar.tum"), "--out", str(tmp_path / name), "--grid", "8x32",
                                        "--max-bounces", "1", *extra])

    def bounce1(name):
        return np.asarray(hds.open_dataset(str(tmp_path / name)).scene("scene")["gt/range"][...])[:, 0]

    def expected(x0, span_m):
        """Bounce 1 with column j's pose at x0 + span_m·(j + 0.5)/W, traced column by column."""
        cols = np.stack([pose(x0 + span_m * (j + 0.5) / g.W, 0.0) for j in range(g.W)])
        o, d = beam_rays(g, np.eye(4), OriginModel(), cols)
        return scene.trace(o, d, max_bounces=1).range[:, 0].reshape(g.H, g.W)

    r = run("next.zarr")
    assert r.exit_code == 0, r.output
    assert "columns span each frame's stamp to the next frame's" in r.output.strip().splitlines()[-1], r.output
    got = bounce1("next.zarr")
    np.testing.assert_allclose(got[2], expected(xs[2], 0.5), atol=1e-4)       # 0.1 mm, every column
    np.testing.assert_allclose(got[4], expected(xs[4], 0.0), atol=1e-4)       # the last frame: its own pose
    gt = hds.open_dataset(str(tmp_path / "next.zarr")).scene("scene").attrs["gt"]
    assert gt["column_times_from"] == "columns span each frame's stamp to the next frame's"
    # the rotations it used are stored, so evaluate places each column where the GT did
    cyc = np.asarray(hds.open_dataset(str(tmp_path / "next.zarr")).scene("scene")["radar/cycle_ns"][...])
    assert cyc.tolist() == [[t0 + k * 10**8, t0 + (k + 1) * 10**8] for k in range(5)]
    assert hds.validate_dataset(str(tmp_path / "next.zarr"))["ok"]
    r = run("still.zarr", "--no-column-time")
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(bounce1("still.zarr")[2], expected(xs[2], 0.0), atol=1e-4)
    r = run("fast.zarr", "--rotation-hz", "20")
    assert r.exit_code == 0 and "columns span 0.05 s (20 Hz) from each frame's stamp" in r.output, r.output
    np.testing.assert_allclose(bounce1("fast.zarr")[2], expected(xs[2], 0.25), atol=1e-4)
    r = run("slow.zarr", "--rotation-hz", "2")
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output, r.output
    assert "radar.tum: a 2 Hz rotation lasts 0.5 s, longer than the 0.1 s between rows 1 and 2" in r.output, r.output
    assert not (tmp_path / "slow.zarr").exists()
