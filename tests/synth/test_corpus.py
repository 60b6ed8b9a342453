"""``holodata synth --corners``: training corners at scale as one dataset (issue 42 point 1)."""
import re

import numpy as np
import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.conventions import Grid
from holodata.dataset import open_dataset, validate_dataset
from holodata.dataset.layout import GT_LABEL, GT_RANGE, RADAR_HEATMAP
from holodata.errors import InputError
from holodata.synth import corpus
from holodata.synth.corpus import CorpusConfig, scene_id, synth_corpus

SMALL = dict(frames=2, grid=Grid(8, 32))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    url = str(tmp_path_factory.mktemp("corpus") / "c.zarr")
    res = synth_corpus(url, CorpusConfig(corners=4, n_test=1, **SMALL), processes=1, quiet=True)
    return url, res


def test_corpus_validates_with_every_kind_and_splits(small):
    url, res = small
    assert validate_dataset(url, quiet=True)["ok"]
    ds = open_dataset(url)
    assert ds.scenes == [scene_id(i) for i in range(4)]
    assert [ds.scene(s).attrs["corner_type"] for s in ds.scenes] == ["T", "L", "cross", "oblique"]
    assert ds.splits["train"] == ds.scenes[:3] and ds.splits["test"] == ds.scenes[3:]
    sc = ds.scene(ds.scenes[0])
    assert sc[RADAR_HEATMAP].shape == (2, 256, 8, 32) and sc[GT_RANGE].shape == (2, 3, 8, 32)
    assert sc.attrs["gt"]["origin_source"] == "recording" and sc.attrs["gt"]["column_times_from"] == "radar/cycle_ns"
    assert res["span"][0].startswith("corners 4: T 1, L 1, cross 1, oblique 1")
    assert res["written"] == 4


def test_heatmap_and_ground_truth_agree(small):
    """The strongest range bin of a beam beyond the TX→RX leakage (0.25 m) sits at its GT bounce-1
    range (same origins, times, bins); another corner's ground truth does not."""
    url, _ = small
    ds = open_dataset(url)
    dr = ds.range_bins.dr
    k0 = int(0.25 / dr)
    peaks, r1s = [], []
    for sid in ds.scenes:
        sc = ds.scene(sid)
        hm = np.asarray(sc[RADAR_HEATMAP][...], np.float32)
        peaks.append((hm[:, k0:].argmax(axis=1) + k0 + 0.5) * dr)
        r1s.append(np.asarray(sc[GT_RANGE][...])[:, 0])

    def hit(p, r):
        m = np.isfinite(r)
        return np.mean(np.abs(p - r)[m] <= 2 * dr)

    assert np.mean([hit(p, r) for p, r in zip(peaks, r1s)]) > 0.6
    assert np.mean([hit(p, r) for p, r in zip(peaks, r1s[1:] + r1s[:1])]) < 0.3


def test_corner_draws_do_not_depend_on_the_corpus_size(small, tmp_path):
    url, _ = small
    url2 = str(tmp_path / "c2.zarr")
    synth_corpus(url2, CorpusConfig(corners=2, **SMALL), processes=1, quiet=True)
    a, b = open_dataset(url).scene(scene_id(1)), open_dataset(url2).scene(scene_id(1))
    np.testing.assert_array_equal(a[RADAR_HEATMAP][...], b[RADAR_HEATMAP][...])
    np.testing.assert_array_equal(a[GT_LABEL][...], b[GT_LABEL][...])
    assert a.attrs["synth"] == b.attrs["synth"]


