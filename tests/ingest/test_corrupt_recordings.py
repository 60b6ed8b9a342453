"""Corrupt recordings never become invalid datasets: seeded mutants (bytes overwritten, spans zeroed,
spans cut) of holodata synth recordings (MCAP as rosbags writes it, the same MCAP with chunk CRCs as
the mcap library writes it, ROS 1) and of real fixtures written by other tools either ingest into a
dataset that ``validate`` accepts, or fail with one line that names the file (never a Python
exception class). Damage that the container can see (an MCAP chunk's CRC) drops the messages it
holds, counted in the scene's ``ingest`` attributes and in one warning line."""
from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _paths import FIXTURES

from holodata.conventions import Grid
from holodata.dataset import validate_dataset

HOLODATA = [sys.executable, "-m", "holodata.cli.main"]
EXC_NAME = re.compile(r"\b[A-Z][A-Za-z]+(Error|Exception)\b")


def mutate(data: bytes, rng: np.random.Generator, kind: int, lo: int) -> bytes:
    """kind 0: 1-64 random bytes overwritten within 4 KB; 1: a 16 B-4 KB span zeroed; 2: cut out."""
    d = bytearray(data)
    pos = int(rng.integers(lo, max(lo + 1, len(d) - 4200)))
    if kind == 0:
        for j in rng.integers(pos, pos + 4096, int(rng.integers(1, 65))):
            d[min(int(j), len(d) - 1)] = int(rng.integers(256))
    elif kind == 1:
        n = int(rng.integers(16, 4096))
        d[pos:pos + n] = bytes(n)
    else:
        del d[pos:pos + int(rng.integers(16, 4096))]
    return bytes(d)


def _synth(root: Path, fmt: str) -> Path:
    from holodata.synth import SynthSpec, synthesize

    out = root / f"L_{fmt}"
    synthesize(out, SynthSpec(corner="L", frames=12, seed=5, format=fmt, grid=Grid(16, 64), lidar_shape=(16, 128),
                              camera_shape=(48, 64)), quiet=True)
    return out / "recording" if fmt == "mcap" else out / "recording.bag"


