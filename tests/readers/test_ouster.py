"""Ouster adapter: both fixture pcaps and the ROS 1 packet bag decode to one destaggered frame that
matches an independent decode of the UDP payloads (np.frombuffer with the packet layouts of the
legacy and RNG15_RFL8_NIR8 profiles, rolled by the json's pixel_shift_by_row); a pcap paired with
the wrong metadata fails loudly."""
from __future__ import annotations

import json
import shutil
import struct

import numpy as np
import pytest

pytest.importorskip("ouster.sdk", reason="ouster-sdk is not installed")

from _recordings import FIXTURES  # noqa: E402

from holodata.errors import RecordingError  # noqa: E402
from holodata.readers import open_recording  # noqa: E402
from holodata.readers.ouster import PacketAssembler, sdk_version  # noqa: E402

OUSTER = FIXTURES / "ouster"
pytestmark = pytest.mark.skipif(not OUSTER.exists(), reason=f"fixture folder {FIXTURES} is absent")


def udp_payloads(path, port=7502):
    b = path.read_bytes()
    o, out = 24, []
    while o + 16 <= len(b):
        (incl,) = struct.unpack_from("<I", b, o + 8)
        pkt = b[o + 16:o + 16 + incl]
        o += 16 + incl
        u = 14 + (pkt[14] & 15) * 4
        if struct.unpack(">H", pkt[u + 2:u + 4])[0] == port:
            out.append(pkt[u + 8:])
    return out


def staggered_legacy(payloads, H, W):
    img = np.zeros((H, W), np.int64)
    for p in payloads:   # 16 columns: 16 B header (ts, measurement id, frame id, encoder), H x 12 B, 4 B status
        a = np.frombuffer(p, np.uint8).reshape(16, 16 + 12 * H + 4)
        mid = a[:, 8:10].copy().view("<u2").ravel()
        rng = a[:, 16:16 + 12 * H].reshape(16, H, 12)[:, :, :4].copy().view("<u4")[..., 0] & 0xFFFFF
        img[:, mid] = rng.T
    return img


def staggered_rng15(payloads, H, W):
    img = np.zeros((H, W), np.int64)
    for p in payloads:   # 32 B packet header; 16 columns of 12 B header + H x 4 B (range u16 15 bits x 8 mm)
        a = np.frombuffer(p[32:32 + 16 * (12 + 4 * H)], np.uint8).reshape(16, 12 + 4 * H)
        mid = a[:, 8:10].copy().view("<u2").ravel()
        rng = (a[:, 12:].reshape(16, H, 4)[:, :, :2].copy().view("<u2")[..., 0] & 0x7FFF).astype(np.int64) * 8
        img[:, mid] = rng.T
    return img


def destagger(img, shifts):
    return np.stack([np.roll(img[i], s) for i, s in enumerate(shifts)])


def _mm(range_m):
    return np.nan_to_num(range_m * 1000.0, nan=0.0).round().astype(np.int64)


@pytest.mark.parametrize("stem, H, decode", [("OS-1-32-G_v2.1.1_1024x10", 32, staggered_legacy),
                                             ("OS-0-128-U1_v2.3.0_1024x10", 128, staggered_rng15)])
def test_pcap_scan_matches_independent_packet_decode(stem, H, decode):
    assert sdk_version() is not None
    pcap = OUSTER / f"{stem}.pcap"
    meta = json.loads((OUSTER / f"{stem}.json").read_text())
    with open_recording(pcap) as r:
        (t,) = r.topics()
        assert (t.name, t.count) == ("/ouster/lidar_scans", 1)
        (scan,) = [m for _, _, m in r.messages()]
    ref = decode(udp_payloads(pcap), H, 1024)
    assert scan.range_m.shape == (H, 1024) and scan.complete
    assert np.isfinite(scan.range_m).sum() == (ref > 0).sum()
    shifts = meta["data_format"]["pixel_shift_by_row"]
    assert list(scan.meta.pixel_shift_by_row) == shifts
    np.testing.assert_array_equal(_mm(scan.range_m), destagger(ref, shifts))
    pts = scan.points()
    assert len(pts) == (ref > 0).sum()
    # points lie at their range from the beam origin: |p| within lidar_origin_to_beam_origin of range
    r = scan.range_m[np.isfinite(scan.range_m)]
    off = meta["lidar_origin_to_beam_origin_mm"] / 1000.0
    d = np.linalg.norm(pts, axis=1)
    assert np.all(np.abs(d - r) <= off + 0.04)  # + lidar_to_sensor z offset
    assert scan.timestamp_ns > 1.4e18 and scan.pixel_times_ns().shape == (H, 1024)


def test_pcap_with_wrong_metadata_fails_loudly(tmp_path):
    shutil.copy(OUSTER / "OS-1-32-G_v2.1.1_1024x10.pcap", tmp_path / "x.pcap")
    shutil.copy(OUSTER / "OS-0-128-U1_v2.3.0_1024x10.json", tmp_path / "x.json")
    with pytest.raises(RecordingError, match=r"decoded 0 scans.*64x 6464 B to port 7502.*8448 bytes"), \
            open_recording(tmp_path / "x.pcap") as r:
        r.topics()
    shutil.copy(OUSTER / "OS-1-32-G_v2.1.1_1024x10.pcap", tmp_path / "y.pcap")
    with pytest.raises(RecordingError, match="no Ouster metadata next to it"):
        open_recording(tmp_path / "y.pcap")
    with open_recording(tmp_path / "y.pcap", meta=OUSTER / "OS-1-32-G_v2.1.1_1024x10.json") as r:
        assert r.topics()[0].count == 1


def test_packet_bag_assembles_one_frame():
    from rosbags.highlevel import AnyReader

    bag = FIXTURES / "ros1" / "512x10_raw.bag"
    with AnyReader([bag]) as r:
        msgs = [(c.topic, t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages()]
    meta_text = next(m.data for tp, _, m in msgs if tp.endswith("metadata"))
    bufs = [bytes(m.buf) for tp, _, m in msgs if tp.endswith("lidar_packets")]
    asm = PacketAssembler(meta_text)
    scans = [s for tp, t, m in msgs if tp.endswith("lidar_packets") for s in [asm.add(m.buf, t)] if s is not None]
    last = asm.flush()
    scans += [last] if last is not None else []
    assert len(scans) == 1 and asm.packets == 32
    s = scans[0]
    ref = staggered_rng15(bufs, 128, 512)
    np.testing.assert_array_equal(_mm(s.range_m), destagger(ref, s.meta.pixel_shift_by_row))
    assert np.isfinite(s.range_m).sum() == (ref > 0).sum() == 28751
    assert s.timestamp_ns == min(t for tp, t, _ in msgs if tp.endswith("lidar_packets"))
    with pytest.raises(RecordingError, match="not valid Ouster sensor metadata"):
        PacketAssembler('{"not": "ouster"}')
