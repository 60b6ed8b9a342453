"""Loading files from elsewhere (issue 43 point 6): datasets, checkpoints and recordings come from other
labs. No load path runs code from a file (torch checkpoints load with ``weights_only=True``, ``.npy`` /
``.npz`` without pickles, YAML safe-loaded), no scene id or archive member writes outside the output,
and each refusal is one line through the CLI (exit 1).

Every crafted file here would, if it were unpickled or unsafe-loaded, create ``MARKER`` (its pickle
calls ``open(MARKER, "w")``; the YAML tag ``!!python/object/apply:builtins.open`` does the same): each
test asserts the refusal and that the marker was never created.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.errors import DatasetError, InputError


class Opens:
    """Pickles as ``open(path, "w")``: unpickling it creates ``path`` (what a hostile file would do)."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def refused(r, *words: str) -> str:
    """The CLI result is exit 1 with one line of output holding ``words``; returns that line."""
    lines = r.output.strip().splitlines()
    assert r.exit_code == 1 and len(lines) == 1, (r.exit_code, r.output)
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


# ------------------------------------------------------------------------------------ checkpoints
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny dataset and a real stage-one + stage-two run on it: (dataset url, run dir)."""
    torch = pytest.importorskip("torch")
    import _eval_dataset as E

    from holodata.torch import TrainConfig, train
    from holodata.torch.stage2_train import Stage2Config, fit_stage2, load_frames
    from holodata.torch.train import RunOptions

    torch.set_num_threads(1)
    d = tmp_path_factory.mktemp("safe_ck")
    ds = E.build(str(d / "tiny.zarr"), frames=2)
    train(ds, d / "run", TrainConfig(epochs=1, depth=2, base_channels=4, max_channels=4, blocks=1), quiet=True)
    frames, grid = load_frames(ds, "train", 1)
    fit_stage2(frames, d / "run", Stage2Config(epochs_rt=1, epochs_refine=1, channels=8, res_blocks=1, fusion_blocks=1,
                                              refine_channels=[8, 8], batch_size=2, p_stage1=0.0, p_clean=1.0,
                                              flip=False), 9.6, grid, RunOptions(quiet=True))
    return ds, d / "run"


def evil_checkpoint(path: Path, marker: Path, **plain) -> Path:
    import torch

    torch.save({"format": "holodata-checkpoint-1", **plain, "meta": {"note": Opens(marker)}}, path)
    return path


def test_the_checkpoints_holodata_writes_and_ships_load_as_weights_only(run):
    from holodata.torch import load_checkpoint, load_stage2
    from holodata.torch.pretrained import WEIGHTS

    _, rundir = run
    ck = load_checkpoint(rundir)   # with optimiser state, RNG state and history
    assert ck["epoch"] == 1 and "optimizer_state" in ck and "model_state" in ck
    s2, ck2 = load_stage2(rundir)
    assert ck2["epoch"] == 2 and s2.refiner is not None
    if (WEIGHTS / "checkpoint.pt").exists():
        assert load_checkpoint(WEIGHTS)["pretrained"]
        assert load_stage2(WEIGHTS)[1]["pretrained"]


CHECKPOINT_CASES = {
    # how: (CLI args after the dataset, what the crafted file is)
    "evaluate --checkpoint FILE": (["evaluate", "{ds}", "--checkpoint", "{evil}", "--out", "{tmp}/rep"], "file"),
    "evaluate --checkpoint RUN": (["evaluate", "{ds}", "--checkpoint", "{tmp}/evilrun", "--out", "{tmp}/rep"],
                                  "run/checkpoint.pt"),
    "evaluate --checkpoint RUN (stage2.pt)": (["evaluate", "{ds}", "--checkpoint", "{tmp}/evilrun", "--out",
                                              "{tmp}/rep"], "run/stage2.pt"),
    "train --init FILE": (["train", "{ds}", "--out", "{tmp}/new", "--init", "{evil}"], "file"),
    "train --out RUN (resume)": (["train", "{ds}", "--out", "{tmp}/evilrun", "--stage", "1"], "run/checkpoint.pt"),
    "train --stage 2 --stage1 FILE": (["train", "{ds}", "--out", "{tmp}/new", "--stage", "2", "--stage1", "{evil}"],
                                      "file"),
    "train --stage 2 --out RUN (resume)": (["train", "{ds}", "--out", "{tmp}/evilrun", "--stage", "2",
                                           "--stage2-epochs", "1"], "run/stage2.pt"),
}


@pytest.mark.parametrize("how", list(CHECKPOINT_CASES))
def test_a_checkpoint_that_pickles_code_is_refused_in_one_line_and_never_runs(run, tmp_path, how):
    ds, rundir = run
    args, what = CHECKPOINT_CASES[how]
    marker = tmp_path / "MARKER"
    evil = evil_checkpoint(tmp_path / "evil.pt", marker)
    if what.startswith("run/"):
        shutil.copytree(rundir, tmp_path / "evilrun")
        evil_checkpoint(tmp_path / "evilrun" / what[len("run/"):], marker)
    argv = [a.format(ds=ds, evil=evil, tmp=tmp_path) for a in args]
    r = CliRunner().invoke(cli, argv)
    assert not marker.exists(), f"the checkpoint's pickle ran ({r.output.strip()})"
    refused(r, "refused", "pickles a Python object", "weights_only=True")


def test_load_checkpoint_api_refuses_a_pickle_and_a_non_checkpoint(tmp_path):
    pytest.importorskip("torch")
    from holodata.torch import load_checkpoint

    marker = tmp_path / "MARKER"
    with pytest.raises(InputError, match="refused"):
        load_checkpoint(evil_checkpoint(tmp_path / "evil.pt", marker))
    assert not marker.exists()
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a holodata checkpoint"):
        load_checkpoint(tmp_path / "junk.pt")


# ------------------------------------------------------------------------------------ npy / npz
def pickled_npy(path: Path, marker: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, np.array([Opens(marker)], dtype=object), allow_pickle=True)
    return path


def test_an_npy_folder_with_a_pickled_object_array_is_refused(tmp_path):
    marker = tmp_path / "MARKER"
    rec = tmp_path / "traj"
    pickled_npy(rec / "rf_npy" / "00000.npy", marker)
    r = CliRunner().invoke(cli, ["ingest", str(rec), "--out", str(tmp_path / "out.zarr"), "--quiet"])
    refused(r, "00000.npy", "allow_pickle=False")
    assert not marker.exists()


def test_a_panoradar_raw_folder_with_pickled_arrays_is_refused(tmp_path):
    marker = tmp_path / "MARKER"
    raw = tmp_path / "raw_static"
    pickled_npy(raw / "radar_data.npy", marker)
    np.savetxt(raw / "radar_ts.txt", np.arange(2, dtype=float))
    np.savez(raw / "data_params.npz", x=np.zeros(1))
    r = CliRunner().invoke(cli, ["ingest", str(raw), "--out", str(tmp_path / "a.zarr"), "--quiet"])
    refused(r, "radar_data.npy")
    # a valid radar_data.npy, but a pickle inside data_params.npz
    np.save(raw / "radar_data.npy", np.zeros((2, 4, 8), np.complex64))
    np.savez(raw / "data_params.npz", x=np.array([Opens(marker)], dtype=object))
    r = CliRunner().invoke(cli, ["ingest", str(raw), "--out", str(tmp_path / "b.zarr"), "--quiet"])
    refused(r, "data_params.npz", "allow_pickle=False")
    assert not marker.exists()


def test_an_npz_truth_file_with_a_pickle_is_refused(tmp_path):
    from holodata.synth.truth import read_lidar_instances

    marker = tmp_path / "MARKER"
    np.savez(tmp_path / "lidar_instances.npz", stamp_ns=np.array([Opens(marker)], dtype=object))
    with pytest.raises(InputError, match="allow_pickle=False"):
        read_lidar_instances(tmp_path / "lidar_instances.npz")
    assert not marker.exists()


# ------------------------------------------------------------------------------------ YAML
def evil_yaml(path: Path, marker: Path, key: str | None = None) -> Path:
    tag = f"!!python/object/apply:builtins.open [{json.dumps(str(marker))}, w]"
    path.write_text(f"{key}:\n  epochs: {tag}\n" if key else f"epochs: {tag}\n")
    return path


@pytest.mark.parametrize("how", ["train --config", "train --stage2-config", "ingest --topics", "slam --config"])
def test_a_yaml_file_with_a_python_tag_is_refused(tmp_path, how):
    marker = tmp_path / "MARKER"
    ds = tmp_path / "nope.zarr"
    if how == "train --config":
        argv = ["train", str(ds), "--out", str(tmp_path / "r"), "--config", str(evil_yaml(tmp_path / "c.yaml", marker))]
    elif how == "train --stage2-config":
        argv = ["train", str(ds), "--out", str(tmp_path / "r"), "--stage", "2", "--stage2-config",
                str(evil_yaml(tmp_path / "c.yaml", marker))]
    elif how == "ingest --topics":
        (tmp_path / "rec").mkdir()
        argv = ["ingest", str(tmp_path / "rec"), "--out", str(ds), "--topics", str(evil_yaml(tmp_path / "t.yaml", marker))]
    else:
        argv = ["slam", str(ds), "--config", str(evil_yaml(tmp_path / "s.yaml", marker, key="slam"))]
    r = CliRunner().invoke(cli, argv)
    refused(r, ".yaml")
    assert not marker.exists()


# ------------------------------------------------------------------------------------ scene ids
BAD_IDS = ["../evil", "..", ".", "a\\b", "..\\..\\evil", "{tmp}/abs_evil"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from holodata.conventions import Grid
    from holodata.synth import SynthSpec, synthesize

    d = tmp_path_factory.mktemp("safe_rec")
    synthesize(d / "L", SynthSpec(corner="L", frames=2, seed=5, grid=Grid(8, 32), lidar_shape=(8, 64), camera_shape=(24, 32),
                                  mapping_pass=False), quiet=True)
    return d / "L"


@pytest.mark.parametrize("sid", BAD_IDS)
def test_ingest_refuses_a_scene_id_that_is_not_one_name_and_writes_nothing(recording, tmp_path, sid):
    sid = sid.format(tmp=tmp_path)
    out = tmp_path / "deep" / "out" / "ds.zarr"
    out.parent.mkdir(parents=True)
    before = tree(tmp_path)
    r = CliRunner().invoke(cli, ["ingest", str(recording), "--out", str(out), "--scene-id", sid, "--quiet"])
    refused(r, "--scene-id", "refused")
    assert tree(tmp_path) == before     # not even the output was created


@pytest.mark.parametrize("sid", BAD_IDS)
def test_raytrace_gt_refuses_a_scene_id_that_is_not_one_name_and_writes_nothing(tmp_path, sid):
    from holodata.meshio import Mesh, write_ply
    from holodata.trajectory import Trajectory, write_tum

    sid = sid.format(tmp=tmp_path)
    V = np.array([[x, y, z] for x in (-3, 3) for y in (-3, 3) for z in (-1, 2)], float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    write_ply(tmp_path / "box.ply", Mesh(V, F))
    write_tum(tmp_path / "p.tum", Trajectory(np.array([10**9, 2 * 10**9]), np.stack([np.eye(4)] * 2)))
    out = tmp_path / "deep" / "out" / "gt.zarr"
    out.parent.mkdir(parents=True)
    before = tree(tmp_path)
    r = CliRunner().invoke(cli, ["raytrace-gt", "--mesh", str(tmp_path / "box.ply"), "--poses", str(tmp_path / "p.tum"),
                                 "--out", str(out), "--scene-id", sid, "--grid", "4x16", "--processes", "1", "--quiet"])
    refused(r, "--scene-id", "refused")
    assert tree(tmp_path) == before


@pytest.mark.parametrize("fmt", ["panoradar", "hdf5"])
@pytest.mark.parametrize("sid", ["..", "."])
def test_export_refuses_a_dataset_whose_split_names_a_scene_outside_it(tmp_path, fmt, sid):
    import _eval_dataset as E

    url = E.build(str(tmp_path / "ds.zarr"), frames=2)
    meta = json.loads((tmp_path / "ds.zarr" / "zarr.json").read_text())
    meta["attributes"]["holodata"]["splits"]["test"] = [sid]
    (tmp_path / "ds.zarr" / "zarr.json").write_text(json.dumps(meta))
    out = tmp_path / "deep" / "out"
    out.parent.mkdir(parents=True)
    before = tree(tmp_path)
    r = CliRunner().invoke(cli, ["export", url, "--format", fmt, "--split", "test", "--out", str(out), "--quiet"])
    refused(r, "scene id", "refused")
    assert {p for p in tree(tmp_path) - before if not p.startswith("deep/out")} == set()
    assert not out.exists() or not any(out.iterdir())


def test_the_python_api_refuses_nul_and_separators_in_scene_ids(recording, tmp_path):
    import holodata.dataset as hds
    from holodata.ingest import ingest

    with pytest.raises(InputError, match="NUL"):
        ingest([recording], tmp_path / "a.zarr", scene_ids=["a\0b"])
    with pytest.raises(InputError, match="separator"):
        ingest([recording], tmp_path / "a.zarr", scene_ids=["a\\b"])
    assert not (tmp_path / "a.zarr").exists()
    ingest([recording], tmp_path / "ok.zarr", scene_ids=["ok"], quiet=True)
    ds = hds.open_dataset(tmp_path / "ok.zarr")
    for bad in ("..", ".", "a\\b", "ok/../ok"):
        with pytest.raises(DatasetError, match="refused"):
            ds.scene(bad)
    assert ds.scene("ok").id == "ok"


# ------------------------------------------------------------------------------------ archive members
def test_a_rosbag2_metadata_member_never_names_a_file_outside_its_folder(tmp_path):
    """holodata extracts no archives; the one member list it follows is a rosbag2 folder's
    ``metadata.yaml`` ``relative_file_paths``: a member ``..`` (the folder above) is not followed."""
    from holodata.readers.rosbag import _storage_files

    bag = tmp_path / "outer" / "bag"
    bag.mkdir(parents=True)
    (bag / "bag_0.db3").write_bytes(b"")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  relative_file_paths: ['..', '../bag_0.db3']\n")
    files = _storage_files(bag)
    assert files and all(f.resolve().parent == bag.resolve() for f in files), files
