"""PointCloud2 decoding: synthetic layouts checked against the arrays they were built from, and the
real Luminar / rosbag2-MCAP fixtures against an independent np.frombuffer decode of their
documented layouts (rosbags / mcap used directly)."""
from __future__ import annotations

import numpy as np
import pytest
from _recordings import FIXTURES, cloud_msg, store_for

from holodata.readers.base import DecodeError
from holodata.readers.pointcloud2 import check_pointcloud2, decode_pointcloud2

T = store_for("mcap").types
STAMP = 1_600_000_000_123_456_789


def _msg(pts, **kw):
    return cloud_msg(T, "mcap", STAMP, "lidar", pts, **kw)


def test_padded_unaligned_fields_and_split_time():
    # x y z at odd offsets (unaligned), padding, split absolute time like Luminar
    dt = np.dtype({"names": ["x", "y", "z", "intensity", "time_sec", "time_nsec"],
                   "formats": ["<f4", "<f4", "<f4", "|u1", "<u4", "<u4"],
                   "offsets": [1, 5, 9, 13, 17, 21], "itemsize": 29})
    rng = np.random.default_rng(0)
    a = np.zeros(50, dt)
    for f in "xyz":
        a[f] = rng.normal(0, 5, 50)
    a["intensity"] = rng.integers(0, 255, 50)
    t_abs = STAMP + rng.integers(-50_000_000, 50_000_000, 50)
    a["time_sec"], a["time_nsec"] = t_abs // 10**9, t_abs % 10**9
    c = decode_pointcloud2(_msg(a), "/l")
    np.testing.assert_array_equal(c.xyz, np.stack([a["x"], a["y"], a["z"]], 1))
    assert c.time_field == "time_sec+time_nsec" and c.time_reference == "stamp"
    np.testing.assert_array_equal(c.time_ns, t_abs - STAMP)
    np.testing.assert_array_equal(c.fields["intensity"], a["intensity"])
    assert c.stamp_ns == STAMP and c.frame_id == "lidar"


def test_row_padding_organised_and_invalid_points_dropped():
    h, w = 3, 5
    dt = np.dtype({"names": ["x", "y", "z", "t"], "formats": ["<f4"] * 3 + ["<u4"], "offsets": [0, 4, 8, 12],
                   "itemsize": 16})
    a = np.zeros((h, w), dt)
    a["x"] = np.arange(15).reshape(h, w) + 1.0
    a["y"], a["z"] = 2.0, 3.0
    a["t"] = np.arange(w) * 1000
    a["x"][0, 1] = np.nan                       # non-finite -> dropped
    a["x"][2, 4] = a["y"][2, 4] = a["z"][2, 4] = 0.0   # Ouster "no return" -> dropped
    pad = 7
    rows = [a[i].tobytes() + b"\xee" * pad for i in range(h)]
    data = b"".join(rows)[:-pad]                 # last row without its padding is still complete
    c = decode_pointcloud2(_msg(a, row_step=w * 16 + pad, data=data), "/l")
    assert c.shape == (h, w) and c.organised and c.n_raw == 15
    keep = np.ones(15, bool)
    keep[[1, 14]] = False
    np.testing.assert_array_equal(c.index, np.flatnonzero(keep))
    np.testing.assert_array_equal(c.xyz[:, 0], a["x"].ravel()[keep])
    assert c.time_reference == "scan" and c.time_field == "t"
    np.testing.assert_array_equal(c.time_ns, np.tile(np.arange(w) * 1000, h)[keep])
    grid = c.grid(c.xyz[:, 0])
    assert np.isnan(grid[0, 1]) and grid[1, 2] == a["x"][1, 2]
    assert decode_pointcloud2(_msg(a, row_step=w * 16 + pad, data=data), keep_invalid=True).xyz.shape == (15, 3)


