"""holodata ingest: tiny recordings written with rosbags' writers (radar + LiDAR + depth camera +
TF) checked array by array against what was written; real fixtures (LiDAR-only, Ouster, the bare
rosbag2 MCAP, the bag with a truncated Image) against independent decodes; rejections, bad input
and truncated recordings through the CLI; resume after an interruption."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _recordings import FIXTURES, Writer, camera_info_msg, image_msg, write_recording
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.dataset import open_dataset, validate_dataset
from holodata.ingest import IngestOptions, ingest, list_recording

needs_fixtures = pytest.mark.skipif(not FIXTURES.exists(), reason=f"fixture folder {FIXTURES} is absent")


def run(*args):
    res = CliRunner().invoke(cli, list(map(str, args)), obj={})
    return res.exit_code, res.stdout, res.stderr


def _nearest(ts, t, tol=50_000_000):
    ts = np.asarray(ts)
    j = int(np.argmin(np.abs(ts - t)))
    return j if abs(ts[j] - t) <= tol else None


def _valid(a):
    xyz = np.stack([a["x"], a["y"], a["z"]], -1).reshape(-1, 3)
    keep = xyz.any(1)
    return xyz[keep], np.broadcast_to(a["t"], a.shape).reshape(-1)[keep]


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1", "sqlite3"])
def test_radar_lidar_camera_tf_recording(tmp_path, fmt):
    rec = tmp_path / ("rec.bag" if fmt == "rosbag1" else "rec")
    truth = write_recording(rec, fmt, n_radar=5)
    out = tmp_path / "ds.zarr"
    summary = ingest([rec], out, IngestOptions(shard_frames=2))
    assert summary["ok"], summary
    ds = open_dataset(out)
    sc = ds.scene("rec")
    T = len(truth["radar"])
    assert sc.n_frames == T and sc.attrs["frame_sensor"] == "radar"
    assert (ds.grid.H, ds.grid.W, ds.range_bins.n) == (4, 16, 8) and ds.range_bins.dr == 0.0375
    np.testing.assert_array_equal(sc["time/timestamp_ns"][...], truth["radar"])
    hm = sc["radar/heatmap"][...]
    assert hm.dtype == np.float16
    np.testing.assert_array_equal(hm, np.stack(truth["heatmaps"]))
    cyc = sc["radar/cycle_ns"][...]
    np.testing.assert_array_equal(cyc[:, 1] - cyc[:, 0], 500_000_000)
    lts = sc["lidar/timestamp_ns"][...]
    cts = sc["camera/timestamp_ns"][...]
    K = truth["K"]
    for k, t in enumerate(truth["radar"]):
        j = _nearest(truth["lidar"], t)
        assert lts[k] == truth["lidar"][j]
        xyz, tt = _valid(truth["clouds"][j])
        np.testing.assert_array_equal(sc.ragged("lidar/points", k), xyz)
        np.testing.assert_array_equal(sc.ragged("lidar/point_time_ns", k)[:, 0], tt)
        rg = sc["lidar/range"][k]
        a = truth["clouds"][j]
        r = np.sqrt(a["x"].astype(np.float64) ** 2 + a["y"] ** 2 + a["z"] ** 2)
        np.testing.assert_allclose(rg[np.isfinite(rg)], r[r > 0], rtol=1e-6)
        assert np.isnan(rg).sum() == (r == 0).sum()
        c = _nearest(truth["camera"], t, 100_000_001)   # auto tolerance: half the 5 Hz camera period
        if c is None:
            assert cts[k] == 0 and len(sc.ragged("camera/points", k)) == 0
            continue
        assert cts[k] == truth["camera"][c]
        d = truth["depths"][c] / 1000.0
        v, u = np.nonzero(d > 0)
        z = d[v, u]
        expect = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], 1)
        np.testing.assert_allclose(sc.ragged("camera/points", k), expect, rtol=1e-6)
    # poses from TF: map -> odom (identity) -> base_link (odometry) -> radar (static)
    P = sc["pose/T_world_radar"][...]
    for k, t in enumerate(truth["radar"]):
        np.testing.assert_allclose(P[k], truth["odom"](t) @ truth["T_base_radar"], atol=1e-9)
    ext = sc.attrs["extrinsics"]
    np.testing.assert_allclose(ext["radar"], truth["T_base_radar"], atol=1e-12)
    np.testing.assert_allclose(ext["camera"], truth["T_base_cam"], atol=1e-9)
    src = sc.attrs["source"]
    import blake3

    assert src["truncated"] is False and "sha256" not in src
    assert src["blake3"] == [blake3.blake3(Path(f).read_bytes()).hexdigest() for f in src["files"]]
    sens = sc.attrs["sensors"]
    assert sens["camera"]["intrinsics"]["K"] == K.tolist() and sens["lidar"]["time_field"] == "t"
    ing = sc.attrs["ingest"]
    assert ing["complete"] and ing["counts"]["radar"] == T and ing["sync"]["lidar"]["matched_frames"] == T
    assert ing["dropped"]["lidar"]["not_near_a_frame"] == len(truth["lidar"]) - T
    assert ing["sync"]["camera"]["tolerance_ns"] == 100_000_001 and ing["sync"]["lidar"]["tolerance_ns"] == 50_000_001
    assert ing["sync"]["camera"]["matched_frames"] == T
    assert validate_dataset(out)["ok"]


def test_tolerance_leaves_frames_empty_and_reported(tmp_path):
    rec = tmp_path / "rec"
    truth = write_recording(rec, "mcap", n_radar=3, tf=False)
    s = ingest([rec], tmp_path / "ds.zarr", IngestOptions(tolerance_ms=1.0))["scenes"][0]
    sc = open_dataset(tmp_path / "ds.zarr").scene("rec")
    lts = sc["lidar/timestamp_ns"][...]
    expect = [truth["lidar"][j] if (j := _nearest(truth["lidar"], t, 1_000_000)) is not None else 0
              for t in truth["radar"]]
    np.testing.assert_array_equal(lts, expect)
    assert (lts == 0).any()
    for k in np.flatnonzero(lts == 0):
        assert len(sc.ragged("lidar/points", int(k))) == 0
    assert any("no lidar message within 1 ms" in w for w in s["warnings"])
    assert "pose/T_world_radar" not in sc.arrays()
    assert validate_dataset(tmp_path / "ds.zarr")["ok"]


def test_lidar_only_and_resume_after_interruption(tmp_path, monkeypatch):
    from holodata.ingest import write as ing_mod  # the write pass (its shard buffer)

    rec = tmp_path / "lid.bag"
    truth = write_recording(rec, "rosbag1", n_radar=3, radar=False, camera=False)
    calls = {"n": 0}
    orig = ing_mod._Out.flush

    def crashing_flush(self, final=False):
        if self.w.name == "lidar/points" and self.k >= 2:
            calls["n"] += 1
            raise KeyboardInterrupt  # killed after two shards
        return orig(self, final)

    monkeypatch.setattr(ing_mod._Out, "flush", crashing_flush)
    with pytest.raises(KeyboardInterrupt):
        ingest([rec], tmp_path / "ds.zarr", IngestOptions(shard_frames=3))
    monkeypatch.setattr(ing_mod._Out, "flush", orig)
    with pytest.raises(Exception, match="started with other topics/tolerance"):
        ingest([rec], tmp_path / "ds.zarr",
               IngestOptions(topics={"camera": None, "tf": None}, tolerance_ms=1.0, shard_frames=3))
    sc = open_dataset(tmp_path / "ds.zarr").scene("lid")
    assert not sc.attrs["ingest"]["complete"]
    assert not validate_dataset(tmp_path / "ds.zarr")["ok"]      # an interrupted ingest never validates
    s = ingest([rec], tmp_path / "ds.zarr", IngestOptions(shard_frames=3))["scenes"][0]
    assert s["frame_sensor"] == "lidar" and s["decoded"]["lidar"] < len(truth["lidar"])  # done shards not decoded
    sc = open_dataset(tmp_path / "ds.zarr").scene("lid")
    np.testing.assert_array_equal(sc["time/timestamp_ns"][...], truth["lidar"])
    for k, a in enumerate(truth["clouds"]):
        np.testing.assert_array_equal(sc.ragged("lidar/points", k), _valid(a)[0])
    assert validate_dataset(tmp_path / "ds.zarr")["ok"]
    again = ingest([rec], tmp_path / "ds.zarr")["scenes"][0]
    assert again["skipped"] == "already ingested"


def test_cli_topics_file_scene_ids_and_json(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b.bag"
    write_recording(a, "mcap", n_radar=2)
    write_recording(b, "rosbag1", n_radar=2)
    topics = tmp_path / "topics.yaml"
    topics.write_text("camera: null\ncamera_info: null\nlidar: /os/points\ntime: log\n")
    code, out, err = run("ingest", a, b, "--out", tmp_path / "ds.zarr", "--topics", topics,
                         "--scene-id", "c1", "--scene-id", "c2", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert [s["scene"] for s in summary["scenes"]] == ["c1", "c2"]
    ds = open_dataset(tmp_path / "ds.zarr")
    assert ds.scenes == ["c1", "c2"]
    assert "camera/points" not in ds.scene("c1").arrays()
    assert ds.scene("c1").attrs["ingest"]["time_source"] == "log"
    topics.write_text("lidr: /os/points\n")
    code, _, err = run("ingest", a, "--out", tmp_path / "ds2.zarr", "--topics", topics)
    assert code == 1 and "unknown key(s) lidr" in err and "Traceback" not in err
    topics.write_text("lidar: /nope\n")
    code, _, err = run("ingest", a, "--out", tmp_path / "ds2.zarr", "--topics", topics)
    assert code == 1 and "/nope is not a topic" in err
    code, _, err = run("ingest", a, b, "--out", tmp_path / "ds3.zarr", "--scene-id", "x")
    assert code == 1 and "1 --scene-id for 2 recordings" in err
    code, _, err = run("ingest", a)
    assert code == 2 and "--out" in err


def test_rejected_recordings_and_bad_input_exit_1_one_line(tmp_path):
    cam = tmp_path / "cam"
    w = Writer(cam, "mcap")
    w.add("/cam/depth", "sensor_msgs/msg/Image")
    w.add("/cam/info", "sensor_msgs/msg/CameraInfo")
    for k in range(2):
        w.write("/cam/depth", k, image_msg(w.T, "mcap", k, "c", np.ones((2, 2), np.uint16), "16UC1"))
        w.write("/cam/info", k, camera_info_msg(w.T, "mcap", k, "c", np.eye(3), 2, 2))
    w.close()
    bad = tmp_path / "rand.bag"
    bad.write_bytes(np.random.default_rng(0).bytes(3000))
    (tmp_path / "empty.mcap").write_bytes(b"")
    (tmp_path / "notabag").mkdir()
    cases = [(cam, "camera-only recording"), (bad, "not a ROS 1 bag"), (tmp_path / "empty.mcap", "file is empty"),
             (tmp_path / "notabag", "folder is not a recording")]
    for path, msg in cases:
        code, out, err = run("ingest", path, "--out", tmp_path / f"ds_{path.name}.zarr")
        assert code == 1, (path, out, err)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:") and msg in lines[0], err
        assert not (tmp_path / f"ds_{path.name}.zarr").exists()
    code, out, err = run("ingest", "--list", cam)
    assert code == 0 and "/cam/depth" in out and "[camera]" in out and "camera-only" in out


def test_truncated_recording_ingests_readable_part_marked(tmp_path):
    rec = tmp_path / "full.bag"
    truth = write_recording(rec, "rosbag1", n_radar=8, camera=False, radar_shape=(16, 8, 32))
    data = rec.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[:len(data) * 3 // 5])
    code, out, err = run("ingest", cut, "--out", tmp_path / "ds.zarr")
    assert code == 0, err
    assert "truncated recording" in out and "warning:" in err and "readable part" in err
    sc = open_dataset(tmp_path / "ds.zarr").scene("cut")
    assert sc.attrs["source"]["truncated"] is True and sc.attrs["source"]["problems"]
    T = sc.n_frames
    assert 0 < T < len(truth["radar"])
    np.testing.assert_array_equal(sc["time/timestamp_ns"][...], truth["radar"][:T])
    np.testing.assert_array_equal(sc["radar/heatmap"][...], np.stack(truth["heatmaps"][:T]))
    assert validate_dataset(tmp_path / "ds.zarr")["ok"]


# ---------------------------------------------------------------------------------------------- fixtures

@needs_fixtures
def test_fixture_lidar_recordings_ingest(tmp_path):
    from rosbags.highlevel import AnyReader

    out = tmp_path / "ds.zarr"
    recs = [FIXTURES / "ros1" / "luminar-test.bag", FIXTURES / "mcap" / "rosbag2_2025_09_10-13_03_56_0.mcap",
            FIXTURES / "ros2" / "sqlite3" / "test_bag_sqlite3", FIXTURES / "ros1" / "512x10_raw.bag"]
    pcaps = [FIXTURES / "ouster" / "OS-1-32-G_v2.1.1_1024x10.pcap", FIXTURES / "ouster" / "OS-0-128-U1_v2.3.0_1024x10.pcap"]
    import importlib.util

    if importlib.util.find_spec("ouster") is None:   # ouster-sdk is optional: skip the Ouster recordings
        recs, pcaps = recs[:3], []
    code, stdout, err = run("ingest", *recs, *pcaps, "--out", out)
    assert code == 0, err
    assert "warning: test_bag_sqlite3: topic /test/sensor_msgs/image: Image payload is 30 bytes" in err
    ds = open_dataset(out)
    # Luminar: every point of every cloud, per-point split time, against np.frombuffer of the documented layout
    sc = ds.scene("luminar-test")
    with AnyReader([recs[0]]) as r:
        conns = [c for c in r.connections if c.topic == "/luminar_pointcloud"]
        msgs = [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(conns)]
    assert sc.n_frames == 5 and sc.attrs["frame_sensor"] == "lidar"
    for k, m in enumerate(msgs):
        raw = np.frombuffer(m.data, np.uint8).reshape(-1, 32)
        np.testing.assert_array_equal(sc.ragged("lidar/points", k), raw[:, :12].copy().view("<f4"))
        t = raw[:, 20:24].copy().view("<u4")[:, 0].astype(np.int64) * 10**9 + raw[:, 24:28].copy().view("<u4")[:, 0]
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        np.testing.assert_array_equal(sc.ragged("lidar/point_time_ns", k)[:, 0], t - stamp)
        assert sc["time/timestamp_ns"][k] == stamp
    assert len(sc.ragged("lidar/points", 0)) == 35707
    sc = ds.scene("rosbag2_2025_09_10-13_03_56_0")
    pts = sc.ragged("lidar/points", 0)
    assert sc.n_frames == 1 and pts.shape == (200, 3) and np.isfinite(pts).all()
    sc = ds.scene("test_bag_sqlite3")
    assert sc.n_frames == 2 and len(sc.ragged("lidar/points", 0)) == 0   # 3 points at (0,0,0): no return
    if pcaps:
        for name, shape in (("512x10_raw", (128, 512)), ("OS-1-32-G_v2.1.1_1024x10", (32, 1024)),
                            ("OS-0-128-U1_v2.3.0_1024x10", (128, 1024))):
            sc = ds.scene(name)
            rg = sc["lidar/range"][0]
            assert sc.n_frames == 1 and rg.shape == shape
            assert len(sc.ragged("lidar/points", 0)) == np.isfinite(rg).sum() > 0
            assert "ouster_metadata_json" in sc.attrs["sensors"]["lidar"]
        assert np.isfinite(ds.scene("512x10_raw")["lidar/range"][0]).sum() == 28751
    assert validate_dataset(out)["ok"]


@needs_fixtures
@pytest.mark.parametrize("rel, reason", [
    ("ros1/example.bag", "no radar, point cloud, depth image or Ouster topic"),
    ("ros1/test1.bag", "IMU/odometry-only recording"),
    ("ros2/mcap/wbag", "no radar, point cloud, depth image or Ouster topic"),
    ("mcap/TenMessages-ch-chx-mx-pad-rch-rsh-st-sum.mcap", "no decodable topic"),
    ("mcap/only_topics.mcap", "no radar, point cloud"),
    ("ros2/sqlite3/cdr_test", "no radar, point cloud"),
])
def test_fixtures_without_sensor_topics_are_listed_and_rejected(tmp_path, rel, reason):
    path = FIXTURES / rel
    code, out, err = run("ingest", "--list", path)
    assert code == 0, err
    info = list_recording(path)
    assert info["messages"] == sum(t["count"] for t in info["topics"]) and not info["ingestable"]
    for t in info["topics"]:
        assert t["name"] in out and t["type"] in out
    code, out, err = run("ingest", path, "--out", tmp_path / "ds.zarr")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 1 and len(lines) == 1 and reason in lines[0] and "Traceback" not in err
    assert not (tmp_path / "ds.zarr").exists()


@needs_fixtures
def test_list_json_matches_rosbags(tmp_path):
    from rosbags.highlevel import AnyReader

    path = FIXTURES / "ros1" / "example.bag"
    code, out, _ = run("ingest", "--list", path, "--json")
    assert code == 0
    info = json.loads(out)["recordings"][0]
    with AnyReader([path]) as r:
        ref = {}
        for c in r.connections:
            ref[c.topic] = ref.get(c.topic, 0) + c.msgcount
    assert {t["name"]: t["count"] for t in info["topics"]} == ref
    assert info["reader"] == "rosbag1" and info["duration_s"] == pytest.approx(21.7, abs=0.1)


def test_stereo_only_camera_gives_points(tmp_path):
    pytest.importorskip("cv2")
    from scipy.ndimage import gaussian_filter

    # LiDAR + a rectified mono8 stereo pair (no depth image): depth comes from OpenCV SGBM
    w = Writer(tmp_path / "st2", "mcap")
    for tp, ty in (("/cam/left/image_rect", "sensor_msgs/msg/Image"), ("/cam/right/image_rect", "sensor_msgs/msg/Image"),
                   ("/cam/left/camera_info", "sensor_msgs/msg/CameraInfo"),
                   ("/cam/right/camera_info", "sensor_msgs/msg/CameraInfo"), ("/os/points", "sensor_msgs/msg/PointCloud2")):
        w.add(tp, ty)
    from _recordings import T0, cloud_msg, lidar_scan

    rng = np.random.default_rng(0)
    tex = gaussian_filter(rng.uniform(0, 255, (60, 200)), 1.2)
    fx, B = 50.0, 0.1
    K = np.array([[fx, 0, 60], [0, fx, 30], [0, 0, 1.0]])
    for k in range(3):
        t = T0 + k * 100_000_000
        L = np.clip(tex[:, 20:140], 0, 255).astype(np.uint8)
        R = np.clip(tex[:, 28:148], 0, 255).astype(np.uint8)
        w.write("/cam/left/image_rect", t, image_msg(w.T, "mcap", t, "left_opt", L, "mono8"))
        w.write("/cam/right/image_rect", t, image_msg(w.T, "mcap", t, "right_opt", R, "mono8"))
        li = camera_info_msg(w.T, "mcap", t, "left_opt", K, 120, 60)
        ri = camera_info_msg(w.T, "mcap", t, "right_opt", K, 120, 60)
        ri.p = np.array([fx, 0, 60, -fx * B, 0, fx, 30, 0, 0, 0, 1, 0], float)
        w.write("/cam/left/camera_info", t, li)
        w.write("/cam/right/camera_info", t, ri)
        w.write("/os/points", t, cloud_msg(w.T, "mcap", t, "os_sensor", lidar_scan(k)))
    w.close()
    s = ingest([tmp_path / "st2"], tmp_path / "ds.zarr")
    assert s["ok"], s
    sc = open_dataset(tmp_path / "ds.zarr").scene("st2")
    assert sc.attrs["frame_sensor"] == "lidar" and sc.attrs["sensors"]["camera"]["stereo"]["baseline_m"] == pytest.approx(B)
    for k in range(3):
        pts = sc.ragged("camera/points", k)
        assert len(pts) > 0.5 * 60 * 120
        np.testing.assert_allclose(np.median(pts[:, 2]), fx * B / 8, rtol=0.02)
    assert not any("not a depth image" in n for n in s["scenes"][0]["notes"])


def test_radar_grid_mismatch_and_same_names(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    write_recording(tmp_path / "a" / "rec", "mcap", n_radar=2, lidar=False, camera=False, tf=False)
    write_recording(tmp_path / "b" / "rec", "mcap", n_radar=2, lidar=False, camera=False, tf=False)
    write_recording(tmp_path / "other", "mcap", n_radar=2, lidar=False, camera=False, tf=False, radar_shape=(8, 4, 32))
    from holodata.errors import RecordingError

    with pytest.raises(RecordingError, match="different radar grids"):
        ingest([tmp_path / "a" / "rec", tmp_path / "other"], tmp_path / "x.zarr")
    assert not (tmp_path / "x.zarr").exists()
    s = ingest([tmp_path / "a" / "rec", tmp_path / "b" / "rec"], tmp_path / "ds.zarr")
    assert [x["scene"] for x in s["scenes"]] == ["rec_0", "rec_1"]
    code, _, err = run("ingest", tmp_path / "other", "--out", tmp_path / "ds.zarr")
    assert code == 1 and "differs from the dataset's" in err
    assert open_dataset(tmp_path / "ds.zarr").scenes == ["rec_0", "rec_1"]


def test_custom_types_without_definitions_warn_or_ask_for_msg_dir(tmp_path):
    import sqlite3

    from _recordings import T0, cloud_msg, lidar_scan
    from rosbags.typesys import get_types_from_msg

    def bag(name, with_lidar):
        w = Writer(tmp_path / name, "sqlite3")
        w.store.register(get_types_from_msg("float32[] power\n", "acme_radar/msg/Scan"))
        w.add("/acme/scan", "acme_radar/msg/Scan")
        if with_lidar:
            w.add("/os/points", "sensor_msgs/msg/PointCloud2")
        for k in range(3):
            t = T0 + k * 100_000_000
            w.write("/acme/scan", t, w.store.types["acme_radar/msg/Scan"](power=np.ones(4, np.float32)))
            if with_lidar:
                w.write("/os/points", t, cloud_msg(w.T, "sqlite3", t, "os_sensor", lidar_scan(k)))
        w.close()
        con = sqlite3.connect(tmp_path / name / f"{name}.db3")
        con.execute("DELETE FROM message_definitions WHERE topic_type = 'acme_radar/msg/Scan'")
        con.commit()
        con.close()
        return tmp_path / name

    code, out, err = run("ingest", bag("mixed", True), "--out", tmp_path / "a.zarr")
    assert code == 0, err
    assert "warning: mixed: topic /acme/scan: acme_radar/msg/Scan x3 skipped (no message definition (pass --msg-dir))" in err
    code, out, err = run("ingest", bag("only", False), "--out", tmp_path / "b.zarr")
    assert code == 1 and "pass --msg-dir with their .msg files" in err and "/acme/scan (acme_radar/msg/Scan)" in err


@pytest.mark.parametrize("array", ["radar/heatmap", "lidar/points"])
def test_a_failing_writer_thread_is_a_one_line_error_not_a_hang(tmp_path, monkeypatch, array):
    """A shard write that fails on one of ingest's writer threads (here: the disk fills up) stops the
    run within seconds with one error line naming the recording, whether the main thread is then
    decoding, waiting for queue room or joining the writers; the dataset left behind does not validate."""
    import time

    from holodata.dataset import writer as W
    from holodata.errors import HolodataError

    rec = tmp_path / "rec"
    write_recording(rec, "mcap", n_radar=8)
    cls = W.RaggedWriter if array == "lidar/points" else W.FrameArrayWriter
    orig = cls.write_shard

    def full_disk(self, k, data):
        if self.name == array and k >= 1:
            raise OSError(28, "No space left on device")
        return orig(self, k, data)

    monkeypatch.setattr(cls, "write_shard", full_disk)
    t = time.monotonic()
    with pytest.raises(HolodataError) as e:
        ingest([rec], tmp_path / "ds.zarr", IngestOptions(shard_frames=2), quiet=True)
    assert time.monotonic() - t < 60
    msg = str(e.value)
    assert "\n" not in msg and "No space left on device" in msg and str(rec) in msg, msg
    assert not validate_dataset(tmp_path / "ds.zarr")["ok"]


def test_scenes_with_a_sha256_source_digest_still_compare(tmp_path):
    """Datasets ingested before BLAKE3 carry source.sha256: re-ingesting the same recording into them
    is still 'already ingested', and another recording under the scene's name is still refused."""
    import hashlib

    from holodata.dataset import open_dataset as od
    from holodata.errors import HolodataError

    rec, other = tmp_path / "rec", tmp_path / "other" / "rec"
    write_recording(rec, "mcap", n_radar=3)
    write_recording(other, "mcap", n_radar=4)
    url = tmp_path / "ds.zarr"
    ingest([rec], url, quiet=True)
    sc = od(url, "r+").scene("rec")
    src = dict(sc.attrs["source"])
    del src["blake3"]
    src["sha256"] = [hashlib.sha256(Path(f).read_bytes()).hexdigest() for f in src["files"]]
    sc.set_attrs({"source": src})
    assert "blake3" not in od(url).scene("rec").attrs["source"]
    assert ingest([rec], url, quiet=True)["scenes"][0]["skipped"] == "already ingested"
    with pytest.raises(HolodataError, match="was ingested from another recording"):
        ingest([other], url, quiet=True)