def with_chunk_crcs(src: Path, dst: Path) -> None:
    """Rewrite the rosbag2 MCAP file ``src`` with the mcap library's writer (uncompressed 1 MB chunks
    carrying CRC-32s, as ``ros2 bag record`` writes them; rosbags' writer leaves them 0)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as fi, open(dst, "wb") as fo:
        r = make_reader(fi)
        w = Writer(fo, compression=CompressionType.NONE, enable_crcs=True)
        w.start(profile="ros2", library="holodata-test")
        summary = r.get_summary()
        schemas = {sid: w.register_schema(sc.name, sc.encoding, sc.data) for sid, sc in summary.schemas.items()}
        chans = {cid: w.register_channel(ch.topic, ch.message_encoding, schemas.get(ch.schema_id, 0), ch.metadata)
                 for cid, ch in summary.channels.items()}
        for _, ch, m in r.iter_messages(log_time_order=False):
            w.add_message(chans[ch.id], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("corrupt")
    out = {"mcap": _synth(root, "mcap"), "rosbag1": _synth(root, "rosbag1")}
    crc = root / "crc" / "recording"
    shutil.copytree(out["mcap"], crc)
    mc = next(crc.glob("*.mcap"))
    with_chunk_crcs(next(out["mcap"].glob("*.mcap")), mc)
    out["mcap-crc"] = crc
    return out


def _cases(synth: dict[str, Path]) -> list[tuple[Path, Path]]:
    """(recording to copy, file in it to damage)."""
    out = [(synth["mcap"], next(synth["mcap"].glob("*.mcap"))), (synth["mcap-crc"], next(synth["mcap-crc"].glob("*.mcap"))),
           (synth["rosbag1"], synth["rosbag1"])]
    for rel in ("mcap/rosbag2_2025_09_10-13_03_56_0.mcap", "ros1/luminar-test.bag", "ros1/512x10_raw.bag"):
        p = FIXTURES / rel
        if p.is_file():
            out.append((p, p))
    return out


def _ingest(src: Path, url: Path) -> subprocess.CompletedProcess:
    return subprocess.run(HOLODATA + ["ingest", str(src), "--out", str(url), "--quiet", "--json"],
                          capture_output=True, text=True, timeout=300)


def _copy(rec: Path, victim: Path, work: Path) -> tuple[Path, Path]:
    """Copy recording ``rec`` under ``work``; (what to ingest, the copy of ``victim``)."""
    if rec.is_dir():
        shutil.copytree(rec, work)
        return work, work / victim.name
    work.mkdir()
    return work / victim.name, work / victim.name


@pytest.mark.slow
def test_mutants_ingest_into_valid_datasets_or_fail_in_one_line(synth, tmp_path):
    rng = np.random.default_rng(2026)
    n_ok = n_failed = 0
    for c, (rec, victim) in enumerate(_cases(synth)):
        data = victim.read_bytes()
        for i in range(6):
            src, target = _copy(rec, victim, tmp_path / f"{c}_{victim.stem}_{i}")
            target.write_bytes(mutate(data, rng, i % 3, lo=min(1000, len(data) // 4)))
            url = tmp_path / f"{c}_{victim.stem}_{i}.zarr"
            r = _ingest(src, url)
            what = f"{victim.name} mutant {i} (kind {i % 3})"
            assert "Traceback" not in r.stderr, f"{what}: {r.stderr[-600:]}"
            if r.returncode == 0:
                rep = validate_dataset(str(url))
                assert rep["ok"], f"{what}: ingest exit 0 but validate: {rep['problems'][0]['line']}"
                n_ok += 1
            else:
                assert r.returncode == 1, f"{what}: {r.stderr[-400:]}"
                err = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
                assert len(err) == 1, f"{what}: {r.stderr[-400:]}"
                assert str(target) in err[0] or str(src) in err[0], f"{what}: the error names no file: {err[0]}"
                assert not EXC_NAME.search(err[0]), f"{what}: a Python exception class in {err[0]}"
                assert not (url.exists() and validate_dataset(str(url))["ok"])
                n_failed += 1
    assert n_ok >= 6   # most damage is survivable: the readable part is ingested


def _message_span(path: Path, topic: str, k: int) -> tuple[int, int]:
    """(file offset, size) of the payload of the ``k``-th message on ``topic`` in an MCAP file."""
    from holodata.readers.mcap_file import McapMessageTable

    t = McapMessageTable.build(path)
    ch = next(i for i, n in t.topics.items() if n == topic)
    off = int(t.offsets[t.channels == ch][k])
    with open(path, "rb") as f:
        f.seek(off)
        op, length = struct.unpack("<BQ", f.read(9))
    assert op == 0x05
    return off + 31, length - 22


@pytest.mark.slow
def test_a_chunk_that_fails_its_crc_drops_its_messages_counted(synth, tmp_path):
    """Zeroed bytes inside one radar heatmap are valid amplitudes — only the chunk's CRC sees them. The
    damaged message is dropped (counted in the scene's ingest attrs, one warning line naming the
    chunk); the other frames are ingested and the dataset validates. The same recording written by
    rosbags (no CRCs) ingests every frame: zeros pass every value rule."""
    from holodata.dataset import open_dataset

    rec = synth["mcap-crc"]
    mc = next(rec.glob("*.mcap"))
    off, size = _message_span(mc, "/radar/heatmap", 5)
    src, target = _copy(rec, mc, tmp_path / "damaged")
    d = bytearray(mc.read_bytes())
    d[off + size // 2:off + size // 2 + 64] = bytes(64)
    assert bytes(d) != mc.read_bytes()
    target.write_bytes(bytes(d))
    good = _ingest(rec, tmp_path / "good.zarr")
    assert good.returncode == 0, good.stderr
    r = _ingest(src, tmp_path / "bad.zarr")
    assert r.returncode == 0, r.stderr
    assert validate_dataset(str(tmp_path / "bad.zarr"))["ok"]
    ds_good, ds_bad = open_dataset(tmp_path / "good.zarr"), open_dataset(tmp_path / "bad.zarr")
    n_good = ds_good.scene(ds_good.scenes[0]).n_frames
    sc = ds_bad.scene(ds_bad.scenes[0])
    assert sc.n_frames == n_good - 1
    assert sc.attrs["ingest"]["dropped"]["radar"].get("undecodable") == 1
    warn = [w for w in json.loads(r.stdout)["scenes"][0]["warnings"] if "CRC" in w]
    assert len(warn) == 1 and "radar" in warn[0] and "chunk at byte" in warn[0], warn


def test_a_tf_transform_with_nan_is_left_out():
    """A TF transform whose damaged bytes read as NaN/inf would make every pose composed through it
    NaN (validate rejects those poses): the buffer leaves it out and says so by its count."""
    from types import SimpleNamespace as N

    from holodata.readers.tf import TransformBuffer

    def ts(x, w, t):
        return N(header=N(frame_id="odom", stamp=N(sec=t, nanosec=0)), child_frame_id="base_link",
                 transform=N(translation=N(x=x, y=0.0, z=0.0), rotation=N(x=0.0, y=0.0, z=0.0, w=w)))

    tf = TransformBuffer()
    assert tf.add_message(N(transforms=[ts(0.0, 1.0, 1), ts(float("nan"), 1.0, 2), ts(1.0, float("inf"), 3),
                                        ts(2.0, 1.0, 4)])) == 2
    T = tf.lookup("odom", "base_link", 3 * 10**9)     # between the two kept ones (t = 1 s, x = 0; t = 4 s, x = 2)
    assert T is not None and np.isfinite(T).all() and abs(T[0, 3] - 2.0 * 2 / 3) < 1e-9
