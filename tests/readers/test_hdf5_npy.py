"""HDF5 (holodata layout) and PanoRadar npy folders: values through the readers and through ingest
against the arrays written, PanoRadar's log scaling undone analytically, layout errors in one line."""
from __future__ import annotations

import numpy as np
import pytest

from holodata.conventions import Grid
from holodata.dataset import open_dataset, validate_dataset
from holodata.errors import RecordingError
from holodata.ingest import ingest
from holodata.readers import guess_reader, open_recording

h5py = pytest.importorskip("h5py")


def _panoradar(tmp_path, n=3, shape=(16, 8, 32)):
    tr = tmp_path / "traj"
    (tr / "rf_npy").mkdir(parents=True)
    (tr / "lidar_npy").mkdir()
    (tr / "seg_npy").mkdir()
    rng = np.random.default_rng(0)
    amps, ranges = [], []
    for i in range(n):
        a = rng.gamma(1.0, 1.0, shape).astype(np.float32)
        a[0, 0, 0] = 0.0
        np.save(tr / "rf_npy" / f"{i:05d}.npy", (np.log10(a + 1e-3) / 3).astype(np.float32))
        r = rng.uniform(0.5, 5.0, (1,) + shape[1:]).astype(np.float32)
        r[0, 0, :4] = -1000.0          # failed returns
        np.save(tr / "lidar_npy" / f"{i:05d}.npy", r / 10)
        amps.append(a)
        ranges.append(r[0])
    return tr, amps, ranges


