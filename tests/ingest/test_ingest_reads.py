"""What ingest's passes read: a ROS 1 bag with uncompressed chunks is read through its index
(:class:`holodata.readers.rosbag.Ros1MessageTable`: header prefixes of the messages a pass will not
decode, whole payloads of the rest) and yields exactly what rosbags' own reader yields, in its order;
a damaged message record stops the read there (the recording is marked truncated and the readable
part ingests into a valid dataset); a bag with compressed chunks is read through rosbags."""
from __future__ import annotations

import struct

import numpy as np
import pytest
from _recordings import Writer, cloud_msg, lidar_scan, write_recording

from holodata.dataset import open_dataset, validate_dataset
from holodata.ingest import ingest
from holodata.readers import open_recording
from holodata.readers.rosbag import Ros1MessageTable

HEADS = {"/radar/heatmap", "/os/points", "/cam/depth/image_raw"}


def _same_as_rosbags(rec, heads) -> int:
    """Assert raw_heads(heads) == raw_messages message by message; returns (how many came header-only,
    how many of ``heads`` are longer than the prefix)."""
    topics = [t.name for t in rec.topics()]
    ref = list(rec.raw_messages(topics))
    got = list(rec.raw_heads(topics, heads))
    assert [(m.topic, m.msgtype, m.log_ns, m.encoding) for m in got] == \
        [(m.topic, m.msgtype, m.log_ns, m.encoding) for m in ref]
    n_head = 0
    for a, b in zip(ref, got):
        if b.ref is not None:
            n_head += 1
            assert b.topic in heads and len(b.data) == Ros1MessageTable.HEAD
            assert bytes(b.data) == bytes(a.data)[:len(b.data)]
            assert rec.stamp_ns(b) == rec.stamp_ns(a)          # the header prefix gives the stamp
        assert bytes(rec.full(b).data) == bytes(a.data)
    return n_head, sum(m.topic in heads and len(m.data) > Ros1MessageTable.HEAD for m in ref)


def test_ros1_index_reads_what_rosbags_reads(tmp_path):
    bag = tmp_path / "r.bag"
    write_recording(bag, "rosbag1", n_radar=4, radar_shape=(16, 8, 32))   # heatmaps 8 KB: > the header prefix
    with open_recording(bag) as rec:
        assert isinstance(rec._message_table(), Ros1MessageTable)
        n_head, n_long = _same_as_rosbags(rec, HEADS)
        assert n_head == n_long > 4          # heatmaps and LiDAR scans: longer than the prefix
        assert _same_as_rosbags(rec, set())[0] == 0


def test_compressed_ros1_chunks_are_read_through_rosbags(tmp_path):
    from rosbags.rosbag1 import Writer

    from holodata.messages import typestore_for

    store = typestore_for(1)
    bag = tmp_path / "lz4.bag"
    w = Writer(bag)
    w.set_compression(Writer.CompressionFormat.LZ4)
    w.open()
    c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
    for k in range(5):
        w.write(c, 10**9 + k, store.serialize_ros1(store.types["std_msgs/msg/String"](data="x" * 400 * k),
                                                   "std_msgs/msg/String"))
    w.close()
    with open_recording(bag) as rec:
        assert rec._message_table() is False
        n_head, n_long = _same_as_rosbags(rec, {"/chatter"})
        assert n_head == 0 and n_long > 0    # read whole through rosbags


@pytest.mark.parametrize("damage", ["zeroed header", "length past the chunk"])
def test_a_damaged_ros1_record_truncates_the_recording(tmp_path, damage):
    bag = tmp_path / "r.bag"
    truth = write_recording(bag, "rosbag1", n_radar=6, radar_shape=(16, 8, 32))
    with open_recording(bag) as rec:
        t = rec._message_table()
        radar = next(c.id for c in rec.reader.connections if c.topic == "/radar/heatmap")
        pos = int(t.pos[t.conn == radar][3])       # the 4th heatmap's message data record
    data = bytearray(bag.read_bytes())
    if damage == "zeroed header":
        data[pos:pos + 16] = bytes(16)
    else:
        (hlen,) = struct.unpack_from("<I", data, pos)
        struct.pack_into("<I", data, pos + 4 + hlen, 0x7FFFFFFF)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(data))
    with open_recording(bad) as rec:
        got = [m for m in rec.raw_heads([t.name for t in rec.topics()], HEADS) if m.topic == "/radar/heatmap"]
        assert len(got) == 3 and rec.truncated
        assert len(rec.problems) == 1 and str(bad) in rec.problems[0] and "damaged record" in rec.problems[0]
    s = ingest([bad], tmp_path / "ds.zarr")
    sc = open_dataset(tmp_path / "ds.zarr").scene(s["scenes"][0]["scene"])
    assert sc.attrs["source"]["truncated"] is True and sc.n_frames == 3
    np.testing.assert_array_equal(sc["radar/heatmap"][...], np.stack(truth["heatmaps"][:3]))
    assert validate_dataset(tmp_path / "ds.zarr")["ok"]


