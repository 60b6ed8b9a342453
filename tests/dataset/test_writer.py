"""Dataset writer: round trip (local + memory://), layout (chunks, shards, codec, attrs), atomic
whole-shard commits, resume after SIGKILL with identical checksums, ragged arrays, reopen rules."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from holodata.conventions import Grid, RangeBins
from holodata.dataset import FrameStorage, create_dataset, open_dataset
from holodata.dataset import shards as sh
from holodata.dataset.info import dataset_info
from holodata.dataset.synthetic import toy_frames, write_toy_dataset
from holodata.errors import DatasetError

G = Grid(8, 32)


def _write(url, T=10, S=4):
    w = create_dataset(url, grid=G, range_bins=RangeBins(), created_by="test", provenance={"x": 1}, shard_frames=S)
    sc = w.scene("c1", n_frames=T, attrs={"corner_type": "L", "width_m": 2.0})
    rng = np.random.default_rng(1)
    data = toy_frames(rng, range(T), G)
    r = sc.frame_array("gt/range", per_frame_shape=(3, 8, 32), dtype="float32",
                       dims=["frame", "bounce", "elevation", "azimuth"], units="m", fill_value=float("nan"))
    t = sc.frame_array("time/timestamp_ns", per_frame_shape=(), dtype="int64", dims=["frame"], units="ns", fill_value=0)
    for k in range(r.n_shards):
        assert not r.is_done(k)
        assert r.write_shard(k, data["gt/range"][r.frames(k)])
        assert r.is_done(k)
        t.write_shard(k, data["time/timestamp_ns"][t.frames(k)])
    pts = [rng.normal(size=(i % 4 * 5, 3)).astype(np.float32) for i in range(T)]
    rag = sc.ragged_array("lidar/points", width=3, dtype="float32", units="m")
    for k in range(rag.n_shards):
        rag.write_shard(k, pts[rag.frames(k)])
    sc.write_array("mesh/vertices", np.arange(12, dtype=np.float32).reshape(4, 3), dims=["vertex", "xyz"], units="m")
    w.set_splits(train=["c1"], test=[])
    return w, data, pts


@pytest.mark.parametrize("where", ["local", "memory"])
def test_round_trip(tmp_path, where):
    url = str(tmp_path / "rt.zarr") if where == "local" else f"memory://rt-{os.getpid()}/ds.zarr"
    w, data, pts = _write(url)
    ds = open_dataset(url)
    assert ds.grid == G and ds.range_bins == RangeBins() and ds.scenes == ["c1"]
    assert ds.splits == {"train": ["c1"], "test": []} and ds.attrs["holodata"]["format_version"] == "1.0"
    assert ds.attrs["holodata"]["provenance"] == {"x": 1}
    s = ds.scene("c1")
    assert s.n_frames == 10 and s.attrs["corner_type"] == "L"
    assert s.arrays() == ["gt/range", "lidar/points", "mesh/vertices", "time/timestamp_ns"]
    z = s["gt/range"]
    np.testing.assert_array_equal(z[...], data["gt/range"])  # NaNs compare equal here
    np.testing.assert_array_equal(z[5], data["gt/range"][5])  # lazy partial read
    assert z.attrs["dims"] == ["frame", "bounce", "elevation", "azimuth"] and z.attrs["units"] == "m"
    # one frame per chunk, 4 frames per shard, Blosc zstd + shuffle
    assert z.shards == (4, 3, 8, 32) and z.chunks == (1, 3, 8, 32)
    meta = json.loads(ds.store.get("scenes/c1/gt/range/zarr.json"))
    blosc = meta["codecs"][0]["configuration"]["codecs"][1]
    assert blosc["name"] == "blosc" and blosc["configuration"]["cname"] == "zstd"
    assert blosc["configuration"]["shuffle"] == "shuffle"
    np.testing.assert_array_equal(s["time/timestamp_ns"][...], data["time/timestamp_ns"])
    for i in range(10):
        np.testing.assert_array_equal(s.ragged("lidar/points", i), pts[i])
    rag = s["lidar/points"]
    off = rag.offsets[...]
    assert off[0] == 0 and off[-1] == rag.values.shape[0] == sum(len(p) for p in pts)
    np.testing.assert_array_equal(s["mesh/vertices"][...], np.arange(12).reshape(4, 3))
    # per-shard records: sha256 of the stored shard object + shape/dtype; folded into attrs when complete
    for k in range(3):
        rec = json.loads(ds.store.get(sh.manifest_key("scenes/c1/gt/range", k)))
        blob = ds.store.get(sh.shard_key("scenes/c1/gt/range", k, 4))
        assert rec["sha256"] == sh.sha256(blob) and rec["shape"] == [10, 3, 8, 32] and rec["dtype"] == "float32"
        assert z.attrs["holodata"]["shards"][k]["sha256"] == rec["sha256"]
    from holodata.dataset.validate import validate_dataset

    rep = validate_dataset(url)  # only gt/range of the gt/* set was written
    assert {p["rule"] for p in rep["problems"]} == {"presence"}
    toy = write_toy_dataset(url.replace("ds.zarr", "toy.zarr").replace("rt.zarr", "toy.zarr"), n_frames=5)
    assert validate_dataset(toy)["ok"]


def test_lz4_codec_and_done_shards_never_rewritten(tmp_path):
    url = str(tmp_path / "a.zarr")
    w = create_dataset(url, grid=G, shard_frames=2, codec="lz4")
    sc = w.scene("s", n_frames=3)
    a = sc.frame_array("gt/label", per_frame_shape=(3, 8, 32), dtype="uint8", dims=["frame", "bounce", "elevation", "azimuth"])
    assert a.n_shards == 2 and a.frames(1) == slice(2, 3)
    assert a.write_shard(0, np.ones((2, 3, 8, 32), np.uint8))
    key = tmp_path / "a.zarr" / sh.shard_key("scenes/s/gt/label", 0, 4)
    m0 = key.stat().st_mtime_ns
    assert a.write_shard(0, np.zeros((2, 3, 8, 32), np.uint8)) is False  # done: untouched
    assert key.stat().st_mtime_ns == m0
    with pytest.raises(DatasetError, match="shard 1: data shape"):
        a.write_shard(1, np.ones((2, 3, 8, 32), np.uint8))
    with pytest.raises(DatasetError, match="cannot be stored"):
        a.write_shard(1, np.ones((1, 3, 8, 32), np.float32))
    a.write_shard(1, np.full((1, 3, 8, 32), 2, np.uint8))
    z = open_dataset(url).scene("s")["gt/label"]
    assert z.metadata.codecs[0].codecs[1].cname.value == "lz4"
    assert z[...].tolist() == np.concatenate([np.ones((2, 3, 8, 32)), np.full((1, 3, 8, 32), 2)]).tolist()
    # every chunk stored even when equal to the fill value: the shard is never "absent"
    a2 = sc.frame_array("gt/range", per_frame_shape=(2,), dtype="float32", dims=["frame", "b"], units="m")
    a2.write_shard(0, np.full((2, 2), np.nan, np.float32))
    assert (tmp_path / "a.zarr" / sh.shard_key("scenes/s/gt/range", 0, 2)).exists()


def test_reopen_rules(tmp_path):
    url = str(tmp_path / "a.zarr")
    w = create_dataset(url, grid=G, shard_frames=4)
    sc = w.scene("s", n_frames=5, attrs={"corner_type": "T"})
    sc.frame_array("gt/range", per_frame_shape=(3, 8, 32), dtype="float32", dims=["frame", "b", "e", "a"], units="m")
    with pytest.raises(DatasetError, match="grid"):
        create_dataset(url, grid=Grid(16, 32))
    with pytest.raises(DatasetError, match="range bins"):
        create_dataset(url, grid=G, range_bins=RangeBins(n=128))
    w2 = create_dataset(url, grid=G, shard_frames=8)  # shard_frames applies to new arrays only
    with pytest.raises(DatasetError, match="has 5 frames"):
        w2.scene("s", n_frames=6)
    sc2 = w2.scene("s", n_frames=5)
    assert sc2.frame_array("gt/range", per_frame_shape=(3, 8, 32), dtype="float32").shard_frames == 4
    with pytest.raises(DatasetError, match="exists as"):
        sc2.frame_array("gt/range", per_frame_shape=(3, 8, 32), dtype="float64")
    with pytest.raises(DatasetError, match="corner_type"):
        sc2.set_attrs({"corner_type": "U"})
    with pytest.raises(DatasetError, match="unknown scene"):
        w2.set_splits(train=["nope"])
    with pytest.raises(DatasetError, match="dims"):
        sc2.frame_array("x/y", per_frame_shape=(2,), dims=["frame"])
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "f.txt").write_text("x")
    with pytest.raises(DatasetError, match="not a holodata dataset"):
        create_dataset(str(tmp_path / "junk"))


def test_ragged_in_order_and_empty_frames(tmp_path):
    url = str(tmp_path / "a.zarr")
    sc = create_dataset(url, grid=G, shard_frames=2).scene("s", n_frames=4)
    rag = sc.ragged_array("camera/points", width=3)
    with pytest.raises(DatasetError, match="write shard 0 before shard 1"):
        rag.write_shard(1, [np.zeros((1, 3)), np.zeros((1, 3))])
    rag.write_shard(0, [np.zeros((0, 3), np.float32), np.ones((2, 3), np.float32)])
    s = open_dataset(url).scene("s")
    assert s.ragged("camera/points", 1).shape == (2, 3) and s.ragged("camera/points", 0).shape == (0, 3)
    with pytest.raises(DatasetError, match="shard 1 not written"):
        s.ragged("camera/points", 2)
    rag.write_shard(1, [np.full((3, 3), 2, np.float32), np.zeros((0, 3), np.float32)])
    s = open_dataset(url).scene("s")
    assert s["camera/points"].offsets[...].tolist() == [0, 0, 2, 5, 5]
    np.testing.assert_array_equal(s.ragged("camera/points", 2), np.full((3, 3), 2))



def test_ragged_sequential_and_random_reads_agree(tmp_path):
    """Sequential reads come from one block per shard, random ones per frame: same rows, and the
    frames handed out are read-only (views of that block), so no caller can change a later read."""
    url = str(tmp_path / "a.zarr")
    rng = np.random.default_rng(0)
    rows = [rng.normal(size=(int(n), 3)).astype(np.float32) for n in rng.integers(0, 50, size=11)]
    rows[4] = np.zeros((0, 3), np.float32)
    sc = create_dataset(url, grid=G, shard_frames=4).scene("s", n_frames=11)
    rag = sc.ragged_array("camera/points", width=3)
    for k in range(3):
        rag.write_shard(k, rows[4 * k:4 * k + 4])
    s = open_dataset(url).scene("s")
    seq = [s.ragged("camera/points", i) for i in range(11)]
    for i in (5, 6):
        with pytest.raises(ValueError, match="read-only"):
            seq[i][:] = 99
    with pytest.raises(ValueError, match="read-only"):
        s.ragged("camera/points", 2)[:] = 99      # random access
    for order in (range(11), [7, 2, 9, 3, 4, 5, 10, 0, 1, 6, 8], range(10, -1, -1)):
        for i in order:
            np.testing.assert_array_equal(s.ragged("camera/points", i), rows[i])
    assert s._get_ragged("camera/points")._block is not None   # the sequential path was taken

WRITER = """
import os, sys, time
from pathlib import Path
from holodata.dataset import store as st
real_replace, n = os.replace, [0]
def replace(src, dst):
    # the 7th frame-array shard object (not a ragged values/offsets chunk): its bytes sit in the
    # temp file; announce, then hang before the rename
    if "/c/" in str(dst) and "/values/c/" not in str(dst) and "/offsets/c/" not in str(dst):
        n[0] += 1
        if n[0] == 7 and len(sys.argv) > 2:
            Path(sys.argv[2]).write_text(str(dst))
            time.sleep(60)
    real_replace(src, dst)
