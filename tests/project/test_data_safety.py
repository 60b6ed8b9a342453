"""Issue 50, points 2, 3, 4 and 8: holodata deletes or replaces only what it can prove it wrote
(holodata.ownership's manifest, a dataset's own Zarr nodes, the creating writer's token), never follows
a symlink out of a dataset or an output folder, and refuses everything else in one line, exit 1."""
from __future__ import annotations

import json
import os

import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.errors import DatasetError, InputError


@pytest.fixture(scope="module")
def traced(tmp_path_factory):
    import _eval_dataset as E

    url = str(tmp_path_factory.mktemp("safety") / "traced.zarr")
    E.build(url, frames=2)
    return url


def _refused(r, *words):
    """A CLI result that is a one-line refusal (exit 1, no traceback) naming ``words``."""
    err = r.output.strip()
    assert r.exit_code == 1, r.output
    assert "Traceback" not in r.output and len(err.splitlines()) == 1, r.output
    for w in words:
        assert w in err, (w, err)


def _user_folder(path, name="notes.txt", text="mine"):
    path.mkdir(parents=True, exist_ok=True)
    (path / name).write_text(text)
    return path / name


# -- point 2: export -------------------------------------------------------------------------------
def test_export_keeps_a_user_folder_that_shares_a_scene_name(traced, tmp_path):
    out = tmp_path / "pr"
    mine = _user_folder(out / "room_a")
    r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out), "--scene", "room_a"])
    _refused(r, str(out / "room_a"), "not written by holodata", "--force")
    assert mine.read_text() == "mine"
    # an export holodata wrote is replaced by the next export; the user's folder only with --force
    r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out), "--scene", "room_b"])
    assert r.exit_code == 0, r.output
    first = (out / "room_b" / "holodata.json").stat().st_ino
    r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out), "--scene", "room_b"])
    assert r.exit_code == 0, r.output
    assert (out / "room_b" / "holodata.json").stat().st_ino != first
    r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out), "--scene", "room_a",
                                 "--force"])
    assert r.exit_code == 0 and not mine.exists() and (out / "room_a" / "rf_npy").is_dir(), r.output
    assert not [p for p in os.listdir(out) if p.endswith(".partial")]


def test_export_replaces_a_folder_only_while_it_is_what_holodata_wrote(traced, tmp_path):
    out = tmp_path / "pr"
    assert CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out),
                                    "--scene", "room_a"]).exit_code == 0
    import shutil

    shutil.rmtree(out / "room_a")          # the user deletes the export and makes a folder of their own
    mine = _user_folder(out / "room_a")
    r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out), "--scene", "room_a"])
    _refused(r, "not written by holodata")
    assert mine.read_text() == "mine"


def test_export_hdf5_keeps_a_user_file_and_partial_names_of_other_scenes(traced, tmp_path):
    out = tmp_path / "h5"
    out.mkdir()
    (out / "room_a.h5").write_text("my own file")
    other = _user_folder(out / "room_b.partial")   # e.g. the export of a scene named 'room_b.partial'
    r = CliRunner().invoke(cli, ["export", traced, "--format", "hdf5", "--out", str(out)])
    _refused(r, str(out / "room_a.h5"))
    assert (out / "room_a.h5").read_text() == "my own file"
    r = CliRunner().invoke(cli, ["export", traced, "--format", "hdf5", "--out", str(out), "--scene", "room_b"])
    assert r.exit_code == 0, r.output
    assert other.read_text() == "mine" and (out / "room_b.h5").is_file()


def test_export_never_replaces_or_writes_through_a_symlink(traced, tmp_path):
    target = tmp_path / "elsewhere"
    mine = _user_folder(target)
    out = tmp_path / "pr"
    out.mkdir()
    (out / "room_a").symlink_to(target)
    for extra in ([], ["--force"]):
        r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(out), "--scene",
                                     "room_a"] + extra)
        _refused(r, "symlink")
    assert mine.read_text() == "mine" and (out / "room_a").is_symlink()


# -- point 3: synth --------------------------------------------------------------------------------
SMALL = dict(frames=2, grid=None, lidar_shape=(8, 64), camera_shape=(24, 32))


def _small():
    from holodata.conventions import Grid

    return {**SMALL, "grid": Grid(8, 32)}


def test_synth_leaves_a_user_mapping_folder_alone(tmp_path):
    from holodata.synth import SynthSpec, synthesize

    out = tmp_path / "s"
    mine = _user_folder(out / "mapping")
    res = synthesize(out, SynthSpec(corner="L", seed=1, mapping_pass=False, **_small()), quiet=True)
    assert mine.read_text() == "mine" and res.recording.exists()
    out2 = tmp_path / "s2"
    mine2 = _user_folder(out2 / "mapping")
    with pytest.raises(InputError, match="mapping.*not written by holodata"):
        synthesize(out2, SynthSpec(corner="L", seed=1, mapping_pass=True, **_small()), quiet=True)
    assert mine2.read_text() == "mine"
    assert not (out2 / "recording").exists()


