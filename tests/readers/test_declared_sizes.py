"""Sizes a file declares are checked against what the file holds before anything is allocated
(holodata.readers.sizes): tiny crafted files that declare gigabytes — an HDF5 dataset of 1e10 rows,
a ROS 1 chunk or an MCAP chunk whose header declares a huge uncompressed size, chunks that
decompress to far more than they declare, a .npy header, a .npz member, a pcap record, an MCAP
message record — give one line naming the file (or a recording marked truncated), fast, with the
address space capped and tracemalloc's peak small."""
from __future__ import annotations

import bz2
import contextlib
import io
import resource
import struct
import time
import tracemalloc
import zipfile

import numpy as np
import pytest

from holodata.errors import InputError, RecordingError
from holodata.readers import open_recording

h5py = pytest.importorskip("h5py")
lz4_frame = pytest.importorskip("lz4.frame")
zstandard = pytest.importorskip("zstandard")
pytest.importorskip("rosbags")
pytest.importorskip("mcap")

MIB = 2 ** 20
PEAK = 64 * MIB          # what a reader may allocate for any of these files
CAP = 768 * MIB          # address space above what the process has when a test starts
BOMB = bz2.compress(bytes(16 * MIB)) * 32     # 32 concatenated bz2 streams: ~1.4 KB -> 512 MiB of zeros


