"""The weights holodata ships (holodata.torch.pretrained): loading them and scoring the held-out
check set gives the numbers recorded when benchmarks/nlos.py --install trained them; a dataset of another
grid, and an --init that does not exist, are one-line errors."""
import subprocess
import sys

import pytest

torch = pytest.importorskip("torch")

from holodata.torch.pretrained import CHECK_SET, WEIGHTS, scores  # noqa: E402
from holodata.torch.train import load_checkpoint  # noqa: E402

HOLODATA = [sys.executable, "-m", "holodata.cli.main"]


def test_weights_record_how_they_were_made():
    ck = load_checkpoint(WEIGHTS)
    rec = ck["pretrained"]
    assert rec["command"].startswith("python benchmarks/nlos.py") and len(rec["commit"]) == 40
    assert rec["heldout_check"]["seed"] == CHECK_SET["seed"] != rec["train_corpus"]["seed"]
    assert "optimizer_state" not in ck
    assert sum(p.stat().st_size for p in WEIGHTS.iterdir()) <= 20 * 2**20


@pytest.mark.slow
def test_pretrained_scores_the_recorded_numbers_on_the_check_set(tmp_path):
    from holodata.evaluate.pipeline import Evaluation
    from holodata.synth.corpus import CorpusConfig, synth_corpus

    rec = load_checkpoint(WEIGHTS)["pretrained"]
    url = str(tmp_path / "check.zarr")
    synth_corpus(url, CorpusConfig(**CHECK_SET), quiet=True)
    got = scores(Evaluation(url, "pretrained", tmp_path / "eval", quiet=True, report=False).run())
    want = rec["scores"]["check"]
    for method, row in want.items():
        for k, v in row.items():
            assert got[method][k] == pytest.approx(v, rel=1e-3, abs=1e-3), (method, k)
    # what the weights are for: the hidden side, better than the strongest-peaks baseline
    assert got["model"]["nlos_f"] > got["baseline"]["nlos_f"]


@pytest.mark.slow
def test_wrong_grid_and_missing_init_are_one_line_errors(tmp_path):
    url = tmp_path / "small.zarr"
    r = subprocess.run(HOLODATA + ["synth", "--corners", "1", "--frames", "1", "--grid", "16x64", "--test", "1",
                                   "--out", str(url), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(HOLODATA + ["evaluate", str(url), "--checkpoint", "pretrained", "--out", str(tmp_path / "ev"),
                                   "--quiet"], capture_output=True, text=True)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "grid" in r.stderr
    r = subprocess.run(HOLODATA + ["train", str(url), "--out", str(tmp_path / "run"), "--init",
                                   str(tmp_path / "nope"), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "nope" in r.stderr
