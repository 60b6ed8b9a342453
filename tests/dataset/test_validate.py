"""holodata validate: a clean dataset passes; one corruption per rule fails with exit 1, a line
naming scene/array/frame and no traceback (through the real CLI)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.dataset import open_dataset
from holodata.dataset import shards as sh
from holodata.dataset.store import Store
from holodata.dataset.synthetic import write_toy_dataset

HOLODATA = Path(sys.executable).with_name("holodata")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    return write_toy_dataset(str(tmp_path_factory.mktemp("v") / "ds.zarr"), n_frames=8, shard_frames=4,
                             scenes=("c1", "c2"))


@pytest.fixture
def ds(pristine, tmp_path):
    dst = tmp_path / "ds.zarr"
    shutil.copytree(pristine, dst)
    return dst


def run(ds, *extra):
    r = CliRunner().invoke(cli, ["validate", str(ds), "--quiet", *extra])
    assert "Traceback" not in r.output
    return r


def shard_file(ds, scene, name, k):
    meta = json.loads((ds / f"scenes/{scene}/{name}/zarr.json").read_text())
    return ds / sh.shard_key(f"scenes/{scene}/{name}", k, len(meta["shape"]))


def rewrite_shard(ds, scene, name, k, fn):
    """Re-encode shard k with fn(data) and a matching manifest record: only value rules can catch it."""
    path = f"scenes/{scene}/{name}"
    meta = json.loads((ds / path / "zarr.json").read_text())
    rec = json.loads((ds / sh.manifest_key(path, k)).read_text())
    n = rec["frames"][1] - rec["frames"][0]
    data = sh.decode_shard(meta, n, shard_file(ds, scene, name, k).read_bytes()).copy()
    fn(data)
    blob = sh.encode_shard(meta, data)
    Store(str(ds)).put(sh.shard_key(path, k, data.ndim), blob)
    rec.update(sha256=sh.sha256(blob), nbytes=len(blob))
    Store(str(ds)).put(sh.manifest_key(path, k), json.dumps(rec).encode())
    hd = meta["attributes"]["holodata"]
    if "shards" in hd:
        hd["shards"][k].update(sha256=rec["sha256"], nbytes=len(blob))
        (ds / path / "zarr.json").write_text(json.dumps(meta))


def edit_json(path: Path, fn):
    d = json.loads(path.read_text())
    fn(d)
    path.write_text(json.dumps(d))


def test_clean_dataset_passes_and_json_report(ds):
    r = run(ds)
    assert r.exit_code == 0, r.output
    assert "ok" in r.output
    r = run(ds, "--json")
    rep = json.loads(r.output)
    assert rep["ok"] and rep["problems"] == [] and rep["shards_checked"] > 0 and rep["bytes_decoded"] > 0


def _nan_first_beam(d):
    d[1, 0, 0, 0] = 0.5
    d[1, 1, 0, 0] = np.nan


CASES = {
    # name: (corruption, expected words in the problem line, array named in the line)
    "flipped_bytes": (lambda ds: _flip(shard_file(ds, "c1", "gt/range", 1)), "sha256 mismatch", "c1 gt/range frame 4"),
    "truncated": (lambda ds: _truncate(shard_file(ds, "c1", "gt/point", 0)), "truncated", "c1 gt/point frame 0"),
    "deleted": (lambda ds: shard_file(ds, "c2", "radar/heatmap", 1).unlink(), "missing", "c2 radar/heatmap frame 4"),
    "dtype_in_metadata": (lambda ds: edit_json(ds / "scenes/c1/gt/range/zarr.json",
                                               lambda d: d.update(data_type="float64")), "dtype", "c1 gt/range"),
    "negative_range": (lambda ds: rewrite_shard(ds, "c1", "gt/range", 0, lambda d: d.__setitem__((2, 0, 3, 4), -1.0)),
                       "not finite >= 0", "c1 gt/range frame 2"),
    "inf_range": (lambda ds: rewrite_shard(ds, "c1", "gt/range", 1, lambda d: d.__setitem__((1, 0, 0, 0), np.inf)),
                  "not finite >= 0", "c1 gt/range frame 5"),
    "r2_before_r1": (lambda ds: rewrite_shard(ds, "c1", "gt/range", 1,
                                              lambda d: d.__setitem__((3, slice(None), 2, 2), [3.0, 2.0, np.nan])),
                     "R1 < R2 < R3", "c1 gt/range frame 7"),
    "label_without_range": (lambda ds: rewrite_shard(ds, "c2", "gt/label", 0, lambda d: _label_on_nan(ds, d)),
                            "label is set without a range", "c2 gt/label frame 0"),
    "label_out_of_range": (lambda ds: rewrite_shard(ds, "c1", "gt/label", 1, lambda d: d.__setitem__((0, 0, 0, 0), 7)),
                           "outside 0..4", "c1 gt/label frame 4"),
    "normal_not_unit": (lambda ds: rewrite_shard(ds, "c1", "gt/normal", 0, lambda d: _scale_normal(ds, d)),
                        "not unit length", "c1 gt/normal frame 1"),
    "timestamps_not_increasing": (lambda ds: rewrite_shard(ds, "c1", "time/timestamp_ns", 1,
                                                           lambda d: d.__setitem__(0, 0)),
                                  "not after the previous", "c1 time/timestamp_ns frame 4"),
    "pose_not_rigid": (lambda ds: rewrite_shard(ds, "c2", "pose/T_world_radar", 1,
                                                lambda d: d.__setitem__((2, 0, 0), 2.0)), "not rigid",
                       "c2 pose/T_world_radar frame 6"),
    "pose_nan": (lambda ds: rewrite_shard(ds, "c2", "pose/T_world_radar", 0,
                                          lambda d: d.__setitem__((3, 0, 3), np.nan)), "NaN", "c2 pose/T_world_radar frame 3"),
    "heatmap_negative": (lambda ds: rewrite_shard(ds, "c1", "radar/heatmap", 0, lambda d: d.__setitem__((1, 0, 0, 0), -1)),
                         "heatmap", "c1 radar/heatmap frame 1"),
    "ragged_offsets_decrease": (lambda ds: _offsets(ds, lambda o: o.__setitem__(3, o[2] - 1)), "offsets decrease",
                                "c1 lidar/points frame 2"),
    "ragged_offsets_end": (lambda ds: _resize_values(ds), "offsets end at", "c1 lidar/points"),
    "splits_unknown_scene": (lambda ds: edit_json(ds / "zarr.json", lambda d: d["attributes"]["holodata"]["splits"]
                                                  .__setitem__("test", ["c9"])), "'c9'", "(dataset)"),
    "scene_attrs_schema": (lambda ds: edit_json(ds / "scenes/c1/zarr.json",
                                                lambda d: d["attributes"].__setitem__("corner_type", "Z")),
                           "corner_type", "c1"),
    "root_attrs_schema": (lambda ds: edit_json(ds / "zarr.json", lambda d: d["attributes"]["holodata"].pop("created_by")),
                          "created_by", "(dataset)"),
    "half_written": (lambda ds: (ds / sh.manifest_key("scenes/c2/gt/normal", 1)).unlink(), "not written",
                     "c2 gt/normal frame 4"),
    "missing_array": (lambda ds: shutil.rmtree(ds / "scenes/c1/gt/label"), "missing while", "c1 gt/label"),
    "wrong_shape_for_grid": (lambda ds: edit_json(ds / "scenes/c1/zarr.json",
                                                  lambda d: d["attributes"].__setitem__("n_frames", 9)),
                             "expected (9,", "c1"),
    "dims_missing": (lambda ds: edit_json(ds / "scenes/c2/gt/point/zarr.json", lambda d: d["attributes"].pop("dims")),
                     "dims", "c2 gt/point"),
    "mesh_corrupt": (lambda ds: _flip(ds / "scenes/c1/mesh/vertices/c/0/0"), "", "c1 mesh/vertices"),
}


def _flip(p: Path):
    b = bytearray(p.read_bytes())
    for i in range(len(b) // 3, len(b) // 3 + 8):
        b[i] ^= 0xFF
    p.write_bytes(bytes(b))


def _truncate(p: Path):
    b = p.read_bytes()
    p.write_bytes(b[: len(b) // 2])


def _label_on_nan(ds, d):
    rng = np.asarray(open_dataset(str(ds)).scene("c2")["gt/range"][0:4])
    i = np.argwhere(np.isnan(rng[0]))[0]
    d[(0, *i)] = 1


def _scale_normal(ds, d):
    rng = np.asarray(open_dataset(str(ds)).scene("c1")["gt/range"][0:4])
    i = np.argwhere(np.isfinite(rng[1]))[0]
    d[(1, *i)] *= 1.01


def _offsets(ds, fn):
    a = zarr.open_array(str(ds / "scenes/c1/lidar/points/offsets"), mode="r+")
    o = a[...]
    fn(o)
    a[...] = o


def _resize_values(ds):
    a = zarr.open_array(str(ds / "scenes/c1/lidar/points/values"), mode="r+")
    a.resize((a.shape[0] + 5, 3))


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_corruption_is_detected(ds, case):
    corrupt, words, where = CASES[case]
    corrupt(ds)
    r = run(ds)
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith(where) and words in ln]
    assert lines, f"no line starting {where!r} containing {words!r} in:\n{r.output}"
    rep = json.loads(run(ds, "--json").output)
    assert not rep["ok"] and rep["n_problems"] >= 1


def test_problems_capped_per_rule_and_json_fields(ds):
    rewrite_shard(ds, "c1", "gt/range", 0, lambda d: d.__setitem__(slice(None), -1.0))
    rewrite_shard(ds, "c1", "gt/range", 1, lambda d: d.__setitem__(slice(None), -1.0))
    rep = json.loads(run(ds, "--json").output)
    neg = [p for p in rep["problems"] if p["rule"] == "range"]
    assert [p["frame"] for p in neg] == list(range(8))
    assert all(p["scene"] == "c1" and p["array"] == "gt/range" for p in neg)


def test_real_console_script_no_traceback(ds):
    _flip(shard_file(ds, "c1", "gt/label", 0))
    p = subprocess.run([str(HOLODATA), "validate", str(ds)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and "Traceback" not in p.stdout + p.stderr
    assert "c1 gt/label frame 0" in p.stdout


@pytest.mark.parametrize("kind", ["missing", "folder", "file", "zarr_not_holodata"])
def test_bad_paths_one_line_exit_1(tmp_path, kind):
    p = tmp_path / "x"
    if kind == "folder":
        p.mkdir()
        (p / "a.txt").write_text("hi")
    elif kind == "file":
        p.write_text("hi")
    elif kind == "zarr_not_holodata":
        zarr.open_group(str(p), mode="w")
    for cmd in ("validate", "info"):
        r = CliRunner().invoke(cli, [cmd, str(p)])
        assert r.exit_code == 1
        assert "Traceback" not in r.output
        lines = r.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and str(p) in lines[0], r.output


def test_large_shards_checked_in_frame_blocks(ds, monkeypatch):
    import holodata.dataset.validate as v

    monkeypatch.setattr(v, "BLOCK_BYTES", 1)  # every heatmap/point shard takes the frame-block path
    rewrite_shard(ds, "c2", "radar/heatmap", 1, lambda d: d.__setitem__((2, 3, 0, 0), np.nan))
    rep = v.validate_dataset(str(ds))
    assert [(p["array"], p["frame"], p["rule"]) for p in rep["problems"]] == [("radar/heatmap", 6, "heatmap")]
    assert rep["bytes_decoded"] > 0
