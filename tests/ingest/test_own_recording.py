"""Issue 55 points 2, 4, 5 and 7: scenes know their role (data pass / mapping pass), splits are set
explicitly and hold data passes only, a missing or empty split or train/test leakage is one line,
synth output folders ingest as both passes with matching ids, train --epochs bounds both stages."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.conventions import Grid
from holodata.dataset import create_dataset, open_dataset


def _one_line(r, code, *words):
    assert r.exit_code == code, r.output
    assert "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1, r.output
    for w in words:
        assert w in r.output, (w, r.output)


@pytest.fixture(scope="module")
def two_passes(tmp_path_factory):
    """A synth output folder with its mapping pass, ingested by giving the folder itself."""
    from holodata.ingest import ingest
    from holodata.synth import SynthSpec, synthesize

    d = tmp_path_factory.mktemp("own")
    synthesize(d / "L", SynthSpec(corner="L", frames=2, seed=5, grid=Grid(8, 32), lidar_shape=(8, 64), camera_shape=(24, 32),
                                  mapping_pass=True), quiet=True)
    url = str(d / "ds.zarr")
    r = ingest([d / "L"], url)
    return d, url, r


def test_a_synth_folder_ingests_as_its_data_and_mapping_pass_with_roles(two_passes, tmp_path):
    d, url, r = two_passes
    ds = open_dataset(url)
    assert ds.scenes == ["L", "L_map"]
    assert ds.scene("L").attrs["role"] == "data" and ds.scene("L_map").attrs["role"] == "mapping"
    # the passes named one by one get the same ids; --scene-id per folder names both
    from holodata.ingest.plan import _scene_id

    assert _scene_id(d / "L" / "recording") == "L" and _scene_id(d / "L" / "mapping") == "L_map"
    from holodata.ingest import _passes

    recs, ids = _passes([d / "L"], ["corner"])
    assert [p.name for p in recs] == ["recording", "mapping"] and ids == ["corner", "corner_map"]


def test_splits_are_explicit_and_hold_data_passes_only(two_passes, tmp_path):
    _, url, _ = two_passes
    r = CliRunner().invoke(cli, ["train", url, "--out", str(tmp_path / "run"), "--epochs", "1"])
    _one_line(r, 1, "split 'train'", "holodata split")
    r = CliRunner().invoke(cli, ["split", url, "--test", "L_map"])
    _one_line(r, 1, "'L_map' is a mapping pass")
    r = CliRunner().invoke(cli, ["split", url, "--test", "L"])
    _one_line(r, 1, "train split would be empty")
    r = CliRunner().invoke(cli, ["split", url, "--test", "nope"])
    _one_line(r, 1, "no scene 'nope'")
    r = CliRunner().invoke(cli, ["split", url])
    assert r.exit_code == 2


def test_train_refuses_an_empty_train_split_and_leakage(tmp_path):
    """``synth --corners 2 --test 2`` left an empty train split: train trained on a test scene."""
    import _eval_dataset as E

    url = str(tmp_path / "d.zarr")
    E.build(url, frames=2)
    w = create_dataset(url)
    w.set_splits(train=[], test=["room_a", "room_b", "room_c"])
    r = CliRunner().invoke(cli, ["train", url, "--out", str(tmp_path / "r1"), "--epochs", "1", "--quiet"])
    _one_line(r, 1, "split 'train' is empty")
    w.set_splits(train=["room_a", "room_b"], test=["room_b", "room_c"])
    r = CliRunner().invoke(cli, ["train", url, "--out", str(tmp_path / "r2"), "--epochs", "1", "--quiet"])
    _one_line(r, 1, "'room_b'", "leakage")
    r = CliRunner().invoke(cli, ["split", url, "--test", "room_c", "--json"])
    assert r.exit_code == 0 and json.loads(r.output) == {"train": ["room_a", "room_b"], "test": ["room_c"]}


def test_train_epochs_bound_both_stages_and_a_rerun_says_nothing_was_trained(tmp_path):
    pytest.importorskip("torch")
    import _eval_dataset as E

    url = str(tmp_path / "d.zarr")
    E.build(url, frames=2)
    run = str(tmp_path / "run")
    r = CliRunner().invoke(cli, ["train", url, "--out", run, "--epochs", "1", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output[r.output.index("{"):])
    assert s["epochs"] == 1 and s["stage2"]["epochs"] == 2      # one ray-tracer and one refiner epoch
    r = CliRunner().invoke(cli, ["train", url, "--out", run, "--epochs", "1"])
    assert r.exit_code == 0, r.output
    assert "stage one: nothing to train" in r.output and "stage two: nothing to train" in r.output
    assert "trained 1 epoch" not in r.output


def test_errors_a_user_meets_are_one_clear_line(tmp_path):
    """Issue 55 point 9: view --save DIR/ and --frames 3-5 are usage errors (exit 2); a checkpoint of
    another grid is named in words (no Python dicts, no install path)."""
    import _eval_dataset as E

    url = str(tmp_path / "d.zarr")
    E.build(url, frames=2)
    (tmp_path / "views").mkdir()
    for args, words in ((["--save", str(tmp_path / "new") + "/"], "is a folder"),
                        (["--save", str(tmp_path / "views")], "is a directory"),
                        (["--save", str(tmp_path / "v.rrd"), "--frames", "3-5"], "give A:B")):
        r = CliRunner().invoke(cli, ["view", url] + args)
        assert r.exit_code == 2 and words in r.output and "Traceback" not in r.output, r.output
    pytest.importorskip("torch")
    r = CliRunner().invoke(cli, ["evaluate", url, "--checkpoint", "pretrained", "--out", str(tmp_path / "rep"),
                                 "--split", "all", "--quiet"])
    _one_line(r, 1, "holodata ships no pretrained weights for the 16x64 beam grid", "it has 32x128")
    assert "{" not in r.output and "site-packages" not in r.output


def test_an_undefined_human_score_is_explained():
    from holodata.evaluate.report import format_tables

    rng = {f"bounce_{b}": {"mean_cm": 1.0, "median_cm": 1.0, "p90_cm": 1.0} for b in (1, 2, 3)}
    cloud = {"cd": 0.1, "mhd": 0.1, "f_score": 0.5}
    doc = {"split": "test", "n_frames": 2, "scenes": ["a"], "settings": {},
           "methods": {"model": {"range": rng, "points": {"los": cloud, "nlos": cloud},
                                 "human": {"f_score": None, "n_gt": 0}}}}
    text = format_tables(doc)
    assert "human F –: no frame of the split holds a person" in text
