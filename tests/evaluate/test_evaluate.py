import json
import os

import numpy as np
import pytest

pytest.importorskip("torch")

import _eval_dataset as E  # noqa: E402

from holodata.conventions import reduced_grid  # noqa: E402
from holodata.evaluate import Evaluation  # noqa: E402
from holodata.evaluate.pipeline import load_schema, validate_metrics  # noqa: E402
from holodata.torch import TrainConfig, train  # noqa: E402

TINY = dict(depth=3, base_channels=8, max_channels=16, blocks=1, batch_size=2, lr=3e-3)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return E.build(str(tmp_path_factory.mktemp("ds") / "tiny.zarr"))


def test_ground_truth_as_prediction_scores_perfectly(dataset, tmp_path):
    doc = Evaluation(dataset, None, tmp_path / "rep", oracle=True, report=False, quiet=True).run()
    validate_metrics(doc)
    m = doc["methods"]["model"]
    assert doc["scenes"] == ["room_c"] and doc["n_frames"] == 4
    for b in (1, 2, 3):
        r = m["range"][f"bounce_{b}"]
        assert r["n"] > 0 and r["mean_cm"] == 0 and r["p90_cm"] == 0 and r["psnr_db"] is None  # inf
        assert r["coverage"] == 1
    # GT clouds are the traced world points moved into the (yawed, moving) radar frame; the
    # prediction is GT ranges un-mirrored with GT normals: equal up to float32 rounding
    for part in ("los", "nlos"):
        p = m["points"][part]
        assert p["cd"] < 1e-4 and p["mhd"] < 1e-4 and p["f_score"] == 1 and p["n_frames"] == 4
        assert all(v == 1 for v in m["prf_curve"][part]["f_score"])
    h = m["human"]
    assert h["n_gt"] >= 4 and h["f_score"] == 1 and h["loc_mean_cm"] < 0.01
    # the baseline reads the same frames from heatmaps: first bounce within about a range bin
    assert 0 < doc["methods"]["baseline"]["range"]["bounce_1"]["mean_cm"] < 100 * E.BINS.dr
    assert doc["methods"]["baseline"]["human"]["n_pred"] == 0  # no human head
    bd = m["breakdown"]
    assert bd["shape"]["cross"]["n_frames"] == 4 and "wide" in bd["width"]
    assert json.loads((tmp_path / "rep" / "metrics.json").read_text()) == doc


