"""holodata view: an .rrd of a traced scene that Rerun's own reader opens, with the panels and the
frame counts expected; one-line errors for bad input."""
from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

from holodata.cli.main import cli

rr = pytest.importorskip("rerun")


@pytest.fixture(scope="module")
def traced(tmp_path_factory):
    import _eval_dataset as E

    url = str(tmp_path_factory.mktemp("view") / "traced.zarr")
    E.build(url)
    return url


def _rows(path) -> dict[str, int]:
    from rerun.chunk import RrdReader

    summary = RrdReader(str(path)).store().summary()
    rows: dict[str, int] = {}
    for m in re.finditer(r"^(\S+) rows=(\d+)", summary, flags=re.M):   # one line per chunk: an entity may have several
        rows[m.group(1)] = rows.get(m.group(1), 0) + int(m.group(2))
    return rows


def test_save_writes_an_rrd_with_every_panel_per_frame(traced, tmp_path):
    out = tmp_path / "a.rrd"
    r = CliRunner().invoke(cli, ["view", traced, "--scene", "room_b", "--frames", "1:4", "--save", str(out)])
    assert r.exit_code == 0, r.output
    assert "note: no lidar/points" in r.output          # the tiny dataset has no LiDAR: said, not failed
    rows = _rows(out)
    for e in ("/radar/range_azimuth", "/radar/elevation_azimuth", "/gt/range/b1", "/gt/range/b3", "/gt/label/b2",
              "/world/gt/mirrored", "/world/gt/unmirrored"):
        assert rows.get(e) == 3, (e, rows)


def test_bad_input_is_one_line(traced, tmp_path):
    for args, words in ((["--scene", "nope"], "no scene 'nope'"), (["--frames", "3:99"], "frames 0..")):
        r = CliRunner().invoke(cli, ["view", traced, "--save", str(tmp_path / "x.rrd")] + args)
        assert r.exit_code == 1 and words in r.output and "Traceback" not in r.output, r.output
    r = CliRunner(env={"DISPLAY": "", "WAYLAND_DISPLAY": ""}).invoke(cli, ["view", traced])
    assert r.exit_code == 1 and "--save" in r.output


def test_web_keeps_its_data_server_alive_while_the_stream_is_held(traced):
    import socket

    from holodata.view import view_scene

    def free_pair() -> int:
        """A port P with P + 1 free too (the web viewer takes P, its data server P + 1)."""
        for _ in range(50):
            with socket.socket() as a:
                a.bind(("0.0.0.0", 0))
                port = a.getsockname()[1]
                try:
                    with socket.socket() as b:
                        b.bind(("0.0.0.0", port + 1))
                except OSError:
                    continue
            return port
        raise AssertionError("no two consecutive free ports")

    port = free_pair()
    r = view_scene(traced, "room_a", "0:2", web=True, port=port)
    assert r["stream"] is not None
    with socket.create_connection(("127.0.0.1", port + 1), timeout=5):   # the gRPC data server answers
        pass
    r["stream"].disconnect()
