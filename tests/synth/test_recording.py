"""Synthetic recordings: every container opened with rosbags' AnyReader and (MCAP) the mcap reader
itself, message counts/types, monotonic timestamps, decodable radar messages, truth files,
byte-for-byte reproducibility."""
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from holodata.conventions import Grid, RangeBins
from holodata.messages import heatmap_from_msg
from holodata.synth import TOPICS, SynthSpec, synthesize
from holodata.trajectory import read_tum

SMALL = dict(frames=2, grid=Grid(8, 32), range_bins=RangeBins(64), lidar_shape=(8, 64), camera_shape=(12, 20))


def _files(root: Path) -> dict:
    """The recording's files (not holodata's manifest of what it wrote there, which names inodes)."""
    from holodata.ownership import MANIFEST

    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
            and p.name != MANIFEST}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    out = {}
    for fmt in ("mcap", "rosbag2", "rosbag1"):
        d = tmp_path_factory.mktemp(fmt)
        out[fmt] = synthesize(d / "a", SynthSpec(corner="T", format=fmt, seed=7, **SMALL), quiet=True)
    return out


@pytest.mark.parametrize("fmt", ["mcap", "rosbag2", "rosbag1"])
def test_anyreader_counts_types_order_and_radar(recordings, fmt):
    res = recordings[fmt]
    assert res.storage_file.exists() and res.storage_file.suffix == {"mcap": ".mcap", "rosbag2": ".db3", "rosbag1": ".bag"}[fmt]
    with AnyReader([res.recording]) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        assert types == TOPICS
        counts = {t: 0 for t in TOPICS}
        last = -1
        heatmaps, stamps = [], []
        for conn, t, raw in r.messages():
            assert t >= last
            last = t
            counts[conn.topic] += 1
            if conn.topic == "/radar/heatmap":
                msg = r.deserialize(raw, conn.msgtype)
                heatmaps.append(heatmap_from_msg(msg))
                s = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                assert msg.cycle_start_ns < s < msg.cycle_end_ns <= t  # logged after the cycle ends
                stamps.append(s)
            if conn.topic == "/ouster/points":
                msg = r.deserialize(raw, conn.msgtype)
                assert (msg.height, msg.width, msg.point_step) == (8, 64, 48) and not msg.is_dense
                offs = {f.name: f.offset for f in msg.fields}
                assert offs == {"x": 0, "y": 4, "z": 8, "intensity": 16, "t": 20, "reflectivity": 24, "ring": 26,
                                "ambient": 28, "range": 32}
    assert counts == res.counts
    assert counts["/radar/heatmap"] == 2 and counts["/ouster/points"] >= 9 and counts["/tf_static"] == 1
    assert all(h.shape == (64, 8, 32) and np.isfinite(h).all() and h.min() >= 0 for h in heatmaps)
    assert np.all(np.diff(stamps) > 0)
    # truth/ matches the recording
    traj = read_tum(res.trajectory_radar)
    assert len(traj) == 2 and np.abs(traj.timestamp_ns - np.array(stamps)).max() < 1000  # read_tum parses floats
    assert len(list(res.human_dir.glob("*.ply"))) == 2
    assert res.stats["lidar_human_hits"] == 0 and res.stats["camera_human_pixels"] > 0


