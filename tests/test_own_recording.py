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
    from holodata.synth import synthesize

    d = tmp_path_factory.mktemp("own")
    synthesize(d / "L", corner="L", frames=2, seed=5, grid=Grid(8, 32), lidar_shape=(8, 64), camera_shape=(24, 32),
               quiet=True, mapping_pass=True)
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
