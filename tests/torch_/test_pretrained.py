"""The weights holodata ships (holodata.torch.pretrained), each grid's: loading them and scoring the
held-out check set gives the numbers recorded when benchmarks/nlos.py --install trained them; a dataset
of another grid, and an --init that does not exist, are one-line errors."""
import subprocess
import sys

import pytest

torch = pytest.importorskip("torch")

from holodata.conventions import Grid  # noqa: E402
from holodata.torch.pretrained import CHECK_SET, installed, scores  # noqa: E402
from holodata.torch.train import load_checkpoint  # noqa: E402

HOLODATA = [sys.executable, "-m", "holodata.cli.main"]
GRIDS = sorted(installed())


def test_the_quick_demo_grid_is_shipped():
    assert "32x128" in GRIDS


@pytest.mark.parametrize("grid", GRIDS)
def test_weights_record_how_they_were_made(grid):
    folder = installed()[grid]
    ck = load_checkpoint(folder)
    rec = ck["pretrained"]
    assert rec["command"].startswith("python benchmarks/nlos.py") and len(rec["commit"]) == 40
    assert rec["heldout_check"]["seed"] == CHECK_SET["seed"] != rec["train_corpus"]["seed"]
    trained = Grid.from_attrs(rec["train_corpus"]["grid"])
    assert f"{trained.H}x{trained.W}" == grid          # in the folder of the grid it was trained for
    assert "optimizer_state" not in ck
    for f in folder.iterdir():
        assert f.stat().st_size <= 25 * 10**6, f


@pytest.mark.slow
@pytest.mark.parametrize("grid", GRIDS)
def test_pretrained_scores_the_recorded_numbers_on_the_check_set(grid, tmp_path):
    from holodata.evaluate.motion import MotionCue
    from holodata.evaluate.pipeline import Evaluation
    from holodata.synth.corpus import CorpusConfig, synth_corpus

    rec = load_checkpoint(installed()[grid])["pretrained"]
    check = rec["heldout_check"]
    url = str(tmp_path / "check.zarr")
    synth_corpus(url, CorpusConfig(**{**CHECK_SET, "grid": Grid.from_attrs(check["grid"]),
                                      "heatmap_dtype": check.get("heatmap_dtype", "float16")}), quiet=True)
    cue = rec.get("motion_cue")   # (recorded before MotionCue.alone existed: the cue's centres joined the head's)
    got = scores(Evaluation(url, "pretrained", tmp_path / "eval", quiet=True, report=False,
                            motion=MotionCue(**{"alone": False, **cue}) if cue else None).run())
    want = rec["scores"]["check"]
    # the recorded scores are the float32 run's; weights stored as float16 (the paper grid's, to stay
    # small) move a score by a few tenths of a point
    half = any(t.dtype == torch.float16 for t in load_checkpoint(installed()[grid])["model_state"].values())
    tol = 5e-3 if half else 1e-3
    for method, row in want.items():
        for k, v in row.items():
            assert got[method][k] == pytest.approx(v, rel=tol, abs=tol), (method, k)
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