def test_interrupted_corner_never_validates_and_resumes_identically(small, tmp_path, monkeypatch):
    url, _ = small
    url2 = str(tmp_path / "cut.zarr")
    import holodata.groundtruth as gt

    def killed(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(gt, "raytrace_dataset", killed)   # killed after the inputs, before the ground truth
    with pytest.raises(KeyboardInterrupt):
        synth_corpus(url2, CorpusConfig(corners=2, **SMALL), processes=1, quiet=True)
    rep = validate_dataset(url2, quiet=True)
    assert not rep["ok"] and any("synth did not finish" in p["line"] for p in rep["problems"])
    monkeypatch.undo()
    res = synth_corpus(url2, CorpusConfig(corners=2, **SMALL), processes=1, quiet=True)
    assert res["written"] == 2 and validate_dataset(url2, quiet=True)["ok"]
    a, b = open_dataset(url).scene(scene_id(0)), open_dataset(url2).scene(scene_id(0))
    for name in (RADAR_HEATMAP, GT_RANGE, GT_LABEL):
        np.testing.assert_array_equal(a[name][...], b[name][...])


def test_two_processes_write_the_same_corpus(small, tmp_path):
    url, _ = small
    url2 = str(tmp_path / "p2.zarr")
    synth_corpus(url2, CorpusConfig(corners=2, **SMALL), processes=2, quiet=True)
    for i in range(2):
        np.testing.assert_array_equal(open_dataset(url).scene(scene_id(i))[GT_RANGE][...],
                                      open_dataset(url2).scene(scene_id(i))[GT_RANGE][...])


def test_other_settings_on_an_existing_corpus_are_refused(small):
    url, _ = small
    with pytest.raises(InputError, match="other settings.*frames 2"):
        synth_corpus(url, CorpusConfig(corners=4, frames=3, grid=Grid(8, 32)), processes=1, quiet=True)


@pytest.mark.parametrize("args,msg", [(["--corners", "0"], "--corners must be >= 1"),
                                      (["--corners", "2", "--frames", "0"], "--frames must be >= 1"),
                                      (["--corners", "2", "--frames", "-3"], "--frames must be >= 1")])
def test_cli_bad_counts_are_one_line_exit_1(tmp_path, args, msg):
    r = CliRunner().invoke(cli, ["synth", "--out", str(tmp_path / "x.zarr"), *args])
    assert r.exit_code == 1, r.output
    assert msg in r.output and "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1


def test_cli_writes_and_reports_the_span(tmp_path):
    out = str(tmp_path / "cli.zarr")
    r = CliRunner().invoke(cli, ["synth", "--corners", "2", "--frames", "1", "--grid", "8x32", "--out", out,
                                 "--processes", "1", "--quiet"])
    assert r.exit_code == 0, r.output
    assert "2 corners x 1 frames" in r.output and "hidden person in" in r.output
    assert re.search(r"\((\d+) standing still, (\d+) walking;", r.output)
    assert corpus.CREATED_BY in open_dataset(out).meta["created_by"]


@pytest.mark.slow
def test_raw_sample_corpus_beamforms_as_ingest_and_keeps_the_ground_truth(small, tmp_path):
    """``--radar-output iq``: the same corners recorded as raw samples and beamformed as ingest does
    (issue 51 point 5): the ground truth is the direct corpus's to the bit, the beamformed heatmap's
    strongest return sits at the GT bounce-1 range as the direct one's does, the beamformer's settings
    are recorded, and the corpus refuses to be finished as direct heatmaps."""
    url, _ = small
    iq = str(tmp_path / "iq.zarr")
    cfg = CorpusConfig(corners=2, radar_output="iq", radar_chirps=128, **SMALL)
    synth_corpus(iq, cfg, processes=1, quiet=True)
    assert validate_dataset(iq, quiet=True)["ok"]
    direct, raw = open_dataset(url), open_dataset(iq)
    dr = raw.range_bins.dr
    k0 = int(0.25 / dr)
    for sid in raw.scenes:
        a, b = raw.scene(sid), direct.scene(sid)
        np.testing.assert_array_equal(np.asarray(a[GT_RANGE][...]), np.asarray(b[GT_RANGE][...]))
        assert a.attrs["beamform"]["params"]["focus"] == "near" and "beamform" not in b.attrs
        hm = np.asarray(a[RADAR_HEATMAP][...], np.float32)
        peak = (hm[:, k0:].argmax(axis=1) + k0 + 0.5) * dr
        r1 = np.asarray(a[GT_RANGE][...])[:, 0]
        m = np.isfinite(r1)
        assert np.mean(np.abs(peak - r1)[m] <= 2 * dr) > 0.5
        assert not np.array_equal(hm, np.asarray(b[RADAR_HEATMAP][...], np.float32))
    with pytest.raises(InputError, match="radar_output iq \\(asked: heatmap\\)"):
        synth_corpus(iq, CorpusConfig(corners=2, **SMALL), processes=1, quiet=True)