def test_synth_replaces_its_own_outputs_with_force_and_a_user_truth_folder_never(tmp_path):
    from holodata.synth import SynthSpec, synthesize

    out = tmp_path / "s"
    synthesize(out, SynthSpec(corner="L", seed=1, mapping_pass=True, **_small()), quiet=True)
    again = synthesize(out, SynthSpec(corner="T", seed=2, mapping_pass=False, **_small()), quiet=True, force=True)
    assert json.loads(again.scene_json.read_text())["corner_type"] == "T"
    assert not (out / "mapping").exists()       # the earlier run's mapping pass (holodata's) went with it
    out2 = tmp_path / "u"
    mine = _user_folder(out2 / "truth")
    with pytest.raises(InputError, match="truth.*not written by holodata"):
        synthesize(out2, SynthSpec(corner="L", seed=1, mapping_pass=False, **_small()), quiet=True, force=True)
    assert mine.read_text() == "mine"


# -- point 4: symlinks and foreign folders inside a dataset -----------------------------------------
def _linked_dataset(tmp_path):
    """(home, its Documents/notes.txt, home/work/ds.zarr whose ``scenes`` is a symlink to ``../..``: home)."""
    import shutil

    from holodata.dataset import create_dataset

    home = tmp_path / "home"
    mine = _user_folder(home / "Documents")
    url = home / "work" / "ds.zarr"
    create_dataset(str(url))
    shutil.rmtree(url / "scenes")
    (url / "scenes").symlink_to("../..")
    return home, mine, url


def test_a_symlinked_scenes_folder_leads_no_write_or_delete_outside_the_dataset(tmp_path):
    from holodata.dataset import create_dataset

    home, mine, url = _linked_dataset(tmp_path)
    for sid in ("Documents", "fresh"):
        with pytest.raises(DatasetError, match="symlink"):
            create_dataset(str(url)).scene(sid, n_frames=2)
    (home / "zarr.json").write_text(json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {}}))
    w = create_dataset(str(url))          # scenes/zarr.json is found (through the link): the writer opens
    for sid in ("Documents", "fresh"):
        with pytest.raises(DatasetError, match="symlink"):
            w.scene(sid, n_frames=2)
    assert mine.read_text() == "mine" and not (home / "fresh").exists()


def test_raytrace_gt_standalone_refuses_a_symlinked_scenes_folder(tmp_path):
    """The reproduction of the issue: ``raytrace-gt --out DS --scene-id Documents``."""
    import _eval_dataset as E
    import numpy as np

    from holodata.meshio import Mesh, write_ply

    _, mine, ds = _linked_dataset(tmp_path)
    V, F = E.box((-3, -3, -1), (3, 3, 2))
    write_ply(tmp_path / "room.ply", Mesh(V, F))
    (tmp_path / "poses.tum").write_text("".join(f"{t} 0 0 0 0 0 0 1\n" for t in np.arange(2) * 0.5))
    r = CliRunner().invoke(cli, ["raytrace-gt", "--mesh", str(tmp_path / "room.ply"), "--poses",
                                 str(tmp_path / "poses.tum"), "--out", str(ds), "--scene-id", "Documents",
                                 "--grid", "8x32"])
    _refused(r, "symlink")
    assert mine.read_text() == "mine"


def test_a_user_folder_inside_scenes_is_not_deleted_to_make_a_scene(tmp_path):
    from holodata.dataset import create_dataset

    url = tmp_path / "ds.zarr"
    w = create_dataset(str(url))
    mine = _user_folder(url / "scenes" / "Documents")
    with pytest.raises(DatasetError, match="notes.txt.*did not write"):
        w.scene("Documents", n_frames=2)
    assert mine.read_text() == "mine"
    # what a killed writer leaves (Zarr node objects, shard records, put temps) is still cleared
    left = url / "scenes" / "killed"
    (left / "radar" / "c" / "0" / "0").mkdir(parents=True)
    (left / "radar" / "c" / "0" / "0" / "0").write_bytes(b"x")
    (left / "radar" / "manifest").mkdir()
    (left / "radar" / "manifest" / "0.json").write_text("{}")
    (left / ".zarr.json.abc.partial").write_text("")
    sc = w.scene("killed", n_frames=2)
    assert sc.n_frames == 2 and not (left / "radar").exists()


def test_a_symlinked_array_folder_is_not_deleted_through(tmp_path):
    from holodata.dataset import create_dataset

    target = tmp_path / "elsewhere"
    mine = _user_folder(target)
    url = tmp_path / "ds.zarr"
    w = create_dataset(str(url))
    sc = w.scene("a", n_frames=2)
    (url / "scenes" / "a" / "gt").symlink_to(target)
    with pytest.raises(DatasetError, match="symlink"):
        sc.frame_array("gt/range", (3, 4, 4))
    with pytest.raises(DatasetError, match="symlink"):
        sc.remove("gt")
    assert mine.read_text() == "mine"