@pytest.mark.slow
def test_train_then_evaluate_writes_valid_report(dataset, tmp_path):
    from click.testing import CliRunner

    from holodata.cli.main import cli

    run = tmp_path / "run"
    res = train(dataset, run, TrainConfig(epochs=12, **TINY), quiet=True)
    assert res.epochs == 12 and res.history[-1]["loss"] < res.history[0]["loss"]
    out = tmp_path / "report"
    r = CliRunner().invoke(cli, ["evaluate", dataset, "--checkpoint", str(run), "--out", str(out), "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    validate_metrics(doc)
    assert doc == json.loads((out / "metrics.json").read_text())
    assert doc["settings"]["train_epochs"] == 12
    html = (out / "report.html").read_text()
    assert {"range_images.png", "error_cdf.png", "bev_clouds.png", "prf_curves.png", "training_loss.png"} <= set(doc["figures"])
    for name in doc["figures"]:
        assert f'src="{name}"' in html
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for method in ("model", "baseline"):
        assert doc["methods"][method]["range"]["bounce_1"]["mean_cm"] is not None
    assert doc["settings"]["motion_cue"] is None
    # the motion cue (a corner's consecutive rotations) gives the model row's people (at most one a frame:
    # the strongest moving cluster) and leaves its points alone, and says so
    r = CliRunner().invoke(cli, ["evaluate", dataset, "--checkpoint", str(run), "--out", str(tmp_path / "motion"),
                                 "--motion-cue", "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    moved = json.loads(r.output)
    validate_metrics(moved)
    assert moved["settings"]["motion_cue"]["min_change_db"] > 0
    assert moved["settings"]["motion_cue"]["alone"] is True
    assert moved["methods"]["model"]["human"]["n_pred"] <= moved["n_frames"]
    assert moved["methods"]["model"]["points"] == doc["methods"]["model"]["points"]
    # a bad checkpoint is a one-line error, exit 1
    bad = tmp_path / "bad.pt"
    bad.write_text("not a checkpoint")
    r = CliRunner().invoke(cli, ["evaluate", dataset, "--checkpoint", str(bad), "--out", str(out)])
    assert r.exit_code == 1 and "not a holodata checkpoint" in r.output


def test_train_cli_resumes(dataset, tmp_path):
    from click.testing import CliRunner

    from holodata.cli.main import cli

    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("depth: 2\nbase_channels: 4\nmax_channels: 8\nblocks: 1\nbatch_size: 4\n")
    args = ["train", dataset, "--out", str(tmp_path / "run"), "--config", str(cfg), "--stage", "1", "--quiet", "--json"]
    r1 = CliRunner().invoke(cli, args + ["--epochs", "1"])
    assert r1.exit_code == 0, r1.output
    r2 = CliRunner().invoke(cli, args + ["--epochs", "2"])
    assert r2.exit_code == 0, r2.output
    s = json.loads(r2.output)
    assert s["epochs"] == 2 and s["resumed_from"] == 1
    lines = (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["epoch"] for x in lines] == [1, 2]
    r = CliRunner().invoke(cli, ["train", dataset, "--out", str(tmp_path / "x"), "--stage", "1", "--device", "cuda"])
    import torch

    if not torch.cuda.is_available():
        assert r.exit_code == 1 and "cuda" in r.output


def test_schema_and_reduced_grid():
    s = load_schema()
    assert s["properties"]["format"]["const"] == "holodata-metrics-1"
    g = reduced_grid(E.GRID, 2)
    assert (g.H, g.W) == (8, 32)
    np.testing.assert_allclose(g.elevations(), E.GRID.elevations()[::2])
    np.testing.assert_allclose(g.azimuths(), E.GRID.azimuths()[::2])


@pytest.mark.browser
def test_report_loads_in_headless_chromium(dataset, tmp_path):
    from holodata.evaluate.report import check_in_browser, find_chromium, screenshot

    if find_chromium() is None:
        if os.environ.get("CI"):   # scripts/setup.sh installs it: in CI this test runs, never skips
            pytest.fail("headless Chromium missing in CI (scripts/setup.sh installs chromium-headless-shell)")
        pytest.skip("headless Chromium not installed (Debian package `chromium-headless-shell`)")
    out = tmp_path / "rep"
    Evaluation(dataset, None, out, oracle=True, quiet=True).run()
    res = check_in_browser(out / "report.html")
    assert res["images_ok"] and res["console_errors"] == []
    png = screenshot(out / "report.html", out / "report.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_person_hidden_and_the_human_hidden_row():
    """A frame's person is hidden when its GT holds human returns and none is LOS; ``human_hidden``
    scores detection on those frames only."""
    from holodata.conventions import Label
    from holodata.evaluate.pipeline import _Acc, person_hidden, summarise

    lab = np.full((3, 4, 8), Label.LOS_STRUCTURE, np.uint8)
    assert not person_hidden(lab)                       # nobody
    lab[1, 1, 2] = Label.NLOS_HUMAN
    assert person_hidden(lab)                           # seen only through a bounce
    lab[0, 2, 3] = Label.LOS_HUMAN
    assert not person_hidden(lab)                       # also in sight

    acc = _Acc()
    person = np.array([[2.0, 1.0, 0.0]])
    acc.pred_centres = [person, np.zeros((0, 3)), person]           # found in frames 0 and 2
    gt = [person, person, person]
    s = summarise(acc, gt, {}, 10.0, hidden=[False, True, True])
    assert s["human"]["tp"] == 2 and s["human"]["n_gt"] == 3
    assert s["human_hidden"]["n_gt"] == 2 and s["human_hidden"]["tp"] == 1
    assert s["human_hidden"]["recall"] == pytest.approx(0.5) and s["human_hidden"]["precision"] == 1.0
