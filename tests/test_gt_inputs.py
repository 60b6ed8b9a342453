"""Issue 55 point 3: ground truth records what it was traced from (scene attrs gt.inputs) and is traced
again when that changed — a person registered after the first trace ends up in the GT."""
from __future__ import annotations

import _eval_dataset as E
import numpy as np
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.conventions import Grid, Label
from holodata.dataset import create_dataset, open_dataset
from holodata.dataset.layout import (
    GT_HUMAN_CENTER,
    GT_LABEL,
    HUMAN_FACES,
    HUMAN_VERTICES,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_RADAR,
    TIME_TIMESTAMP_NS,
)


def _room(url, frames=2):
    w = create_dataset(url, grid=Grid(8, 32))
    sc = w.scene("room", n_frames=frames, attrs={"frame_sensor": "radar"})
    a = sc.frame_array(TIME_TIMESTAMP_NS, dtype="int64")
    a.write_shard(0, (np.arange(frames) * 500_000_000 + 1).astype(np.int64))
    p = sc.frame_array(POSE_T_WORLD_RADAR, (4, 4), dtype="float64")
    p.write_shard(0, np.repeat(np.eye(4)[None], frames, 0))
    V, F = E.box((-3, -3, -1), (3, 3, 2))
    sc.write_array(MESH_VERTICES, V.astype(np.float32))
    sc.write_array(MESH_FACES, F)
    return w, sc


def _add_person(sc, frames=2):
    V, F = E.box((1.0, -0.25, -0.9), (1.4, 0.25, 0.8))
    hv, hf = sc.ragged_array(HUMAN_VERTICES, 3), sc.ragged_array(HUMAN_FACES, 3, dtype="int32")
    hv.write_shard(0, [V.astype(np.float32)] * frames)
    hf.write_shard(0, [F.astype(np.int32)] * frames)


def test_gt_is_traced_again_when_a_person_is_registered_after_it(tmp_path):
    url = str(tmp_path / "ds.zarr")
    _, sc = _room(url)
    r = CliRunner().invoke(cli, ["raytrace-gt", url, "--scene", "room"])
    assert r.exit_code == 0, r.output
    s = open_dataset(url).scene("room")
    assert not np.isin(np.asarray(s[GT_LABEL][...]), (Label.LOS_HUMAN, Label.NLOS_HUMAN)).any()
    assert "human/vertices" in s.attrs["gt"]["inputs"] and s.attrs["gt"]["inputs"]["human/vertices"] is None
    _add_person(sc)          # what register writes
    r = CliRunner().invoke(cli, ["raytrace-gt", url, "--scene", "room"])
    assert r.exit_code == 0, r.output
    assert "traced again" in r.output and "human/vertices" in r.output
    s = open_dataset(url).scene("room")
    assert (np.asarray(s[GT_LABEL][...]) == Label.LOS_HUMAN).any()
    assert np.isfinite(np.asarray(s[GT_HUMAN_CENTER][...])).all()
    # unchanged inputs: the rerun resumes (nothing traced); --force traces again
    r = CliRunner().invoke(cli, ["raytrace-gt", url, "--scene", "room", "--json"])
    import json

    assert json.loads(r.output)["scenes"][0]["shards_written"] == 0
    r = CliRunner().invoke(cli, ["raytrace-gt", url, "--scene", "room", "--force", "--json"])
    assert json.loads(r.output)["scenes"][0]["shards_written"] == 1


def test_gt_is_traced_again_when_the_mesh_changes(tmp_path):
    url = str(tmp_path / "ds.zarr")
    _, sc = _room(url)
    from holodata.groundtruth import raytrace_dataset

    raytrace_dataset(url, ["room"])
    V, F = E.box((-2, -2, -1), (2, 2, 2))     # a re-built mesh
    sc.write_array(MESH_VERTICES, V.astype(np.float32))
    sc.write_array(MESH_FACES, F)
    out = raytrace_dataset(url, ["room"])["scenes"][0]
    assert MESH_VERTICES in out["retraced"]
    r = np.asarray(open_dataset(url).scene("room")["gt/range"][0, 0])
    assert np.nanmax(r) < 4.0     # the 2 m room, not the 3 m one


def test_validate_names_stale_gt_and_bad_splits(tmp_path):
    """GT traced before the person was registered fails validate until raytrace-gt reruns; a mapping
    pass in a split and a scene in both splits are problems."""
    from holodata.dataset import validate_dataset
    from holodata.groundtruth import raytrace_dataset

    url = str(tmp_path / "ds.zarr")
    w, sc = _room(url)
    raytrace_dataset(url, ["room"])
    assert validate_dataset(url)["ok"]
    _add_person(sc)
    lines = [p["line"] for p in validate_dataset(url)["problems"]]
    assert any("other inputs" in ln and "human/vertices" in ln and "raytrace-gt" in ln for ln in lines), lines
    raytrace_dataset(url, ["room"])
    assert validate_dataset(url)["ok"], validate_dataset(url)["problems"]
    m = w.scene("room_map", n_frames=1, attrs={"frame_sensor": "lidar", "role": "mapping"})
    m.frame_array(TIME_TIMESTAMP_NS, dtype="int64").write_shard(0, np.ones(1, np.int64))
    w.set_splits(train=["room", "room_map"], test=["room"])
    lines = [p["line"] for p in validate_dataset(url)["problems"]]
    assert any("mapping pass 'room_map'" in ln for ln in lines), lines
