"""The paper-grid loader (issue 51 points 1-2): log-amplitude uint8 heatmap codes, frames read straight
from their shards, range pooling + normalisation by table lookup; every fast path against the plain
numpy/zarr way of doing the same work."""
import json
from pathlib import Path

import numpy as np
import pytest

from holodata.conventions import Grid, LogCode
from holodata.dataset import open_dataset, validate_dataset
from holodata.dataset.heatmap import read_heatmap
from holodata.dataset.layout import GT_LABEL, GT_RANGE, RADAR_HEATMAP
from holodata.errors import DatasetError
from holodata.synth.corpus import CorpusConfig, synth_corpus

torch = pytest.importorskip("torch")

from holodata.torch import HeatmapDataset  # noqa: E402
from holodata.torch._lut_kernel import pool_lookup  # noqa: E402
from holodata.torch.data import HeatmapNorm, SampleTransform, apply_transform  # noqa: E402

SMALL = dict(corners=2, frames=2, grid=Grid(8, 32))


@pytest.fixture(scope="module")
def corpora(tmp_path_factory):
    d = tmp_path_factory.mktemp("loader")
    out = {}
    for dt in ("uint8", "float16"):
        out[dt] = str(d / f"{dt}.zarr")
        synth_corpus(out[dt], CorpusConfig(heatmap_dtype=dt, **SMALL), processes=1, quiet=True)
    return out


def test_log_code_round_trip_and_monotone():
    c = LogCode()
    a = np.concatenate([[0.0], np.logspace(-4, 2.5, 2000)]).astype(np.float32)
    q = c.encode(a)
    assert q[0] == 0 and c.decode(q)[0] == 0.0            # amplitude 0 is code 0 and back
    assert np.all(np.diff(q.astype(int)) >= 0)             # monotone: pooling commutes with the code
    inside = (a > 0.01) & (a < 10 ** c.hi - c.eps)
    step = (c.hi - c.lo) / 255
    err = np.abs(np.log10(c.decode(q)[inside] + c.eps) - np.log10(a[inside] + c.eps))
    assert err.max() <= step / 2 + 1e-6                   # half a step in log10(a + eps)
    assert q[a > 10 ** c.hi].min() == 255                  # saturates
    assert LogCode.from_attrs(c.to_attrs()) == c
    for bad in ({"kind": "linear"}, {"kind": "log10_u8", "eps": 1e-3, "lo": 1.0, "hi": 0.0}, None):
        with pytest.raises(ValueError):
            LogCode.from_attrs(bad)


