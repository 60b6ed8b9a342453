"""open_dataset: lazy reads, fsspec URLs, one-line errors for bad paths and format versions."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import holodata
from holodata.cli.main import cli
from holodata.dataset import open_dataset
from holodata.dataset.synthetic import write_toy_dataset
from holodata.errors import DatasetError


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return write_toy_dataset(str(tmp_path_factory.mktemp("r") / "ds.zarr"), n_frames=6, scenes=("a", "b"))


def test_public_entry_point_and_lazy_arrays(toy):
    ds = holodata.open_dataset(toy)
    assert ds.scenes == ["a", "b"] and ds.splits == {"train": ["a"], "test": ["b"]}
    s = ds.scene("a")
    z = s["radar/heatmap"]
    assert z.shape == (6, 16, 8, 32) and z.dtype == np.float16  # metadata only so far
    assert "gt/range" in s and "nope" not in s
    assert s.is_done("gt/range", 0)
    with pytest.raises(DatasetError, match="no scene 'zz'"):
        ds.scene("zz")
    with pytest.raises(DatasetError, match="no array 'x/y'"):
        s["x/y"]
    with pytest.raises(DatasetError, match="out of range"):
        s.ragged("lidar/points", 6)


@pytest.mark.parametrize("version,words", [("0.9", "too old"), ("2.0", "too new"), ("1.3", None)])
def test_format_version_errors_say_what_to_do(toy, tmp_path, version, words):
    import shutil

    p = tmp_path / "ds.zarr"
    shutil.copytree(toy, p)
    meta = json.loads((p / "zarr.json").read_text())
    meta["attributes"]["holodata"]["format_version"] = version
    (p / "zarr.json").write_text(json.dumps(meta))
    if words is None:  # a newer minor version of the same major is readable
        assert open_dataset(str(p)).format_version == "1.3"
        return
    with pytest.raises(DatasetError, match=words) as e:
        open_dataset(str(p))
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg
    assert ("upgrade holodata" in msg) if words == "too new" else ("re-create" in msg)
    r = CliRunner().invoke(cli, ["info", str(p)])
    assert r.exit_code == 1 and words in r.output and "Traceback" not in r.output


def test_fsspec_memory_url_errors_and_info():
    with pytest.raises(DatasetError, match="does not exist"):
        open_dataset("memory://nothing-here/ds.zarr")
    url = write_toy_dataset("memory://reader-test/ds.zarr", n_frames=4, scenes=("m",))
    r = CliRunner().invoke(cli, ["info", url, "--json"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.output)
    arrays = {a["name"]: a for a in info["scenes"][0]["arrays"]}
    assert arrays["gt/range"]["shape"] == [4, 3, 8, 32] and arrays["gt/range"]["dtype"] == "float32"
    assert arrays["gt/range"]["raw_bytes"] == 4 * 3 * 8 * 32 * 4
    assert arrays["gt/range"]["stored_bytes"] > 0 and arrays["gt/label"]["compression_ratio"] > 1
    assert info["frames"] == 4 and info["splits"] == {"train": ["m"], "test": ["m"]}
    r = CliRunner().invoke(cli, ["validate", url, "--quiet"])
    assert r.exit_code == 0, r.output


def test_info_text(toy):
    r = CliRunner().invoke(cli, ["info", toy])
    assert r.exit_code == 0
    for words in ("2 scenes, 12 frames", "gt/normal", "6x3x8x32x3", "float16", "ratio", "splits: train: a; test: b"):
        assert words in r.output
