"""holodata export: PanoRadar processed folders and HDF5 files that holodata's own readers ingest
back to the source arrays."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.dataset import open_dataset, validate_dataset
from holodata.export import export_dataset
from holodata.ingest import ingest


@pytest.fixture(scope="module")
def traced(tmp_path_factory):
    import _eval_dataset as E

    url = str(tmp_path_factory.mktemp("exp") / "traced.zarr")
    E.build(url)
    return url


@pytest.fixture(scope="module")
def ingested(tmp_path_factory):
    from holodata.conventions import Grid
    from holodata.synth import SynthSpec, synthesize

    d = tmp_path_factory.mktemp("exp_synth")
    synthesize(d / "L", SynthSpec(corner="L", frames=3, seed=5, grid=Grid(8, 32), lidar_shape=(8, 64), camera_shape=(24, 32),
                                  mapping_pass=False), quiet=True)
    url = str(d / "ing.zarr")
    ingest([d / "L"], url)
    return url


def test_panoradar_export_ingests_back_to_the_heatmaps_and_first_bounce_ranges(traced, tmp_path):
    src = open_dataset(traced)
    sid = src.scenes[0]
    r = CliRunner().invoke(cli, ["export", traced, "--format", "panoradar", "--out", str(tmp_path / "pr"),
                                 "--scene", sid, "--quiet"])
    assert r.exit_code == 0, r.output
    folder = tmp_path / "pr" / sid
    assert sorted(p.name for p in folder.iterdir()) == ["gt_npy", "holodata.json", "label_npy", "lidar_npy", "rf_npy"]
    x = np.load(folder / "rf_npy" / "00000.npy")
    assert x.dtype == np.float32 and x.shape == src.scene(sid)["radar/heatmap"].shape[1:]
    url = str(tmp_path / "back.zarr")
    ingest([folder], url, scene_ids=["back"])
    back, s = open_dataset(url).scene("back"), src.scene(sid)
    a, b = np.asarray(back["radar/heatmap"][...]), np.asarray(s["radar/heatmap"][...])
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=2e-6)
    g = np.asarray(s["gt/range"][...])[:, 0]
    np.testing.assert_allclose(np.asarray(back["lidar/range"][...]), g, rtol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(np.load(folder / "label_npy" / "00001.npy"), np.asarray(s["gt/label"][1]))


def test_hdf5_export_ingests_back_to_the_same_arrays(ingested, tmp_path):
    import h5py

    src = open_dataset(ingested)
    sid = src.scenes[0]
    r = export_dataset(ingested, "hdf5", tmp_path / "h5")
    path = tmp_path / "h5" / f"{sid}.h5"
    assert r["scenes"][0]["out"] == str(path) and not list((tmp_path / "h5").glob("*partial*"))
    s = src.scene(sid)
    with h5py.File(path) as h:
        for name in s.arrays():
            assert f"holodata/{name}" in h or name in h, name
        assert "units" in h["radar/heatmap"].attrs["holodata_attrs"]
        assert h["holodata/lidar/range"].shape == s["lidar/range"].shape
    url = str(tmp_path / "back.zarr")
    ingest([path], url, scene_ids=["back"])
    assert validate_dataset(url)["ok"]
    back = open_dataset(url).scene("back")
    np.testing.assert_array_equal(np.asarray(back["radar/heatmap"][...]), np.asarray(s["radar/heatmap"][...]))
    np.testing.assert_array_equal(back["time/timestamp_ns"][...], s["time/timestamp_ns"][...])
    for role in ("lidar", "camera"):
        for f in range(s.n_frames):
            np.testing.assert_array_equal(back[f"{role}/points"][f], s[f"{role}/points"][f])


def test_a_scene_without_stamps_or_sensors_exports_to_hdf5(traced, tmp_path):
    r = export_dataset(traced, "hdf5", tmp_path / "h5", split=None)
    assert len(r["scenes"]) == len(open_dataset(traced).scenes)
    url = str(tmp_path / "back.zarr")
    ingest([tmp_path / "h5" / "room_a.h5"], url, scene_ids=["a"])
    np.testing.assert_array_equal(np.asarray(open_dataset(url).scene("a")["radar/heatmap"][...]),
                                  np.asarray(open_dataset(traced).scene("room_a")["radar/heatmap"][...]))


def test_export_errors_are_one_line(traced, tmp_path):
    for args, words in ((["--scene", "nope"], "no scene 'nope'"), (["--split", "nope"], "no split 'nope'")):
        r = CliRunner().invoke(cli, ["export", traced, "--format", "hdf5", "--out", str(tmp_path / "x")] + args)
        assert r.exit_code == 1 and words in r.output and "Traceback" not in r.output, r.output
    r = CliRunner().invoke(cli, ["export", str(tmp_path / "missing.zarr"), "--format", "hdf5", "--out", str(tmp_path / "y")])
    assert r.exit_code == 1 and "missing.zarr" in r.output