def test_mcap_reader_decodes_every_message(recordings):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    res = recordings["mcap"]
    n, last, seen = 0, -1, set()
    with open(res.storage_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert message.log_time >= last  # stored in time order
            last = message.log_time
            n += 1
            seen.add((channel.topic, schema.name))
            if channel.topic == "/radar/heatmap":
                assert schema.name == "holodata_msgs/msg/RadarHeatmap"
                data = np.frombuffer(bytes(decoded.data), "<f2")
                assert data.size == decoded.n_range * decoded.n_elevation * decoded.n_azimuth == 64 * 8 * 32
    assert n == sum(res.counts.values())
    assert {(t, ty.replace("/msg/", "/msg/")) for t, ty in TOPICS.items()} == seen


def test_same_seed_is_byte_identical_and_other_seed_differs(recordings, tmp_path):
    for fmt in ("mcap", "rosbag1"):
        ref = recordings[fmt]
        again = synthesize(tmp_path / fmt, SynthSpec(corner="T", format=fmt, seed=7, **SMALL), quiet=True)
        a, b = _files(ref.out_dir), _files(again.out_dir)
        assert a.keys() == b.keys()
        assert all(a[k] == b[k] for k in a), [k for k in a if a[k] != b[k]]
    other = synthesize(tmp_path / "other", SynthSpec(corner="T", format="mcap", seed=8, **SMALL), quiet=True)
    assert other.storage_file.read_bytes() != recordings["mcap"].storage_file.read_bytes()


def test_sqlite3_bag_is_reproducible(recordings, tmp_path):
    again = synthesize(tmp_path / "b", SynthSpec(corner="T", format="rosbag2", seed=7, **SMALL), quiet=True)
    a, b = _files(recordings["rosbag2"].out_dir), _files(again.out_dir)
    assert a == b


def test_truth_folder(recordings):
    import json

    from holodata.meshio import read_mesh

    res = recordings["mcap"]
    scene = json.loads(res.scene_json.read_text())
    assert scene["corner_type"] == "T" and scene["seed"] == 7 and scene["human"]["height_m"] >= 1.5
    assert scene["radar"]["grid"] == {"H": 8, "W": 32, "elev_deg": [45.0, -45.0]}
    mesh = read_mesh(res.mesh)
    assert mesh.face_class is not None and "wall" in mesh.class_names.values()
    ext = json.loads((res.truth_dir / "extrinsics.json").read_text())
    T = np.array(ext["T_base_radar"])
    assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6)
    base = read_tum(res.trajectory_base)
    speed = np.linalg.norm(np.diff(base.poses[:, :2, 3], axis=0), axis=1) / (np.diff(base.timestamp_ns) / 1e9)
    assert speed.max() <= 0.5 + 1e-3


def test_no_human_recording(tmp_path):
    res = synthesize(tmp_path / "n", SynthSpec(corner="oblique", seed=2, human=False, **SMALL), quiet=True)
    assert res.human_dir is None and not (res.truth_dir / "human").exists()
    assert res.stats["camera_human_pixels"] == 0


def test_refuses_existing_output(recordings):
    from holodata.errors import InputError

    with pytest.raises(InputError, match="already holds.*--force"):
        synthesize(recordings["mcap"].out_dir, SynthSpec(corner="T", seed=7, **SMALL), quiet=True)


def test_force_replaces_a_recording(tmp_path):
    import json

    synthesize(tmp_path / "f", SynthSpec(corner="L", seed=1, **SMALL), quiet=True)
    again = synthesize(tmp_path / "f", SynthSpec(corner="T", seed=7, **SMALL), quiet=True, force=True)
    assert json.loads(again.scene_json.read_text())["corner_type"] == "T"
    assert not list((tmp_path / "f").glob(".*.partial"))


def test_size_estimate_matches_the_files_and_a_full_disk_is_refused(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    from holodata.errors import InputError
    from holodata.synth import estimate_bytes

    res = synthesize(tmp_path / "s", SynthSpec(corner="L", seed=1, **SMALL), quiet=True)
    est = estimate_bytes(SynthSpec(**{**SMALL, "frames": res.n_frames}))
    got = res.storage_file.stat().st_size
    assert 0.8 * got <= est <= 1.1 * got, (est, got)
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**9, 10**9, est // 2))
    with pytest.raises(InputError, match="GB free"):
        synthesize(tmp_path / "t", SynthSpec(corner="L", seed=1, **SMALL), quiet=True)
    assert not (tmp_path / "t" / "recording").exists()