@contextlib.contextmanager
def small_memory():
    """The address space capped at its current size + CAP (an allocation of what a file declares
    fails instead of taking the machine), tracemalloc running; yields a dict whose "peak" (bytes) and
    "seconds" are set on exit."""
    import holodata.readers.hdf5  # noqa: F401 - libraries mapped before the cap
    import holodata.readers.mcap_file  # noqa: F401
    import holodata.readers.rosbag  # noqa: F401

    with open("/proc/self/status") as f:
        vm = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = vm + CAP if hard == resource.RLIM_INFINITY else min(vm + CAP, hard)
    out: dict = {}
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        yield out
    finally:
        out["seconds"] = time.perf_counter() - t0
        out["peak"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def assert_one_line_error(fn, path, words: str):
    with small_memory() as mem, pytest.raises((InputError, RecordingError)) as e:
        fn()
    msg = str(e.value)
    assert str(path) in msg and "\n" not in msg and words in msg, msg
    assert "allocate" not in msg and not isinstance(e.value.__cause__, MemoryError), msg
    assert mem["peak"] < PEAK and mem["seconds"] < 10, mem
    return msg


def read_all(path, reader=None):
    """(messages, truncated, problems) of the recording at ``path``, every message's payload read."""
    with open_recording(path, reader=reader) as r:
        n = sum(1 for raw in r.raw_messages() if r.full(raw) is not None)
        return n, r.truncated, list(r.problems)


# --------------------------------------------------------------------------------------------------
# HDF5

def _h5(path, **datasets):
    with h5py.File(path, "w") as f:
        for name, spec in datasets.items():
            if isinstance(spec, np.ndarray):
                f[name] = spec
            else:           # (shape, dtype, create_dataset options): declared, never written
                shape, dtype, kw = spec
                f.create_dataset(name, shape=shape, dtype=dtype, **kw)
    return path


@pytest.mark.parametrize("case, words", [
    ("timestamps", "radar/timestamp_ns (10000000000,) int64 declares 80000000000 bytes (74.5 GiB)"),
    ("heatmap", "radar/heatmap (1000000, 64, 64, 64) float32 declares"),
    ("points", "lidar/points (10000000000, 3) float32 declares"),
])
def test_hdf5_dataset_declaring_more_than_the_file_stores(tmp_path, case, words):
    p = tmp_path / f"{case}.h5"
    hm = np.zeros((1, 2, 2, 2), np.float32)
    if case == "timestamps":     # the file: 5 KB, 'Unable to allocate 74.5 GiB'
        _h5(p, **{"radar/heatmap": hm, "radar/timestamp_ns": ((10 ** 10,), "i8", {})})
    elif case == "heatmap":      # 1e6 gzip-chunked frames of 1 MiB, none written
        _h5(p, **{"radar/heatmap": ((10 ** 6, 64, 64, 64), "f4", {"chunks": (1, 64, 64, 64), "compression": "gzip"}),
                  "radar/timestamp_ns": np.arange(10 ** 6, dtype=np.int64)})
    else:
        _h5(p, **{"lidar/points": ((10 ** 10, 3), "f4", {}), "lidar/offsets": np.array([0, 10 ** 10]),
                  "lidar/timestamp_ns": np.array([5])})
    assert p.stat().st_size < 64 * 1024 if case != "heatmap" else p.stat().st_size < 9 * MIB
    assert_one_line_error(lambda: open_recording(p), p, words)


def test_hdf5_declared_size_is_one_line_through_the_cli(tmp_path):
    from click.testing import CliRunner

    from holodata.cli.main import cli

    p = _h5(tmp_path / "rec.h5", **{"radar/heatmap": np.zeros((1, 2, 2, 2), np.float32),
                                    "radar/timestamp_ns": ((10 ** 10,), "i8", {})})
    with small_memory():
        r = CliRunner().invoke(cli, ["ingest", str(p), "--out", str(tmp_path / "ds.zarr"), "--quiet"])
    assert r.exit_code == 1 and str(p) in r.output and "declares" in r.output, r.output
    assert "Traceback" not in r.output and "allocate" not in r.output and len(r.output.strip().splitlines()) == 1


# --------------------------------------------------------------------------------------------------
# ROS 1

def _fields(**kv) -> bytes:
    return b"".join(struct.pack("<I", len(k) + 1 + len(v)) + k.encode() + b"=" + v for k, v in kv.items())


def _record(data: bytes = b"", **kv) -> bytes:
    h = _fields(**kv)
    return struct.pack("<I", len(h)) + h + struct.pack("<I", len(data)) + data


def _ros1_bag(path, chunks, indexed=True):
    """A ROS 1 bag of ``chunks``: each a dict with ``compression`` ('none', 'bz2', 'lz4'), optional
    ``size`` (the uncompressed size its header declares; default the true one) and ``extra`` (bytes
    appended to its compressed data). Every chunk holds the /chatter connection and 2 std_msgs/String
    messages; ``indexed``: index data records and the index section as rosbag writes them."""
    u32, u64 = (lambda v: struct.pack("<I", v)), (lambda v: struct.pack("<Q", v))
    conn = _record(_fields(topic=b"/chatter", type=b"std_msgs/String", md5sum=b"992ce8a1687cec8c8bd883ec73ca41d1",
                           message_definition=b"string data\n"), op=b"\x07", conn=u32(0), topic=b"/chatter")
    body, infos, t = b"", [], 1
    head_len = 13 + len(_record(op=b"\x03", index_pos=u64(0), conn_count=u32(0), chunk_count=u32(0)))
    for c in chunks:
        inner, index = conn, b""
        for _ in range(2):
            index += struct.pack("<III", t, 0, len(inner))
            inner += _record(struct.pack("<I", 5) + b"hello", op=b"\x02", conn=u32(0), time=struct.pack("<II", t, 0))
            t += 1
        comp = c["compression"]
        data = {"none": lambda b: b, "bz2": bz2.compress, "lz4": lz4_frame.compress}[comp](inner)
        pos = head_len + len(body)
        body += _record(data + c.get("extra", b""), op=b"\x05", compression=comp.encode(),
                        size=u32(c.get("size", len(inner))))
        if indexed:
            body += _record(index, op=b"\x04", ver=u32(1), conn=u32(0), count=u32(2))
        infos.append(_record(u32(0) + u32(2), op=b"\x06", ver=u32(1), chunk_pos=u64(pos),
                             start_time=struct.pack("<II", t - 2, 0), end_time=struct.pack("<II", t - 1, 0),
                             count=u32(1)))
    index_pos = head_len + len(body) if indexed else 0
    head = _record(op=b"\x03", index_pos=u64(index_pos), conn_count=u32(1 if indexed else 0),
                   chunk_count=u32(len(chunks) if indexed else 0))
    tail = conn + b"".join(infos) if indexed else b""
    path.write_bytes(b"#ROSBAG V2.0\n" + head + body + tail)
    return path


@pytest.mark.parametrize("indexed", [True, False])
def test_ros1_bags_of_real_chunks_still_read(tmp_path, indexed):
    """The crafted bags are bags: rosbags (indexed) and the linear scan (not) read all 6 messages."""
    p = _ros1_bag(tmp_path / "ok.bag", [{"compression": "bz2"}, {"compression": "lz4"}, {"compression": "none"}],
                  indexed)
    n, truncated, _ = read_all(p)
    assert n == 6 and not truncated


@pytest.mark.parametrize("indexed", [True, False])
def test_ros1_chunk_declaring_a_huge_uncompressed_size(tmp_path, indexed):
    """A chunk header declaring 4 GiB for ~1.4 KB of bz2 data (which is a bomb: 512 MiB of zeros):
    refused before it is decompressed, by rosbags (indexed) or by the linear scan."""
    p = _ros1_bag(tmp_path / "huge.bag", [{"compression": "bz2"},
                                          {"compression": "bz2", "size": 2 ** 32 - 1, "extra": BOMB}], indexed)
    assert p.stat().st_size < 5000
    assert_one_line_error(lambda: read_all(p), p, "declares 4294967295 bytes (4.0 GiB)")


@pytest.mark.parametrize("indexed", [True, False])
def test_ros1_chunk_decompressing_to_more_than_it_declares(tmp_path, indexed):
    """A chunk whose header declares its true size but whose data goes on (512 MiB of bz2 zeros):
    decompression stops there; the chunk is damaged, the bag marked truncated."""
    p = _ros1_bag(tmp_path / "bomb.bag", [{"compression": "bz2"}, {"compression": "bz2", "extra": BOMB}], indexed)
    with small_memory() as mem:
        n, truncated, problems = read_all(p)
    assert truncated and n == 2, (n, problems)
    assert any(str(p) in x and "decompresses to more than" in x for x in problems), problems
    assert mem["peak"] < PEAK and mem["seconds"] < 10, mem


# --------------------------------------------------------------------------------------------------
# MCAP

def _mcap_written(path, ros2: bool, compression: str = "zstd", crcs: bool = True):
    """An MCAP file by the mcap library's writer: 3 messages in one chunk, with summary."""
    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as f:
        w = Writer(f, compression=getattr(CompressionType, compression.upper()), enable_crcs=crcs)
        w.start(profile="ros2" if ros2 else "", library="test")
        if ros2:
            from rosbags.typesys import Stores, get_typestore

            ts = get_typestore(Stores.ROS2_HUMBLE)
            ty = "geometry_msgs/msg/PointStamped"
            P, H, T, Pt = (ts.types[k] for k in (ty, "std_msgs/msg/Header", "builtin_interfaces/msg/Time",
                                                 "geometry_msgs/msg/Point"))
            sid = w.register_schema(ty, "ros2msg", b"std_msgs/Header header\ngeometry_msgs/Point point\n")
            cid = w.register_channel("/p", "cdr", sid)
            msgs = [bytes(ts.serialize_cdr(P(H(T(i, 0), "map" * 100), Pt(1.0, 2.0, 3.0)), ty)) for i in range(3)]
        else:
            sid = w.register_schema("Ex", "jsonschema", b"{}")
            cid = w.register_channel("/ex", "json", sid)
            msgs = [b'{"a": %d}' % i for i in range(3)]
        for i, m in enumerate(msgs):
            w.add_message(cid, (i + 1) * 10 ** 9, m, (i + 1) * 10 ** 9)
        w.finish()
    return path


def _summary_chunk_index_ends(data: bytes) -> list[int]:
    """End offsets of the summary's ChunkIndex records (their last field: uncompressed_size)."""
    (start,) = struct.unpack_from("<Q", data, len(data) - 37 + 9)
    out, pos = [], start
    while pos < len(data) - 37:
        op, n = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x08:
            out.append(pos + 9 + n)
        pos += 9 + n
    return out


@pytest.mark.parametrize("ros2, reader", [(False, None), (True, None), (True, "rosbag2")])
def test_mcap_chunk_declaring_a_huge_uncompressed_size(tmp_path, ros2, reader):
    """A zstd chunk (and its summary index) declaring 1 TiB: refused when the file is opened, by the
    mcap-library reader and before rosbags (a rosbag2 storage file) reads it."""
    from mcap.reader import SeekingReader

    p = _mcap_written(tmp_path / "huge.mcap", ros2)
    with open(p, "rb") as f:
        ci = SeekingReader(f).get_summary().chunk_indexes[0]
    d = bytearray(p.read_bytes())
    d[ci.chunk_start_offset + 9 + 16:ci.chunk_start_offset + 9 + 24] = struct.pack("<Q", 2 ** 40)
    for end in _summary_chunk_index_ends(bytes(d)):
        d[end - 8:end] = struct.pack("<Q", 2 ** 40)
    p.write_bytes(bytes(d))
    assert_one_line_error(lambda: read_all(p, reader), p, "declares 1099511627776 bytes (1.0 TiB)")


def _mcap_linear(path, chunk: bytes, compression: str, usize: int):
    """A summary-less MCAP file: header, one channel (schemaless, 'json'), one chunk record of the
    given compressed ``chunk`` bytes declaring ``usize``, data end, footer."""
    def rec(op, body):
        return bytes([op]) + struct.pack("<Q", len(body)) + body

    def s(x: bytes):
        return struct.pack("<I", len(x)) + x

    out = b"\x89MCAP0\r\n" + rec(0x01, s(b"") + s(b"test"))
    out += rec(0x04, struct.pack("<HH", 1, 0) + s(b"/ex") + s(b"json") + struct.pack("<I", 0))
    out += rec(0x06, struct.pack("<QQQI", 10 ** 9, 3 * 10 ** 9, usize, 0) + s(compression.encode())
               + struct.pack("<Q", len(chunk)) + chunk)
    out += rec(0x0F, struct.pack("<I", 0)) + rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n"
    path.write_bytes(out)
    return path


def _mcap_messages(n=3) -> bytes:
    return b"".join(bytes([0x05]) + struct.pack("<Q", 22 + 8) + struct.pack("<HIQQ", 1, i, (i + 1) * 10 ** 9,
                                                                              (i + 1) * 10 ** 9) + b'{"a": 1}'
                    for i in range(n))


def test_mcap_linear_chunk_declaring_a_huge_uncompressed_size(tmp_path):
    """No summary: the linear walk finds the chunk; its zstd frame states no content size, so the
    mcap library would reserve the declared 1 TiB."""
    recs = _mcap_messages()
    z = zstandard.ZstdCompressor(write_content_size=False).compress(recs)
    p = _mcap_linear(tmp_path / "lin.mcap", z, "zstd", 2 ** 40)
    ok = _mcap_linear(tmp_path / "ok.mcap", z, "zstd", len(recs))
    assert read_all(ok)[:2] == (3, False)
    assert_one_line_error(lambda: read_all(p), p, "declares 1099511627776 bytes (1.0 TiB)")


def test_mcap_chunk_whose_zstd_frame_declares_a_huge_content_size(tmp_path):
    """The chunk declares its true size, its zstd frame 16 GiB (zstandard.decompress reserves what the
    frame declares): decompressed in bounded steps, the chunk is damaged, the file truncated."""
    recs = _mcap_messages()
    nc = zstandard.ZstdCompressor(write_content_size=False, write_checksum=False).compress(recs)
    fhd = nc[4]
    assert not fhd & 0x20           # not single-segment: a window descriptor byte follows
    frame = nc[:4] + bytes([0xC0 | (fhd & 0x3F)]) + nc[5:6] + struct.pack("<Q", 16 * 2 ** 30) + nc[6:]
    assert zstandard.get_frame_parameters(frame).content_size == 16 * 2 ** 30
    p = _mcap_linear(tmp_path / "frame.mcap", frame, "zstd", len(recs))
    with small_memory() as mem:
        n, truncated, problems = read_all(p)
    assert truncated and n == 0 and any(str(p) in x and "does not decompress" in x for x in problems), problems
    assert not any("Memory" in x or "allocate" in x for x in problems), problems
    assert mem["peak"] < PEAK and mem["seconds"] < 10, mem


def test_mcap_message_record_declaring_a_huge_length(tmp_path):
    """A message record in an uncompressed chunk of a rosbag2 MCAP storage file declaring 1 TiB: the
    header-only pass (frame ids, :class:`McapMessageTable`) refuses to read it (the recording is
    marked truncated) instead of reserving it."""
    from holodata.readers.mcap_file import McapMessageTable

    p = _mcap_written(tmp_path / "msg.mcap", ros2=True, compression="none", crcs=False)
    off = int(McapMessageTable.build(p).offsets[0])
    d = bytearray(p.read_bytes())
    d[off + 1:off + 9] = struct.pack("<Q", 2 ** 40 + 22)
    p.write_bytes(bytes(d))
    with small_memory() as mem, open_recording(p, reader="rosbag2") as r:
        assert r.kind == "rosbag2-mcap"
        r.topics()
        truncated, problems = r.truncated, list(r.problems)
    assert truncated and any(str(p) in x and "declares 1099511627776 bytes" in x for x in problems), problems
    assert mem["peak"] < PEAK, mem


# --------------------------------------------------------------------------------------------------
# .npy / .npz, pcap

def _npy_header(shape, descr="<f4") -> bytes:
    b = io.BytesIO()
    np.lib.format.write_array_header_1_0(b, {"descr": descr, "fortran_order": False, "shape": shape})
    return b.getvalue()


def test_npy_folder_file_declaring_a_huge_array(tmp_path):
    tr = tmp_path / "traj"
    (tr / "rf_npy").mkdir(parents=True)
    f = tr / "rf_npy" / "00000.npy"
    f.write_bytes(_npy_header((10 ** 6, 64, 512)) + bytes(64))
    with open_recording(tr) as r:
        raw = next(r.raw_messages())
        msg = assert_one_line_error(lambda: r.decode(raw), f, "declares 131072000000 bytes")
    assert "truncated?" in msg


def test_panoradar_raw_npz_member_declaring_a_huge_array(tmp_path):
    tr = tmp_path / "static_01"
    tr.mkdir()
    np.save(tr / "radar_data.npy", np.zeros((8, 2, 16), np.complex64))
    np.savetxt(tr / "radar_ts.txt", np.arange(8) * 0.01)
    with zipfile.ZipFile(tr / "data_params.npz", "w") as z:
        z.writestr("radar_sep.npy", _npy_header((10 ** 10,), "<i8") + bytes(16))
    assert_one_line_error(lambda: open_recording(tr), tr / "data_params.npz",
                          "member radar_sep.npy: array (10000000000,) int64 declares 80000000000 bytes")


def test_pcap_record_declaring_a_huge_length(tmp_path):
    """The pcap summary behind Ouster's zero-scan message reads a record's declared length only as
    far as the file goes."""
    from holodata.readers.ouster import pcap_udp_summary

    p = tmp_path / "x.pcap"
    p.write_bytes(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
                  + struct.pack("<IIII", 0, 0, 0xFFFFFFF0, 0xFFFFFFF0) + bytes(100))
    with small_memory() as mem:
        udp, n = pcap_udp_summary(p)
    assert (dict(udp), n) == ({}, 0) and mem["peak"] < PEAK, mem