@pytest.mark.parametrize("codes", ["uint8", "float16"])
@pytest.mark.parametrize("f", [1, 2, 3])
def test_pool_lookup_is_numpy_pool_of_the_norm(codes, f):
    rng = np.random.default_rng(f)
    norm = HeatmapNorm(lo=-2.5, hi=1.0)
    if codes == "uint8":
        q = rng.integers(0, 256, (12, 4, 6)).astype(np.uint8)
        values = norm(LogCode().table())
        amp = LogCode().decode(q)
    else:
        amp = rng.lognormal(-3, 2, (12, 4, 6)).astype(np.float16)
        amp[0, 0, 0] = 0
        q = amp.view(np.uint16)
        with np.errstate(invalid="ignore"):
            values = norm(np.arange(65536, dtype=np.uint32).astype(np.uint16).view(np.float16))
    want, _, _ = apply_transform(norm(amp.astype(np.float32)), np.zeros((3, 4, 6)), np.zeros((3, 4, 6)),
                                 SampleTransform(range_pool=f))
    for dt in (np.float32, np.float16):
        got = pool_lookup(q, values, f, dt)
        assert got.dtype == dt and got.shape == (12 // f, 4, 6)
        np.testing.assert_array_equal(got, want.astype(dt))


def test_uint8_corpus_validates_and_decodes_close_to_float16(corpora):
    for url in corpora.values():
        assert validate_dataset(url)["ok"]
    u, h = open_dataset(corpora["uint8"]), open_dataset(corpora["float16"])
    sid = u.scenes[0]
    meta = json.loads(Path(f"{corpora['uint8']}/scenes/{sid}/{RADAR_HEATMAP}/zarr.json").read_text())
    assert meta["data_type"] == "uint8" and meta["fill_value"] == 0
    assert LogCode.from_attrs(meta["attributes"]["encoding"]) == LogCode()
    a, b = read_heatmap(u.scene(sid), 1), read_heatmap(h.scene(sid), 1)
    assert a.dtype == b.dtype == np.float32
    big = b > 0.01          # same simulation, stored two ways: within the code's step (float16 rounding aside)
    assert np.abs(np.log10(a[big] + 1e-3) - np.log10(b[big] + 1e-3)).max() < 0.012


def test_scene_frame_reads_what_zarr_reads(corpora):
    ds = open_dataset(corpora["uint8"])
    sc = ds.scene(ds.scenes[1])
    for name in (RADAR_HEATMAP, GT_RANGE, GT_LABEL):
        for k in range(sc.n_frames):
            np.testing.assert_array_equal(sc.frame(name, k), np.asarray(sc[name][k]))
    with pytest.raises(DatasetError, match="no frame 5"):
        sc.frame(GT_RANGE, 5)


@pytest.mark.parametrize("dt", ["uint8", "float16"])
def test_samples_equal_the_plain_path(corpora, dt):
    tf = SampleTransform(range_pool=2, crop_w=16, random_crop=True)
    ds = HeatmapDataset(corpora[dt], split="train", transform=tf)
    ds.set_epoch(3, 1)
    for i in range(len(ds)):
        s = ds[i]
        hm, rng, lab = ds.read(i)
        hm, rng, lab = apply_transform(hm, rng, lab, tf, ds.sample_gen(i))
        np.testing.assert_array_equal(s["heatmap"].numpy(), ds.norm(hm))
        np.testing.assert_array_equal(s["range"].numpy(), rng)
        np.testing.assert_array_equal(s["label"].numpy(), lab)
    half = HeatmapDataset(corpora[dt], split="train", transform=tf, norm=ds.norm, dtype=np.float16)
    half.set_epoch(3, 1)
    assert half[0]["heatmap"].dtype == torch.float16
    np.testing.assert_array_equal(half[0]["heatmap"].numpy(), ds[0]["heatmap"].numpy().astype(np.float16))


def test_damaged_shard_index_is_one_line(corpora, tmp_path):
    import shutil

    url = str(tmp_path / "d.zarr")
    shutil.copytree(corpora["uint8"], url)
    ds = open_dataset(url)
    sid = ds.scenes[0]
    shard = next(p for p in (tmp_path / "d.zarr" / "scenes" / sid / RADAR_HEATMAP / "c").rglob("*") if p.is_file())
    b = bytearray(shard.read_bytes())
    b[-10] ^= 0xFF        # inside the index: its crc32c no longer matches
    shard.write_bytes(bytes(b))
    with pytest.raises(DatasetError, match="crc32c"):
        open_dataset(url).scene(sid).frame(RADAR_HEATMAP, 0)


def test_heatmap_encoding_is_checked_by_validate(corpora, tmp_path):
    import shutil

    url = str(tmp_path / "e.zarr")
    shutil.copytree(corpora["uint8"], url)
    sid = open_dataset(url).scenes[0]
    p = tmp_path / "e.zarr" / "scenes" / sid / RADAR_HEATMAP / "zarr.json"
    meta = json.loads(p.read_text())
    meta["attributes"].pop("encoding")
    p.write_text(json.dumps(meta))
    rep = validate_dataset(url)
    assert not rep["ok"] and any("encoding" in p["message"] for p in rep["problems"])


@pytest.mark.parametrize("flags, said", [(["--grid", "16x64"], "grid 8x32 (asked: 16x64)"),
                                         (["--grid", "8x32", "--heatmap-dtype", "float16"],
                                          "heatmap_dtype uint8 (asked: float16)")])
def test_a_corpus_of_other_settings_is_one_line(corpora, flags, said):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "holodata.cli.main", "synth", "--corners", "3", "--frames", "2",
                        "--out", corpora["uint8"], "--quiet", *flags], capture_output=True, text=True)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and said in r.stderr, r.stderr