# -- point 8: train / evaluate outputs, and a dataset only its creator deletes ------------------------
def test_train_refuses_a_folder_that_is_not_a_run(traced, tmp_path):
    pytest.importorskip("torch")
    out = tmp_path / "mine"
    cfg = _user_folder(out, "config.json", '{"my": "settings"}')
    log = _user_folder(out, "metrics.jsonl", "my log\n")
    r = CliRunner().invoke(cli, ["train", traced, "--out", str(out), "--epochs", "1", "--quiet"])
    _refused(r, str(out), "not written by holodata")
    assert cfg.read_text() == '{"my": "settings"}' and log.read_text() == "my log\n"


def test_evaluate_refuses_a_folder_it_did_not_write_and_reruns_into_its_own(traced, tmp_path):
    out = tmp_path / "rep"
    mine = _user_folder(out, "metrics.json", "my numbers")
    r = CliRunner().invoke(cli, ["evaluate", traced, "--oracle", "--out", str(out), "--split", "all", "--quiet"])
    _refused(r, str(out), "not written by holodata")
    assert mine.read_text() == "my numbers"
    new = tmp_path / "rep2"
    for _ in range(2):   # its own report folder: rewritten on the rerun
        r = CliRunner().invoke(cli, ["evaluate", traced, "--oracle", "--out", str(new), "--split", "all", "--quiet"])
        assert r.exit_code == 0, r.output
    link = tmp_path / "rep3"
    link.mkdir()
    (link / "metrics.json").symlink_to(mine)
    from holodata.ownership import OutputDir

    with pytest.raises(InputError):
        OutputDir(link, "holodata evaluate", whole=True)
    assert mine.read_text() == "my numbers"


@pytest.mark.parametrize("where", ["local", "memory"])
def test_a_dataset_is_discarded_only_by_the_writer_that_created_it(tmp_path, where):
    import uuid

    from holodata.dataset import create_dataset
    from holodata.dataset.store import Store

    url = str(tmp_path / "ds.zarr") if where == "local" else f"memory://h50-{uuid.uuid4().hex}/ds.zarr"
    a = create_dataset(url)
    b = create_dataset(url)                       # opened, not created: never deletes it
    assert not b.discard()
    b.scene("theirs", n_frames=1)
    assert not a.discard()                        # another writer's scene landed meanwhile
    assert Store(url).exists("scenes/theirs/zarr.json")
    url2 = str(tmp_path / "ds2.zarr") if where == "local" else f"memory://h50-{uuid.uuid4().hex}/ds2.zarr"
    c = create_dataset(url2)
    assert c.discard() and not Store(url2).exists("zarr.json")
    if where == "local":
        assert not (tmp_path / "ds2.zarr").exists()
        keep = tmp_path / "empty"                 # a folder the user made: emptied of holodata's files, kept
        keep.mkdir()
        d = create_dataset(str(keep))
        assert d.discard() and keep.is_dir() and not list(keep.iterdir())


def test_ownership_manifest_sweeps_only_the_temps_it_names(tmp_path):
    from holodata.ownership import MANIFEST, OutputDir

    od = OutputDir(tmp_path / "o", "holodata test")
    t = od.temp("x", folder=True)
    (t / "half").write_text("killed here")
    user_partial = _user_folder(tmp_path / "o" / ".y.partial")
    OutputDir(tmp_path / "o", "holodata test")   # the rerun
    assert not t.exists() and user_partial.read_text() == "mine"
    data = json.loads((tmp_path / "o" / MANIFEST).read_text())
    assert data["pending"] == {}


def test_single_output_files_leave_a_user_file_in_the_way(traced, tmp_path):
    """view --save and slam --ply/--tum (holodata.ownership.write_file) replace only a file holodata
    wrote: a user's file of that name stays, with a one-line refusal; --force replaces a plain file,
    never a symlink."""
    from holodata.ownership import write_file

    mine = tmp_path / "scene.rrd"
    mine.write_text("my recording")
    r = CliRunner().invoke(cli, ["view", traced, "--scene", "room_a", "--frames", "0:1", "--save", str(mine)])
    _refused(r, str(mine), "not written by holodata", "--force")
    assert mine.read_text() == "my recording"
    ply = tmp_path / "mesh.ply"
    ply.write_text("my mesh")
    with pytest.raises(InputError, match="not written by holodata"):
        write_file(ply, "holodata slam --ply", lambda p: p.write_text("holodata's mesh"))
    assert ply.read_text() == "my mesh"
    write_file(tmp_path / "new.ply", "holodata slam --ply", lambda p: p.write_text("first"))
    write_file(tmp_path / "new.ply", "holodata slam --ply", lambda p: p.write_text("second"))   # its own: replaced
    assert (tmp_path / "new.ply").read_text() == "second"
    (tmp_path / "link.ply").symlink_to(ply)
    with pytest.raises(InputError, match="symlink"):
        write_file(tmp_path / "link.ply", "holodata slam --ply", lambda p: p.write_text("x"), force=True)
    assert ply.read_text() == "my mesh"
