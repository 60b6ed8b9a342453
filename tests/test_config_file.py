"""Stage settings from one YAML file (holodata.config_file, ``--config``): the shipped example is the
defaults, precedence flag > file > default, one-line errors naming the file, and a CLI run whose
result follows the file."""
from __future__ import annotations

import dataclasses

import pytest
from _paths import REPO
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.config_file import SECTIONS, build, config_class, read
from holodata.errors import InputError

EXAMPLE = REPO / "examples" / "holodata.yaml"


def test_the_example_names_every_section_and_holds_the_defaults():
    data = read(EXAMPLE)
    assert set(data) == set(SECTIONS)
    for section in data:
        assert build(section, EXAMPLE) == config_class(section)(), section
    from holodata.torch.train import TrainConfig

    pytest.importorskip("torch")
    assert TrainConfig.from_file(EXAMPLE) == TrainConfig()      # train reads its section of the same file


def test_a_flag_given_wins_over_the_file_and_the_file_over_the_dataclass_default(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("slam: {voxel: 0.3, icp_distances: [0.4, 0.2]}\ngt: {grid: 16x64}\n")
    assert build("slam", f, {"voxel": None, "refine": None}).voxel == 0.3     # None: the flag was not given
    assert build("slam", f, {"voxel": 0.2}).voxel == 0.2
    assert build("slam", f, {"voxel": 0.2}).icp_distances == (0.4, 0.2)      # YAML list -> the field's tuple
    assert build("gt", f).grid.W == 64 and build("slam", None, {"voxel": 0.2}).voxel == 0.2
    assert build("slam", None, {"voxel": None}) == build("slam") == config_class("slam")()
    assert {x.name for x in dataclasses.fields(config_class("register"))} >= {"guess_std_m", "max_rmse_m"}


@pytest.mark.parametrize("text,words", [("slammm: {voxel: 1}\n", "unknown section(s) slammm"),
                                        ("slam: {voxle: 1}\n", "unknown slam field(s) voxle"),
                                        ("slam: [1, 2]\n", "must be a mapping"),
                                        ("slam: {voxel: [1\n", "not a YAML/JSON mapping"),
                                        ("- 1\n", "mapping of sections")])
def test_bad_files_are_one_line_errors_naming_the_file(tmp_path, text, words):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(InputError, match="bad.yaml") as e:
        read(f)
    assert words in str(e.value)


def test_raytrace_gt_follows_the_file_unless_a_flag_says_otherwise(tmp_path):
    from test_distributed import gt_args, make_inputs

    from holodata.dataset import open_dataset

    make_inputs(tmp_path, 2)
    cfg = tmp_path / "stages.yaml"
    cfg.write_text("gt:\n  max_bounces: 2\n  max_range: 8.0\n")
    args = [a for a in gt_args(tmp_path, tmp_path / "a.zarr") if a != "--json"]
    r = CliRunner().invoke(cli, args + ["--config", str(cfg)])
    assert r.exit_code == 0, r.output
    sc = open_dataset(str(tmp_path / "a.zarr")).scene("scene")
    assert sc["gt/range"].shape[1] == 2 and sc.attrs["gt"]["max_range_m"] == 8.0
    r = CliRunner().invoke(cli, [a for a in gt_args(tmp_path, tmp_path / "b.zarr") if a != "--json"]
                           + ["--config", str(cfg), "--max-bounces", "3"])
    assert r.exit_code == 0, r.output
    assert open_dataset(str(tmp_path / "b.zarr")).scene("scene")["gt/range"].shape[1] == 3
    cfg.write_text("gt: {bounces: 2}\n")
    r = CliRunner().invoke(cli, args + ["--config", str(cfg)])
    assert r.exit_code == 1 and "unknown gt field(s) bounces" in r.output and "Traceback" not in r.output