st.os.replace = replace
from holodata.dataset.synthetic import write_toy_dataset
write_toy_dataset(sys.argv[1], n_frames=24, shard_frames=4, scenes=("c1",), seed=3)
"""


def _records(root: Path) -> dict:
    return {str(p.relative_to(root)): json.loads(p.read_text())["sha256"] for p in root.rglob("manifest/*.json")}


def test_resume_after_sigkill_mid_shard_matches_uninterrupted_run(tmp_path):
    from holodata.dataset.validate import validate_dataset

    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    ref, out, marker = tmp_path / "ref.zarr", tmp_path / "out.zarr", tmp_path / "killed_at"
    subprocess.run([sys.executable, str(script), str(ref)], check=True, timeout=120)
    p = subprocess.Popen([sys.executable, str(script), str(out), str(marker)])
    deadline = time.time() + 60
    while time.time() < deadline and not marker.exists():
        time.sleep(0.01)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert p.returncode == -signal.SIGKILL
    victim = Path(marker.read_text())
    assert not victim.exists() and list(victim.parent.glob(f".{victim.name}.*.partial"))  # killed mid-put
    done_before = _records(out)
    assert 0 < len(done_before) < len(_records(ref))
    mtimes = {k: (out / k).stat().st_mtime_ns for k in done_before}
    rep = validate_dataset(str(out))  # half-written: never passes
    assert not rep["ok"] and any(p_["rule"] == "incomplete" for p_ in rep["problems"])
    name, k = str(victim.relative_to(out / "scenes/c1")).split("/c/")
    assert not open_dataset(str(out)).scene("c1").is_done(name, int(k.split("/")[0]))
    stale = list(victim.parent.glob(f".{victim.name}.*.partial"))
    for f in stale:  # the killed writer's temp files, as found hours later ...
        os.utime(f, (time.time() - 7200, time.time() - 7200))
    young = victim.parent / f".{victim.name}.{'0' * 32}.partial"  # ... and one a live writer may own
    young.write_bytes(b"x")
    manifest = (out / next(iter(done_before))).parent
    (manifest / f".0.json.{'0' * 32}.partial").write_bytes(b'{"sha')  # a manifest record half put
    assert young.name not in open_dataset(str(out)).store.list(str(young.parent.relative_to(out)))
    assert dataset_info(str(out))["scenes"]   # listings skip temp files (info read the half record as JSON)
    subprocess.run([sys.executable, str(script), str(out)], check=True, timeout=120)
    assert victim.exists()
    assert not any(f.exists() for f in stale) and young.exists()  # resuming swept only the old ones
    assert _records(out) == _records(ref)  # identical shard bytes
    assert all((out / k).stat().st_mtime_ns == m for k, m in mtimes.items())  # finished shards not rewritten
    assert validate_dataset(str(out))["ok"]


def test_toy_dataset_is_valid_and_deterministic(tmp_path):
    from holodata.dataset.validate import validate_dataset

    a = write_toy_dataset(str(tmp_path / "a.zarr"), n_frames=6, scenes=("x", "y"), seed=5)
    b = write_toy_dataset(str(tmp_path / "b.zarr"), n_frames=6, scenes=("x", "y"), seed=5)
    assert validate_dataset(a)["ok"]
    assert _records(Path(a)) == _records(Path(b))


def test_ragged_resume_after_torn_append(tmp_path):
    """A writer that died after growing values/offsets but before its commit record: the rerun
    rewrites that shard from the last committed row; readers and validate never saw it."""
    import zarr

    from holodata.dataset.validate import validate_dataset

    url = str(tmp_path / "a.zarr")
    w = create_dataset(url, grid=G, shard_frames=2)
    sc = w.scene("s", n_frames=4)
    sc.frame_array("time/timestamp_ns", per_frame_shape=(), dtype="int64", dims=["frame"], units="ns").write_shard(0, [1, 2])
    sc.frame_array("time/timestamp_ns", per_frame_shape=(), dtype="int64").write_shard(1, [3, 4])
    rag = sc.ragged_array("lidar/points", width=3)
    f = [np.full((n, 3), i, np.float32) for i, n in enumerate([3, 1, 2, 5])]
    rag.write_shard(0, f[:2])
    vals = zarr.open_array(url + "/scenes/s/lidar/points/values", mode="r+")
    vals.resize((40, 3))
    vals[4:40] = -7.0  # torn append: rows written, no commit record
    rep = validate_dataset(url)
    assert not rep["ok"] and {p["rule"] for p in rep["problems"]} >= {"incomplete"}
    sc = create_dataset(url, grid=G).scene("s", n_frames=4)
    rag = sc.ragged_array("lidar/points", width=3)
    assert rag.is_done(0) and not rag.is_done(1)
    rag.write_shard(1, f[2:])
    s = open_dataset(url).scene("s")
    for i in range(4):
        np.testing.assert_array_equal(s.ragged("lidar/points", i), f[i])
    assert s["lidar/points"].values.shape == (11, 3)
    assert validate_dataset(url)["ok"]


@pytest.mark.parametrize("where", ["local", "memory"])
def test_remove_lets_a_later_stage_rewrite_an_array(tmp_path, where):
    url = str(tmp_path / "d.zarr") if where == "local" else "memory://remove-test/d.zarr"
    w = create_dataset(url, grid=G, range_bins=RangeBins(), created_by="test", shard_frames=4)
    sc = w.scene("c1", n_frames=6)
    a = sc.frame_array("pose/T_world_radar", (4, 4), "float64", ["frame", "row", "col"], "m")
    for k in range(a.n_shards):
        a.write_shard(k, np.broadcast_to(np.eye(4), (len(range(6)[a.frames(k)]), 4, 4)))
    sc.remove("pose/T_world_radar")
    assert "pose/T_world_radar" not in sc.arrays()
    b = sc.frame_array("pose/T_world_radar", (4, 4), "float64", ["frame", "row", "col"], "m")
    assert not b.is_done(0)
    new = np.broadcast_to(np.eye(4), (6, 4, 4)).copy()
    new[:, 0, 3] = 2.0
    for k in range(b.n_shards):
        b.write_shard(k, new[b.frames(k)])
    got = np.asarray(open_dataset(url).scene("c1")["pose/T_world_radar"][...])
    assert np.array_equal(got, new)


@pytest.mark.parametrize("codec", ["zstd", "lz4"])
def test_fast_shard_codec_is_byte_exact_with_zarr_and_catches_damage(tmp_path, codec):
    """encode_shard assembles shard objects itself (Zarr v3 sharding spec: Blosc chunks + (offset,
    nbytes) index + crc32c); they must equal zarr-python's own bytes (full and partial last shard,
    0-d and n-d frames, several dtypes), zarr must read them back, and decode_shard must refuse a
    damaged index or chunk header."""
    import zarr

    url = tmp_path / "x.zarr"
    sc = create_dataset(url, codec=codec).scene("s", n_frames=11)
    rng = np.random.default_rng(3)
    for name, per, dt in [("a", (4, 5), "float32"), ("b", (), "int64"), ("f", (3, 2, 2), "float16"),
                          ("d", (2, 7), "uint16")]:
        w = sc.frame_array(name, per, dt, storage=FrameStorage(shard_frames=4))
        data = (rng.normal(size=(11,) + per) * 100).astype(dt)
        for k in range(w.n_shards):
            part = data[w.frames(k)]
            blob = sh.encode_shard(w.meta, part)
            assert sh._fast_layout(w.meta) is not None
            assert blob == sh._encode_shard_zarr(w.meta, part), (name, k)
            assert np.array_equal(sh.decode_shard(w.meta, len(part), blob), part)
            assert w.write_shard(k, part)
        got = zarr.open_array(str(url), path=f"scenes/s/{name}", mode="r")[...]
        assert got.dtype == np.dtype(dt) and np.array_equal(got, data)
    w = sc.frame_array("a", (4, 5), "float32")
    part = rng.normal(size=(4, 4, 5)).astype(np.float32)
    blob = bytearray(sh.encode_shard(w.meta, part))
    bad_index = bytes(blob[:-20]) + bytes([blob[-20] ^ 1]) + bytes(blob[-19:])
    with pytest.raises(ValueError, match="crc32c"):
        sh.decode_shard(w.meta, 4, bad_index)
    bad_header = bytes([blob[0]]) + bytes(blob[1:4]) + (999).to_bytes(4, "little") + bytes(blob[8:])
    with pytest.raises(ValueError, match="damaged"):
        sh.decode_shard(w.meta, 4, bad_header)
    with pytest.raises(ValueError):
        sh.decode_shard(w.meta, 4, bytes(blob[:10]))


def test_ragged_rows_written_chunk_by_chunk_match_zarr(tmp_path, monkeypatch):
    """Ragged values are stored chunk by chunk without zarr's write path (edge chunk read back and
    completed); with 7-row chunks every shard boundary falls inside a chunk. zarr reads the rows
    back exactly, and a run through zarr's own setitem stores the same values."""
    import zarr

    from holodata.dataset import writer as wmod

    monkeypatch.setattr(wmod, "RAGGED_CHUNK_BYTES", 7 * 12)
    rng = np.random.default_rng(5)
    frames = [rng.normal(size=(int(n), 3)).astype(np.float32) for n in rng.integers(0, 12, 13)]
    got = {}
    for fast in (True, False):
        if not fast:
            monkeypatch.setattr(wmod.sh, "chunk_codec", lambda meta: None)
        url = tmp_path / f"r{fast}.zarr"
        rag = create_dataset(url, shard_frames=3).scene("s", n_frames=13).ragged_array("p", width=3)
        for k in range(rag.n_shards):
            assert rag.write_shard(k, frames[rag.frames(k)])
        vals = zarr.open_array(str(url), path="scenes/s/p/values", mode="r")
        assert vals.chunks == (7, 3)
        got[fast] = vals[...]
        assert np.array_equal(got[fast], np.concatenate(frames))
        rd = open_dataset(url).scene("s")
        for i in (0, 5, 12):
            assert np.array_equal(rd.ragged("p", i), frames[i])
    assert np.array_equal(got[True], got[False])