def test_big_endian_and_float_time_fields():
    dt = np.dtype({"names": ["x", "y", "z", "time"], "formats": [">f4"] * 4, "offsets": [0, 4, 8, 12], "itemsize": 16})
    a = np.zeros(4, dt)
    a["x"] = [1, 2, 3, 4]
    a["y"], a["z"] = -1.5, 0.25
    a["time"] = [-0.05, 0.0, 0.01, 0.099]       # Velodyne: relative seconds
    c = decode_pointcloud2(_msg(a, bigendian=True))
    np.testing.assert_array_equal(c.xyz[:, 0], [1, 2, 3, 4])
    assert c.xyz.dtype == np.float32 and c.time_reference == "scan"
    np.testing.assert_array_equal(c.time_ns, np.rint(a["time"].astype(np.float64) * 1e9).astype(np.int64))
    # absolute float64 seconds (Hesai)
    dt2 = np.dtype({"names": ["x", "y", "z", "timestamp"], "formats": ["<f4"] * 3 + ["<f8"], "offsets": [0, 4, 8, 16],
                    "itemsize": 24})
    b = np.zeros(3, dt2)
    b["x"] = 1
    b["timestamp"] = STAMP / 1e9 + np.array([0.0, 0.01, 0.02])
    c2 = decode_pointcloud2(_msg(b))
    assert c2.time_reference == "stamp"
    assert np.abs(c2.time_ns - np.array([0, 10_000_000, 20_000_000]) - (int(round(STAMP / 1e9 * 1e9)) - STAMP)).max() < 1000


def test_errors_name_the_topic():
    dt = np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3, "offsets": [0, 4, 8], "itemsize": 12})
    a = np.ones(10, dt)
    with pytest.raises(DecodeError, match="topic /c: .*truncated"):
        decode_pointcloud2(_msg(a, data=a.tobytes()[:-5]), "/c")
    with pytest.raises(DecodeError, match="topic /c: .*truncated"):
        check_pointcloud2(_msg(a, data=a.tobytes()[:-5]), "/c")
    nz = np.zeros(3, np.dtype({"names": ["x", "y", "i"], "formats": ["<f4"] * 3, "offsets": [0, 4, 8], "itemsize": 12}))
    with pytest.raises(DecodeError, match="no z field"):
        decode_pointcloud2(_msg(nz), "/c")
    assert decode_pointcloud2(_msg(np.zeros(0, dt))).xyz.shape == (0, 3)


@pytest.fixture(scope="module")
def luminar():
    path = FIXTURES / "ros1" / "luminar-test.bag"
    if not path.exists():
        pytest.skip(f"fixture folder {FIXTURES} is absent")
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        conns = [c for c in r.connections if c.topic == "/luminar_pointcloud"]
        return [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(conns)]


def test_luminar_fixture_against_documented_layout(luminar):
    assert len(luminar) == 5
    for m in luminar:
        # documented layout: point_step 32, x y z intensity f4 @0 4 8 16, time_sec/time_nsec u4 @20/24
        raw = np.frombuffer(m.data, np.uint8).reshape(-1, 32)
        xyz = raw[:, :12].copy().view("<f4")
        t = raw[:, 20:24].copy().view("<u4")[:, 0].astype(np.int64) * 10**9 + raw[:, 24:28].copy().view("<u4")[:, 0]
        c = decode_pointcloud2(m, "/luminar_pointcloud")
        assert len(c.xyz) == m.width == len(raw)      # is_dense: every point kept
        np.testing.assert_array_equal(c.xyz, xyz)
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        np.testing.assert_array_equal(c.time_ns, t - stamp)
        np.testing.assert_array_equal(c.fields["intensity"], raw[:, 16:20].copy().view("<f4")[:, 0])
        assert c.frame_id == "luminar_lidar"
    assert len(decode_pointcloud2(luminar[0]).xyz) == 35707


def test_rosbag2_mcap_fixture_via_mcap_library():
    path = FIXTURES / "mcap" / "rosbag2_2025_09_10-13_03_56_0.mcap"
    if not path.exists():
        pytest.skip(f"fixture folder {FIXTURES} is absent")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        msgs = [m for _, _, _, m in make_reader(f, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=["/point_cloud2"])]
    assert len(msgs) == 1
    m = msgs[0]
    raw = np.frombuffer(bytes(m.data), np.uint8).reshape(-1, 16).copy().view("<f4")
    c = decode_pointcloud2(m, "/point_cloud2")
    assert len(c.xyz) == 200
    np.testing.assert_array_equal(c.xyz, raw[:, :3])
    inten = c.fields["intensity"]
    assert inten.min() >= 100 and inten.max() <= 200