def test_each_heatmap_is_value_checked_once(tmp_path, monkeypatch):
    """The index pass checks every radar heatmap against the value rules (a frame exists only for a
    message that passes); the write pass keeps that verdict instead of checking the same bytes again."""
    import holodata.ingest.radar_streams as streams

    calls = []
    real = streams.frames_not_finite_nonneg

    def counting(a):
        calls.append(a.shape)
        return real(a)

    monkeypatch.setattr(streams, "frames_not_finite_nonneg", counting)
    rec = tmp_path / "rec"
    truth = write_recording(rec, "mcap", n_radar=5, radar_shape=(16, 8, 32))
    ingest([rec], tmp_path / "ds.zarr")
    assert len(calls) == len(truth["radar"]) == 5
    sc = open_dataset(tmp_path / "ds.zarr").scene("rec")
    np.testing.assert_array_equal(sc["radar/heatmap"][...], np.stack(truth["heatmaps"]))


def test_source_digests_are_the_files_blake3_and_sha256(tmp_path):
    """The source digests ingest records (read in 4 MB blocks into one reused buffer) are the BLAKE3 /
    sha256 of the whole file, across block boundaries and for an empty file."""
    import hashlib

    import blake3

    from holodata.ingest.plan import file_digests

    rng = np.random.default_rng(3)
    files = [tmp_path / "a.bin", tmp_path / "b.bin", tmp_path / "empty.bin"]
    files[0].write_bytes(rng.bytes((9 << 20) + 123))
    files[1].write_bytes(rng.bytes(4 << 20))
    files[2].write_bytes(b"")
    assert file_digests(files) == [blake3.blake3(f.read_bytes()).hexdigest() for f in files]
    assert file_digests(files, "sha256") == [hashlib.sha256(f.read_bytes()).hexdigest() for f in files]
    rec = tmp_path / "r.bag"
    write_recording(rec, "rosbag1", n_radar=3)
    ingest([rec], tmp_path / "ds.zarr")
    src = open_dataset(tmp_path / "ds.zarr").scene("r").attrs["source"]
    assert src["blake3"] == [blake3.blake3(rec.read_bytes()).hexdigest()]


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1"])
def test_decoded_arrays_are_views_of_the_payload(tmp_path, fmt):
    """Decoding a message does not copy its payload: a heatmap's bytes are a view of the bytes read
    (rosbags slices the CDR encapsulation header off its input, which copied a ``bytes`` payload)."""
    rec = tmp_path / ("r.bag" if fmt == "rosbag1" else "r")
    truth = write_recording(rec, fmt, n_radar=2, radar_shape=(16, 8, 32))
    with open_recording(rec) as r:
        raw = r.full(next(r.raw_heads(["/radar/heatmap"], {"/radar/heatmap"})))
        msg = r.decode(raw)
        assert np.shares_memory(np.asarray(msg.data), np.frombuffer(raw.data, np.uint8))
        np.testing.assert_array_equal(np.asarray(msg.data).view("<f2").reshape(16, 8, 32), truth["heatmaps"][0])


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1"])
def test_topic_frame_ids_from_header_prefixes(tmp_path, fmt):
    """``topics(frame_ids=True)`` reads header prefixes where the reader can seek: the frame ids are
    those of the whole messages, also one longer than the prefix (read whole then)."""
    rec = tmp_path / ("r.bag" if fmt == "rosbag1" else "r")
    long_id = "sensor_" + "x" * 300
    w = Writer(rec, fmt)
    w.add("/a/points", "sensor_msgs/msg/PointCloud2")
    w.add("/b/points", "sensor_msgs/msg/PointCloud2")
    for k in range(3):
        w.write("/a/points", 10**9 + k, cloud_msg(w.T, fmt, 10**9 + k, "os_sensor", lidar_scan(k)))
        w.write("/b/points", 10**9 + k, cloud_msg(w.T, fmt, 10**9 + k, long_id, lidar_scan(k)))
    w.close()
    with open_recording(rec) as r:
        assert r._message_table()            # read through the index: header prefixes
        ids = {t.name: t.frame_id for t in r.topics(frame_ids=True)}
        whole = {m.topic: str(r.decode(m).header.frame_id) for m in r.raw_messages(["/a/points", "/b/points"])}
    assert ids == whole == {"/a/points": "os_sensor", "/b/points": long_id}


def test_mcap_topic_times_from_the_message_table(tmp_path):
    """A single-file rosbag2 MCAP bag's first/last log times (and so its rates) come from the message
    table ingest reads anyway; they are those of the chunk message indexes read record by record."""
    from holodata.readers.mcap_file import McapMessageTable, topic_times_mcap

    rec = tmp_path / "r"
    write_recording(rec, "mcap", n_radar=3)
    with open_recording(rec) as r:
        assert isinstance(r._message_table(), McapMessageTable)
        got = {t.name: (t.first_ns, t.last_ns) for t in r.topics(frame_ids=False) if t.count}
        assert got == topic_times_mcap(r.files[0]) and len(got) >= 5


def test_lidar_range_norms_are_numpys_bits():
    """lidar/range of organised clouds: the per-point norm ingest computes is, bit for bit,
    ``np.linalg.norm(xyz, axis=1)`` in float32 (NaN and inf included)."""
    from holodata.ingest.streams import _norm3

    rng = np.random.default_rng(7)
    xyz = (rng.normal(size=(5000, 3)) * rng.uniform(0.01, 300, (5000, 1))).astype(np.float32)
    xyz[::11] = np.nan
    xyz[5::13, 1] = np.inf
    got = _norm3(xyz)
    assert got.dtype == np.float32
    assert np.array_equal(got.view(np.uint32), np.linalg.norm(xyz, axis=1).astype(np.float32).view(np.uint32))
