"""Reader registry on the real fixtures (counts from their README), damaged and bad input, message
definitions from --msg-dir, placeholder type hashes. Independent checks use rosbags / mcap directly."""
from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from _recordings import FIXTURES, Writer, write_recording

from holodata.errors import RecordingError
from holodata.readers import guess_reader, open_recording
from holodata.readers.base import DecodeError

needs_fixtures = pytest.mark.skipif(not FIXTURES.exists(), reason=f"fixture folder {FIXTURES} is absent")


def _topics(path, **kw):
    with open_recording(path, **kw) as r:
        return {t.name: t for t in r.topics()}, r.kind


@needs_fixtures
def test_ros1_fixtures_counts_and_lz4_equals_plain():
    t, kind = _topics(FIXTURES / "ros1" / "example.bag")
    assert kind == "rosbag1"
    assert t["/turtle1/pose"].count == 1344 and t["/turtle1/pose"].msgtype == "turtlesim/msg/Pose"
    assert t["/tf_static"].count == 1 and t["/tf"].count == 2688 and sum(x.count for x in t.values()) == 8647
    assert abs(t["/turtle1/pose"].rate_hz - 1343 / ((t["/turtle1/pose"].last_ns - t["/turtle1/pose"].first_ns) / 1e9)) < 1e-9
    with open_recording(FIXTURES / "ros1" / "example.bag") as a, open_recording(FIXTURES / "ros1" / "example-lz4.bag") as b:
        ma = sorted((m.topic, m.log_ns, bytes(m.data)) for m in a.raw_messages(["/turtle1/pose", "/tf"]))
        mb = sorted((m.topic, m.log_ns, bytes(m.data)) for m in b.raw_messages(["/turtle1/pose", "/tf"]))
        assert ma == mb and len(ma) == 1344 + 2688
    t, _ = _topics(FIXTURES / "ros1" / "test1.bag")
    assert (t["/imu/data"].count, t["/husky_velocity_controller/odom"].count, t["/fix"].count) == (11865, 3952, 989)
    assert t["/imu/data"].msgtype == "sensor_msgs/msg/Imu"
    t, _ = _topics(FIXTURES / "ros1" / "512x10_raw.bag")
    assert (t["/os_node0/lidar_packets"].count, t["/os_node0/imu_packets"].count, t["/os_node0/metadata"].count) == (32, 10, 1)
    t, _ = _topics(FIXTURES / "ros1" / "luminar-test.bag")
    assert t["/luminar_pointcloud"].frame_id == "luminar_lidar" and t["/luminar_pointcloud"].count == 5


@needs_fixtures
def test_ros2_fixtures_counts_frames_and_storage_equivalence():
    from rosbags.highlevel import AnyReader

    t, kind = _topics(FIXTURES / "ros2" / "sqlite3" / "cdr_test")
    assert kind == "rosbag2-sqlite3" and t["/array_topic"].count == 4 and t["/test_topic"].count == 3
    with open_recording(FIXTURES / "ros2" / "sqlite3" / "cdr_test") as a, \
            open_recording(FIXTURES / "ros2" / "mcap" / "cdr_test") as b:
        assert b.kind == "rosbag2-mcap"
        assert [(m.topic, m.log_ns) for m in a.raw_messages()] == [(m.topic, m.log_ns) for m in b.raw_messages()]
        msgs = [m for _, _, m in b.messages(["/test_topic"])]
        assert len(msgs) == 3 and hasattr(msgs[0], "int32_value")
    t, _ = _topics(FIXTURES / "ros2" / "mcap" / "wbag")
    assert len(t) == 8 and sum(x.count for x in t.values()) == 6074 and t["AAA"].count == 804
    t, _ = _topics(FIXTURES / "ros2" / "sqlite3" / "test_bag_sqlite3")
    assert len(t) == 94 and sum(x.count for x in t.values()) == 188
    assert t["/test/sensor_msgs/point_cloud2"].count == 2 and t["/test/sensor_msgs/image"].msgtype == "sensor_msgs/msg/Image"
    # bare rosbag2 MCAP without metadata.yaml: same as rosbags' AnyReader on the file
    bare = FIXTURES / "mcap" / "rosbag2_2025_09_10-13_03_56_0.mcap"
    t, _ = _topics(bare)
    with AnyReader([bare]) as r:
        ref = {c.topic: c.msgcount for c in r.connections}
    assert {k: v.count for k, v in t.items()} == ref and sum(ref.values()) == 194 and len(ref) == 32
    assert sum(1 for v in t.values() if v.count == 0) == 4
    assert t["/point_cloud2"].frame_id == "base_link" and t["/rosout"].count == 117