def test_open_for_update_keeps_the_dataset_s_grid_and_range_bins(tmp_path):
    from holodata.dataset import DatasetWriter

    url = str(tmp_path / "u.zarr")
    create_dataset(url, grid=Grid(4, 16), range_bins=RangeBins(64, 0.05)).scene("s", n_frames=2)
    w = open_dataset(url, "r+", created_by="test")
    assert isinstance(w, DatasetWriter) and w.grid == Grid(4, 16) and w.range_bins == RangeBins(64, 0.05)
    w.scene("s").write_array("mesh/vertices", np.zeros((3, 3), np.float32), ["vertex", "xyz"])
    sc = open_dataset(url).scene("s")
    assert sc["mesh/vertices"].attrs["units"] == "m"           # the layout's units, the caller gave none
    with pytest.raises(ValueError, match="mode"):
        open_dataset(url, "w")


def test_next_writer_sweeps_stale_partials_but_not_a_concurrent_writers(tmp_path, monkeypatch):
    """Like two Dask tasks on one array: writer A is inside a shard put (its temp object written, the
    rename pending) when writer B opens the array and writes other shards. B's sweep removes a
    temp object older than the threshold (left by a writer killed hours ago) but not A's, so A's
    put still lands and every shard is committed with the right data."""
    import threading

    from holodata.dataset import store as st

    T, S = 8, 2
    url = str(tmp_path / "d.zarr")
    data = toy_frames(np.random.default_rng(4), range(T), G)["gt/range"]

    def array():
        w = create_dataset(url, grid=G, range_bins=RangeBins(), created_by="test", provenance={"x": 1}, shard_frames=S)
        sc = w.scene("c1", n_frames=T, attrs={"corner_type": "L", "width_m": 2.0})
        return sc.frame_array("gt/range", per_frame_shape=(3, 8, 32), dtype="float32",
                              dims=["frame", "bounce", "elevation", "azimuth"], units="m", fill_value=float("nan"))

    a0 = array()
    assert a0.write_shard(0, data[a0.frames(0)])
    folder = tmp_path / "d.zarr" / "scenes" / "c1" / "gt" / "range"
    shard0 = next(p for p in folder.rglob("*") if p.is_file() and "/c/0" in str(p))
    stale = shard0.parent / f".{shard0.name}.{'f' * 32}.partial"      # a writer killed two hours ago
    stale.write_bytes(b"half a shard")
    os.utime(stale, (time.time() - 7200, time.time() - 7200))

    in_put, go, seen = threading.Event(), threading.Event(), []

    def paused(move):
        def run(*args, **kw):
            src, dst = str(args[-2]), str(args[-1])
            if "/gt/range/c/1/" in dst and not in_put.is_set():
                seen.append(src)
                in_put.set()
                assert go.wait(60)
            return move(*args, **kw)
        return run

    monkeypatch.setattr(st.os, "replace", paused(os.replace))
    result = {}
    a = threading.Thread(target=lambda: result.setdefault("a", (w := array()).write_shard(1, data[w.frames(1)])))
    a.start()
    try:
        assert in_put.wait(60), "writer A never reached its rename"
        a_tmp = Path(seen[0])
        assert a_tmp.exists() and a_tmp.name.endswith(".partial")
        b = array()                       # the next writer: opening the array sweeps
        assert not stale.exists(), "a temp object older than the threshold was left"
        assert a_tmp.exists(), "the sweep removed a live writer's temp object"
        assert b.write_shard(2, data[b.frames(2)]) and b.write_shard(3, data[b.frames(3)])
    finally:
        go.set()
        a.join(60)
    assert result.get("a") is True
    sc = open_dataset(url).scene("c1")
    assert all(sc.is_done("gt/range", k) for k in range(T // S))
    np.testing.assert_array_equal(sc["gt/range"][...], data)
    assert not list(folder.rglob("*.partial"))


def test_sweep_on_a_non_object_store_filesystem_keeps_young_partials(tmp_path):
    """fsspec filesystems that write in place (puts go through ``.partial`` objects): the sweep
    goes by the objects' modification time as on local folders."""
    from holodata.dataset.store import Store

    st = Store(f"local://{tmp_path}/ds")
    assert not st.local and not st.atomic_put
    st.put("a/c/0", b"shard")
    old, young = tmp_path / "ds/a/c/.1.{}.partial".format("e" * 32), tmp_path / "ds/a/c/.2.{}.partial".format("d" * 32)
    old.write_bytes(b"x")
    young.write_bytes(b"y")
    os.utime(old, (time.time() - 7200, time.time() - 7200))
    assert st.sweep_partials("a", older_than_s=3600) == 1
    assert not old.exists() and young.exists() and st.get("a/c/0") == b"shard"
    assert Store(str(tmp_path / "ds")).sweep_partials("a", older_than_s=0) == 1 and not young.exists()