def test_panoradar_folder_reader_and_ingest(tmp_path):
    tr, amps, ranges = _panoradar(tmp_path)
    assert guess_reader(tr) == "npy-folder"
    with open_recording(tr) as r:
        t = {x.name: x for x in r.topics()}
        assert t["/panoradar/rf"].count == 3 and t["/panoradar/lidar_range"].count == 3
        msgs = list(r.messages(["/panoradar/rf"]))
        hm = np.frombuffer(msgs[1][2].data, "<f4").reshape(16, 8, 32)
        np.testing.assert_allclose(hm, amps[1], rtol=1e-5, atol=1e-6)
        assert hm[0, 0, 0] == 0.0 and "log10" in r.attrs["radar_scaling"]
    s = ingest([tr], tmp_path / "ds.zarr")
    assert s["ok"], s
    ds = open_dataset(tmp_path / "ds.zarr")
    sc = ds.scene("traj")
    assert sc.n_frames == 3 and (ds.grid.H, ds.grid.W, ds.range_bins.n) == (8, 32, 16)
    np.testing.assert_allclose(sc["radar/heatmap"][...], np.stack(amps), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(sc["time/timestamp_ns"][...], np.arange(3) * 500_000_000 + 250_000_000)
    rg = sc["lidar/range"][1]
    expect = np.where(ranges[1] > 0, ranges[1] * 10 / 10, np.nan)   # stored /10, read back x10
    np.testing.assert_allclose(rg, expect, rtol=1e-6)
    pts = sc.ragged("lidar/points", 1)
    d = Grid(8, 32).directions()
    ok = np.isfinite(expect)
    np.testing.assert_allclose(pts, (d * np.nan_to_num(expect)[..., None])[ok], rtol=1e-5, atol=1e-6)
    assert "synthesised" in sc.attrs["source"]["timestamps"]
    assert validate_dataset(tmp_path / "ds.zarr")["ok"]


def _h5(path, **over):
    rng = np.random.default_rng(1)
    hm = rng.uniform(0, 1, (4, 8, 4, 16)).astype(np.float16)
    pts = rng.normal(size=(90, 3)).astype(np.float32)
    d = {"radar/heatmap": hm, "radar/timestamp_ns": np.arange(4, dtype=np.int64) * 500_000_000 + 10**18,
         "lidar/points": pts, "lidar/offsets": np.array([0, 20, 45, 70, 90]),
         "lidar/timestamp_ns": np.arange(4, dtype=np.int64) * 500_000_000 + 10**18 + 5_000_000,
         "lidar/point_time_ns": np.arange(90, dtype=np.int64)}
    d.update(over)
    with h5py.File(path, "w") as f:
        for k, v in d.items():
            if v is not None:
                f[k] = v
        if "radar/heatmap" in f:
            f["radar/heatmap"].attrs["range_resolution_m"] = 0.05
    return d


def test_hdf5_reader_and_ingest(tmp_path):
    d = _h5(tmp_path / "rec.h5")
    with open_recording(tmp_path / "rec.h5") as r:
        assert {t.name: t.count for t in r.topics()} == {"/radar/heatmap": 4, "/lidar/points": 4}
    s = ingest([tmp_path / "rec.h5"], tmp_path / "ds.zarr")
    assert s["ok"], s
    ds = open_dataset(tmp_path / "ds.zarr")
    sc = ds.scene("rec")
    assert ds.range_bins.dr == 0.05
    np.testing.assert_array_equal(sc["radar/heatmap"][...], d["radar/heatmap"])
    for k in range(4):
        lo, hi = d["lidar/offsets"][k], d["lidar/offsets"][k + 1]
        np.testing.assert_array_equal(sc.ragged("lidar/points", k), d["lidar/points"][lo:hi])
        np.testing.assert_array_equal(sc.ragged("lidar/point_time_ns", k)[:, 0], np.arange(lo, hi))
    np.testing.assert_array_equal(sc["lidar/timestamp_ns"][...], d["lidar/timestamp_ns"])
    assert validate_dataset(tmp_path / "ds.zarr")["ok"]


@pytest.mark.parametrize("over, msg", [
    ({"radar/timestamp_ns": np.arange(3)}, r"radar/timestamp_ns has shape \(3,\), expected \(4,\)"),
    ({"lidar/offsets": np.array([0, 20, 10, 70, 90])}, "lidar/offsets must start at 0, never decrease"),
    ({"radar/heatmap": np.zeros((2, 3)), "radar/timestamp_ns": np.arange(2)}, "radar/heatmap must be"),
    ({"radar/heatmap": None, "radar/timestamp_ns": None, "lidar/points": None, "lidar/offsets": None,
      "lidar/timestamp_ns": None, "lidar/point_time_ns": None, "other": np.zeros(3)}, "has neither"),
])
def test_hdf5_layout_errors(tmp_path, over, msg):
    _h5(tmp_path / "bad.h5", **over)
    with pytest.raises(RecordingError, match=msg):
        open_recording(tmp_path / "bad.h5")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all" * 10)
    with pytest.raises(RecordingError, match="not a readable HDF5 file"):
        open_recording(tmp_path / "junk.h5")


def test_bad_npy_folder(tmp_path):
    (tmp_path / "t" / "rf_npy").mkdir(parents=True)
    with pytest.raises(RecordingError, match="hold no .npy files"):
        open_recording(tmp_path / "t")
    (tmp_path / "t" / "rf_npy" / "00000.npy").write_bytes(b"garbage")
    with open_recording(tmp_path / "t") as r, pytest.raises(RecordingError, match="not a readable .npy array"):
        list(r.messages())


@pytest.mark.parametrize("attr, kind, radius", [(None, "rotation_centre", 0.0), ("antenna", "rotation_circle", 0.08)])
def test_hdf5_and_npy_state_their_beam_origin(tmp_path, attr, kind, radius):
    _h5(tmp_path / "rec.h5")
    with h5py.File(tmp_path / "rec.h5", "a") as f:
        if attr:
            f["radar/heatmap"].attrs["range_origin"] = attr
            f["radar/heatmap"].attrs["rotation_radius_m"] = radius
    ingest([tmp_path / "rec.h5"], tmp_path / "ds.zarr")
    bo = open_dataset(tmp_path / "ds.zarr").scene("rec").attrs["sensors"]["radar"]["beam_origin"]
    assert (bo["type"], bo["rotation_radius_m"], bo["column_time"]) == (kind, radius, True)
    tr, _, _ = _panoradar(tmp_path)            # PanoRadar's imaging aligns every chirp to the centre
    ingest([tr], tmp_path / "pr.zarr")
    assert open_dataset(tmp_path / "pr.zarr").scene("traj").attrs["sensors"]["radar"]["beam_origin"]["type"] == \
        "rotation_centre"