@needs_fixtures
def test_plain_mcap_fixtures_listed():
    t, _ = _topics(FIXTURES / "mcap" / "only_topics.mcap")
    assert t["/parameter_events"].count == 7 and t["/rosout"].count == 0 and t["/events/write_split"].count == 0
    path = FIXTURES / "mcap" / "TenMessages-ch-chx-mx-pad-rch-rsh-st-sum.mcap"
    with open_recording(path) as r:
        (info,) = r.topics()
        assert (info.name, info.msgtype, info.count, info.encoding, info.decodable) == ("example", "Example", 10, "a", False)
        raws = list(r.raw_messages())
        assert len(raws) == 10
        with pytest.raises(DecodeError, match="not a ROS encoding"):
            r.decode(raws[0])


def _file(name, data):
    def make(d: Path) -> Path:
        (d / name).write_bytes(data)
        return d / name
    return make


def _folder(d: Path) -> Path:
    (d / "folder").mkdir()
    (d / "folder" / "x.txt").write_text("hi")
    return d / "folder"


@pytest.mark.parametrize("make, pattern", [
    (_file("e.bag", b""), "file is empty"),
    (_file("r.bag", np.random.default_rng(0).bytes(4000)), "not a ROS 1 bag"),
    (_file("r.mcap", np.random.default_rng(1).bytes(4000)), "not an MCAP file"),
    (_file("r.db3", np.random.default_rng(2).bytes(4000)), "r.db3"),
    (_file("r.pcap", np.random.default_rng(3).bytes(4000)), "r.pcap"),
    (_folder, "folder is not a recording"),
    (lambda d: d / "missing.bag", "no such file"),
    (_file("x.weird", b"hello world"), "unknown recording format"),
])
def test_bad_input_is_one_line_recording_error(tmp_path, make, pattern):
    path = make(tmp_path)
    with pytest.raises(RecordingError, match=pattern) as ei, open_recording(path) as r:
        r.topics()
    assert "\n" not in str(ei.value)


def _all(path):
    with open_recording(path) as r:
        return [(m.topic, m.log_ns, bytes(m.data)) for m in r.raw_messages()], r.truncated, list(r.problems)


@pytest.mark.parametrize("fmt", ["rosbag1", "mcap"])
def test_truncated_recording_gives_readable_prefix_marked(tmp_path, fmt):
    src = tmp_path / "full"
    write_recording(src, fmt, n_radar=6, camera=False, tf=False, radar_shape=(16, 8, 32))
    f = src if fmt == "rosbag1" else src / "full.mcap"
    full, trunc, _ = _all(f)
    assert not trunc and len(full) > 30
    for frac in (0.35, 0.7, 0.97):
        cut = tmp_path / f"cut{frac}{f.suffix}"
        data = f.read_bytes()
        cut.write_bytes(data[:int(len(data) * frac)])
        got, trunc, problems = _all(cut)
        assert trunc and problems and 0 < len(got) < len(full)
        assert set(got) <= set(full)  # nothing invented, no partial payloads
        # the prefix: every message before the last one read is there
        last = max(t for _, t, _ in got)
        assert {m for m in full if m[1] < last - 200_000_000} <= set(got)
    with open_recording(cut) as r:  # a second pass over the same recording notes the break once
        for _ in range(2):
            list(r.raw_messages())
        assert r.truncated and len(r.problems) == len(set(r.problems)) >= 1


