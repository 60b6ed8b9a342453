"""Frictions a new user meets in the first hour (issue 24): Ouster support without the SDK says one
thing everywhere, with the command that fixes it."""
from __future__ import annotations

import sys

import pytest
from _paths import FIXTURES, REPO
from click.testing import CliRunner

from holodata.cli.main import cli

PACKETS_BAG = FIXTURES / "ros1" / "512x10_raw.bag"
PCAP = FIXTURES / "ouster" / "OS-1-32-G_v2.1.1_1024x10.pcap"


@pytest.fixture
def no_ouster_sdk(monkeypatch):
    for name in ("ouster", "ouster.sdk", "ouster.sdk.core"):
        monkeypatch.setitem(sys.modules, name, None)   # import fails as if it were not installed


@pytest.mark.skipif(not PACKETS_BAG.is_file(), reason="shared fixtures not present")
def test_without_the_ouster_sdk_list_and_ingest_say_the_same_one_line(no_ouster_sdk, tmp_path):
    from holodata.readers.ouster import INSTALL_COMMAND, SDK_REQUIREMENTS

    assert INSTALL_COMMAND.startswith("pip install --no-deps ") and all(r in INSTALL_COMMAND for r in SDK_REQUIREMENTS)
    setup = (REPO / "scripts" / "setup.sh").read_text()
    assert "holodata.readers.ouster" in setup            # setup.sh installs exactly that list
    r = CliRunner().invoke(cli, ["ingest", "--list", str(PACKETS_BAG)])
    assert r.exit_code == 0, r.output
    last = r.output.strip().splitlines()[-1]
    assert last.startswith("Ingest:    no") and INSTALL_COMMAND in last
    for rec in (PACKETS_BAG, PCAP):
        r = CliRunner().invoke(cli, ["ingest", str(rec), "--out", str(tmp_path / "d.zarr")])
        assert r.exit_code == 1 and r.stdout == ""
        err = r.stderr.strip().splitlines()
        assert len(err) == 1 and str(rec) in err[0] and INSTALL_COMMAND in err[0], err


def test_a_lidar_only_dataset_takes_the_grid_of_the_first_radar_recording(tmp_path):
    from _recordings import write_recording

    from holodata.dataset import open_dataset, validate_dataset
    from holodata.ingest import ingest

    write_recording(tmp_path / "lidar", "mcap", n_radar=2, radar=False, camera=False)
    write_recording(tmp_path / "radar", "mcap", n_radar=2, radar_shape=(8, 4, 16))
    write_recording(tmp_path / "other", "mcap", n_radar=2, radar_shape=(8, 6, 16))
    url = str(tmp_path / "d.zarr")
    ingest([tmp_path / "lidar"], url, quiet=True)
    assert open_dataset(url).meta["grid_source"] == "default"
    r = CliRunner().invoke(cli, ["info", url])
    assert "no radar yet" in r.output
    ingest([tmp_path / "radar"], url, quiet=True)                 # 4x16, not the default 64x512
    ds = open_dataset(url)
    assert (ds.grid.H, ds.grid.W, ds.range_bins.n) == (4, 16, 8) and ds.meta["grid_source"] == "given"
    assert validate_dataset(url)["ok"]
    r = CliRunner().invoke(cli, ["ingest", str(tmp_path / "other"), "--out", url])   # now the grid is set
    assert r.exit_code == 1
    assert "radar grid 6×16 beams (elevation +45° to -45°), 8 range bins of" in r.output and "{" not in r.output


def test_validate_and_info_count_the_same_stored_bytes(tmp_path):
    from _recordings import write_recording

    from holodata.dataset import dataset_info, validate_dataset
    from holodata.ingest import ingest

    write_recording(tmp_path / "rec", "mcap", n_radar=3)
    url = str(tmp_path / "d.zarr")
    ingest([tmp_path / "rec"], url, quiet=True)
    info, rep = dataset_info(url), validate_dataset(url)
    ragged = sum(a["stored_bytes"] for s in info["scenes"] for a in s["arrays"] if a["kind"] == "ragged")
    assert ragged > 0 and rep["bytes_stored"] == info["stored_bytes"]


def test_ragged_arrays_slice_by_frames(tmp_path):
    from _recordings import write_recording

    from holodata.dataset import open_dataset
    from holodata.errors import DatasetError
    from holodata.ingest import ingest

    write_recording(tmp_path / "rec", "mcap", n_radar=3)
    url = str(tmp_path / "d.zarr")
    ingest([tmp_path / "rec"], url, quiet=True)
    pts = open_dataset(url).scene("rec")["lidar/points"]
    two = pts[0:2]
    assert len(two) == 2 and all((a == pts[i]).all() for i, a in enumerate(two))
    assert len(pts[::2]) == 2 and len(pts[-1:]) == 1
    with pytest.raises(DatasetError, match="frame number or a slice"):
        pts["0"]


def test_debug_flag_after_the_command(tmp_path):
    r = CliRunner().invoke(cli, ["info", str(tmp_path / "missing.zarr"), "--debug"])
    assert r.exit_code != 2                                  # not a usage error
    assert isinstance(r.exception, Exception) and not isinstance(r.exception, SystemExit)  # --debug: the traceback
    r = CliRunner().invoke(cli, ["info", str(tmp_path / "missing.zarr")])
    assert r.exit_code == 1 and r.output.startswith("error: ")


def test_a_bad_topics_file_names_line_and_problem(tmp_path):
    bad = tmp_path / "topics.yaml"
    bad.write_text("radar: [unclosed\nlidar: /x\n")
    r = CliRunner().invoke(cli, ["ingest", "--list", str(FIXTURES / "ros1" / "example.bag"), "--topics", str(bad)])
    assert r.exit_code == 1
    assert f"{bad}: not valid YAML at line 2, column 6: expected ',' or ']', but got ':'" in r.output


def test_synth_outputs_ingest_as_scenes_named_after_their_folders(tmp_path):
    """Every synth output holds OUT/recording (+ OUT/truth/): two of them ingest side by side, the
    folder itself is accepted as the recording, and each scene is named after its OUT."""
    from _recordings import write_recording

    from holodata.dataset import open_dataset
    from holodata.ingest import ingest

    for name in ("L_3", "T_4"):
        write_recording(tmp_path / name / "recording", "mcap", n_radar=2)
        (tmp_path / name / "truth").mkdir()
    url = str(tmp_path / "d.zarr")
    ingest([tmp_path / "L_3"], url, quiet=True)                       # the synth folder itself
    ingest([tmp_path / "T_4" / "recording"], url, quiet=True)         # or the recording inside it
    assert sorted(open_dataset(url).scenes) == ["L_3", "T_4"]
    r = CliRunner().invoke(cli, ["ingest", "--list", str(tmp_path / "L_3")])
    assert r.exit_code == 0, r.output


def test_errors_keep_their_cause(tmp_path):
    """One line without --debug; with it, the exception that caused the error is chained (``from err``),
    so the traceback shows both: a dataset whose zarr.json is not JSON."""
    bad = tmp_path / "bad.zarr"
    bad.mkdir()
    (bad / "zarr.json").write_text("{not json")
    r = CliRunner().invoke(cli, ["info", str(bad)])
    assert r.exit_code == 1 and r.output.count("\n") == 1 and "not valid JSON" in r.output, r.output
    r = CliRunner().invoke(cli, ["--debug", "info", str(bad)])
    assert isinstance(r.exception, Exception) and isinstance(r.exception.__cause__, ValueError), r.exception