def _count_opens(monkeypatch) -> tuple[dict, dict]:
    """Every reader's open wrapped (the registry, whoever calls it): ({recording path: opens},
    {recording path: closes of what those opens returned})."""
    import dataclasses
    from collections import Counter

    from holodata.readers import READERS

    opens, closes = Counter(), Counter()

    def wrap(spec):
        def open_(path, *a, **k):
            opens[str(path)] += 1
            rec = spec.open(path, *a, **k)
            real_close = rec.close

            def close():
                closes[str(path)] += 1
                real_close()

            rec.close = close
            return rec
        return dataclasses.replace(spec, open=open_)

    for name, spec in list(READERS.items()):
        monkeypatch.setitem(READERS, name, wrap(spec))
    return opens, closes


def test_ingest_opens_each_recording_once(tmp_path, monkeypatch):
    """Issue 44 point 3: the grid pre-pass (several recordings into a new dataset), the plan and the
    write pass share one opened recording per recording (it was opened by the pre-pass and again by
    the plan), closed once when its scene is written or it failed; a LiDAR-only recording among them
    and one rejected when planned likewise. Counted at the reader registry, whoever calls it."""
    recs = [tmp_path / "a", tmp_path / "b.bag", tmp_path / "lidar"]
    write_recording(recs[0], "mcap", n_radar=3, camera=False)
    write_recording(recs[1], "rosbag1", n_radar=3, camera=False)
    write_recording(recs[2], "mcap", n_radar=0, radar=False, camera=False)
    bad = tmp_path / "tf_only"                  # opens, has no sensor topic: rejected when planned
    write_recording(bad, "mcap", n_radar=2, radar=False, lidar=False, camera=False)
    opens, closes = _count_opens(monkeypatch)
    s = ingest(recs + [bad], tmp_path / "ds.zarr", IngestOptions(shard_frames=2))
    assert [x["scene"] for x in s["scenes"]] == ["a", "b", "lidar"] and len(s["failed"]) == 1, s
    assert dict(opens) == {str(r): 1 for r in recs + [bad]}
    assert closes == opens
    # into the existing dataset (no pre-pass) and a single recording: once as well
    opens.clear()
    closes.clear()
    write_recording(tmp_path / "c", "mcap", n_radar=3, camera=False)
    ingest([tmp_path / "c"], tmp_path / "ds.zarr", IngestOptions(shard_frames=2))
    assert dict(opens) == {str(tmp_path / "c"): 1} and closes == opens
