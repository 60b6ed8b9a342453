"""holodata demo: the whole pipeline on tiny synthetic corners (oracle mapping), and a rerun that
resumes instead of redoing work."""
from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.conventions import Grid
from holodata.dataset import open_dataset, validate_dataset
from holodata.demo import (
    DemoConfig,
    combined_metrics,
    demo_config,
    map_scene_id,
    remove_ingested_recordings,
    resolve_mapping,
    run_demo,
)
from holodata.errors import InputError
from holodata.evaluate.pipeline import STAGE2_ROWS

pytest.importorskip("torch")

TINY = DemoConfig(corners=(("L", 1), ("T", 2), ("oblique", 3)), n_test=1, frames=3, grid=Grid(8, 32),
                  lidar_shape=(16, 128), camera_shape=(24, 32), epochs=1, depth=3, base_channels=4,
                  max_channels=8, stage2=dict(epochs_rt=1, epochs_refine=1, channels=8, res_blocks=1, fusion_blocks=1,
                                              refine_channels=[8, 8], batch_size=2))


@pytest.mark.slow
def test_demo_runs_every_stage_and_resumes(tmp_path):
    lines = []
    res = run_demo(tmp_path / "demo", mapping="truth", quiet=True, config=TINY, log=lines.append)
    assert [ln.split()[0] for ln in lines] == ["synth", "ingest", "mapping:truth", "raytrace-gt", "validate",
                                               "train", "train:stage2", "evaluate", "pretrained"]
    assert "grid" in lines[-1] and res.pretrained is None  # the shipped weights are for the quick demo's grid
    assert validate_dataset(str(res.dataset))["ok"]
    ds = open_dataset(str(res.dataset))
    assert ds.splits == {"train": ["L_1", "T_2"], "test": ["oblique_3"]}
    sc = ds.scene("oblique_3")
    assert sc.attrs["corner_type"] == "oblique" and 1.3 <= sc.attrs["width_m"] <= 4.7
    assert {"gt/range", "gt/label", "mesh/vertices", "human/vertices", "radar/heatmap"} <= set(sc.arrays())
    assert sc.attrs.get("class_names")
    assert res.report.is_file() and (res.report.parent / "metrics.json").is_file()
    assert set(res.metrics["methods"]) == set(STAGE2_ROWS)  # both stages trained: every Table-2 row
    assert json.loads((res.out_dir / "demo.json").read_text())["test"] == ["oblique_3"]
    # the ingested recordings are gone (synth's, proven by its manifest), their truth stays
    for sid in ("L_1", "T_2", "oblique_3"):
        d = res.out_dir / "recordings" / sid
        assert not (d / "recording").exists() and not (d / "mapping").exists() and (d / "truth" / "scene.json").is_file()
    # a rerun takes the corners from the dataset, reuses its shards and the checkpoint
    again = run_demo(tmp_path / "demo", mapping="truth", quiet=True, config=TINY)
    assert again.timings["synth"] < 1.0
    assert again.metrics["methods"]["model"]["range"] == res.metrics["methods"]["model"]["range"]
    # keep_recordings (--keep-recordings) keeps them; removing later takes only what synth wrote as it wrote it
    kept = run_demo(tmp_path / "kept", mapping="truth", quiet=True, config=TINY, keep_recordings=True)
    rec, ids = kept.out_dir / "recordings", ["L_1", "T_2", "oblique_3"]
    assert all((rec / s / "recording").is_dir() and (rec / s / "mapping").is_dir() for s in ids)
    (rec / "L_1" / "recording" / "notes.txt").write_text("mine")   # no longer the folder synth recorded
    outside = tmp_path / "users_own"                                  # a symlink leading out of the demo
    outside.mkdir()
    (outside / "data.bin").write_bytes(b"x")
    shutil.rmtree(rec / "oblique_3" / "mapping")
    (rec / "oblique_3" / "mapping").symlink_to(outside, target_is_directory=True)
    said: list[str] = []
    assert remove_ingested_recordings(rec, ids, {s: map_scene_id(s) for s in ids}, kept.dataset, said.append) > 0
    assert (rec / "L_1" / "recording" / "notes.txt").is_file() and not (rec / "L_1" / "mapping").exists()
    assert not (rec / "T_2" / "recording").exists() and (rec / "T_2" / "truth").is_dir()
    assert (rec / "oblique_3" / "mapping").is_symlink() and (outside / "data.bin").read_bytes() == b"x"
    assert sorted(ln.split(":")[0] for ln in said) == [f"kept {rec / 'L_1' / 'recording'}",
                                                       f"kept {rec / 'oblique_3' / 'mapping'}"]


def test_tables_lead_with_the_model_then_the_shipped_weights():
    row = {"range": {}, "points": {}}
    doc = {"methods": {m: dict(row, name=m) for m in STAGE2_ROWS}}
    pre = {"methods": {m: dict(row, name="pre_" + m) for m in STAGE2_ROWS}}
    both = combined_metrics(doc, pre)["methods"]
    assert list(both) == ["model", "model_no_refine", "model_analytic", "pretrained", "pretr_no_refine",
                          "pretr_analytic", "baseline", "oracle_stage1"]
    assert both["pretrained"]["name"] == "pre_model" and both["baseline"]["name"] == "baseline"
    assert all(len(m) <= 15 for m in both)   # format_tables' row-name column
    assert combined_metrics(doc, None) is doc


def test_quick_config_is_small_and_full_config_is_paper_size():
    q, full = demo_config(True), demo_config(False)
    assert q.grid.H * q.grid.W < full.grid.H * full.grid.W
    assert (full.grid.H, full.grid.W) == (64, 512)
    assert {c for c, _ in full.corners} == {"T", "L", "cross", "oblique"}
    assert 0 < q.n_test < len(q.corners)


def test_unknown_mapping_is_an_input_error():
    with pytest.raises(InputError):
        resolve_mapping("magic")


def test_cli_help_and_bad_flag():
    r = CliRunner().invoke(cli, ["demo", "--help"])
    assert r.exit_code == 0 and "--quick" in r.output
    r = CliRunner().invoke(cli, ["demo", "--mapping", "magic"])
    assert r.exit_code == 2