def test_truncated_rosbag2_folder_falls_back_to_storage_file(tmp_path):
    src = tmp_path / "bag"
    write_recording(src, "mcap", n_radar=6, camera=False, tf=False, radar_shape=(16, 8, 32))
    full, _, _ = _all(src)
    mc = src / "bag.mcap"
    data = mc.read_bytes()
    mc.write_bytes(data[:len(data) * 2 // 3])
    got, trunc, problems = _all(src)
    assert trunc and any("rosbags cannot open" in p for p in problems)
    assert 0 < len(got) < len(full) and set(got) <= set(full)


def test_rosbag2_without_definitions_needs_msg_dir(tmp_path):
    from rosbags.typesys import get_types_from_msg

    bag = tmp_path / "custom"
    w = Writer(bag, "sqlite3")
    w.store.register(get_types_from_msg("uint32 a\nstring b\nfloat64[] c\n", "my_pkg/msg/Blob"))
    w.add("/blob", "my_pkg/msg/Blob")
    Blob = w.store.types["my_pkg/msg/Blob"]
    for k in range(3):
        w.write("/blob", 1000 + k, Blob(a=k, b=f"n{k}", c=np.arange(k, dtype=np.float64)))
    w.close()
    con = sqlite3.connect(bag / "custom.db3")
    con.execute("DELETE FROM message_definitions")   # as recorded by rosbag2 before Iron
    con.commit()
    con.close()
    with open_recording(bag) as r:
        (t,) = r.topics()
        assert not t.decodable and "--msg-dir" in t.note
        with pytest.raises(DecodeError, match="--msg-dir"):
            next(iter(r.messages()))
    msgs = tmp_path / "defs" / "my_pkg" / "msg"
    msgs.mkdir(parents=True)
    (msgs / "Blob.msg").write_text("uint32 a\nstring b\nfloat64[] c\n")
    with open_recording(bag, msg_dir=tmp_path / "defs") as r:
        got = [m for _, _, m in r.messages()]
    assert [(m.a, m.b, len(m.c)) for m in got] == [(0, "n0", 0), (1, "n1", 1), (2, "n2", 2)]
    (tmp_path / "empty").mkdir()
    with pytest.raises(RecordingError, match="no .msg files"):
        open_recording(bag, msg_dir=tmp_path / "empty")


def test_placeholder_type_hashes_are_tolerated(tmp_path):
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "hb"
    truth = write_recording(bag, "sqlite3", n_radar=2, camera=False, tf=False)
    meta = (bag / "metadata.yaml").read_text()
    con = sqlite3.connect(bag / "hb.db3")
    for (h,) in con.execute("SELECT type_description_hash FROM topics").fetchall():
        meta = meta.replace(h, "RIHS01_" + "0" * 64)
    con.execute(f"UPDATE topics SET type_description_hash = 'RIHS01_{'0' * 64}'")
    con.execute(f"UPDATE message_definitions SET type_description_hash = 'RIHS01_{'0' * 64}'")
    con.commit()
    con.close()
    (bag / "metadata.yaml").write_text(meta)
    with pytest.raises(Exception, match="hash mismatch"), AnyReader([bag]) as r:
        pass
    with open_recording(bag) as r:
        got = [m for _, _, m in r.messages(["/radar/heatmap"])]
    assert len(got) == 2 == len(truth["radar"])


def test_guess_reader_by_extension_and_content(tmp_path):
    write_recording(tmp_path / "a.bag", "rosbag1", n_radar=1, lidar=False, camera=False, tf=False)
    write_recording(tmp_path / "b", "mcap", n_radar=1, lidar=False, camera=False, tf=False)
    assert guess_reader(tmp_path / "a.bag") == "rosbag1"
    assert guess_reader(tmp_path / "b") == "rosbag2"
    assert guess_reader(tmp_path / "b" / "b.mcap") == "rosbag2"     # storage file inside a bag folder
    assert guess_reader(tmp_path / "b" / "metadata.yaml") == "rosbag2"
    shutil.copy(tmp_path / "a.bag", tmp_path / "noext")
    assert guess_reader(tmp_path / "noext") == "rosbag1"
    shutil.copy(tmp_path / "b" / "b.mcap", tmp_path / "bare.mcap")
    with open_recording(tmp_path / "bare.mcap") as r:
        assert [t.name for t in r.topics()] == ["/radar/heatmap"]


def _heads_vs_full(path):
    with open_recording(path) as r:
        full = [(m.topic, m.log_ns, bytes(m.data)) for m in r.raw_messages()]
        topics = sorted({t for t, _, _ in full})
        heads = topics[::2]
        got = []
        for m in r.raw_heads(topics, heads):
            if m.ref is not None:
                assert m.topic in heads and len(m.data) == 256
                whole = r.full(m)
                assert whole.ref is None and bytes(whole.data[:256]) == bytes(m.data)
                assert r.decode(m) is not None        # decode reads the rest itself
                m = whole
            got.append((m.topic, m.log_ns, bytes(m.data)))
        return full, got, r._message_table() if hasattr(r, "_message_table") else None


def test_raw_heads_reads_the_same_messages_as_rosbags(tmp_path):
    """rosbag2 MCAP with uncompressed chunks: raw_heads seeks to each message through the chunk
    message indexes; same messages, order and bytes as rosbags' reader; header-only messages are
    prefixes that full() / decode() complete."""
    bag = tmp_path / "bag"
    write_recording(bag, "mcap", n_radar=3)
    full, got, table = _heads_vs_full(bag)
    assert table and len(full) > 20 and got == full
    if FIXTURES.exists():
        for p in (FIXTURES / "ros2" / "mcap" / "wbag", FIXTURES / "ros2" / "mcap" / "cdr_test"):
            full, got, _ = _heads_vs_full(p)
            assert got == full


def test_raw_heads_stops_at_a_record_that_is_not_the_indexed_message(tmp_path):
    """A message record whose log time no longer matches its chunk index (damaged bytes): the
    seeking reader yields the messages before it, then marks the recording truncated."""
    bag = tmp_path / "bag"
    write_recording(bag, "mcap", n_radar=3)
    with open_recording(bag) as r:
        table = r._message_table()
        n = len(table.offsets)
        off = int(table.offsets[n // 2])
    mcap = next(bag.glob("*.mcap"))
    b = bytearray(mcap.read_bytes())
    b[off + 1 + 8 + 2 + 4] ^= 0xFF        # first byte of the record's log time
    mcap.write_bytes(bytes(b))
    with open_recording(bag) as r:
        got = list(r.raw_heads(sorted({t.name for t in r.topics()}), []))
        assert len(got) == n // 2 and r.truncated
        assert any("damaged record" in p for p in r.problems)
