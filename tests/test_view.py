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


def test_an_oracle_report_draws_the_gt_hit_points_as_predictions(traced, tmp_path):
    """A perfect prediction (an oracle evaluation's report) must land exactly on the traced hit
    points, with the GT labels: the view runs the same stage two as evaluate, in the world frame."""
    pytest.importorskip("torch")
    import numpy as np

    from holodata.dataset import open_dataset
    from holodata.evaluate import evaluate
    from holodata.view import _Predictions, run_of_report

    rep = tmp_path / "oracle"
    evaluate(traced, None, rep, split="all", oracle=True, report=False, quiet=True)
    ck, oracle, est = run_of_report(rep)
    assert oracle and ck is None
    ds = open_dataset(traced)
    sc = ds.scene("room_b")
    pred = _Predictions(ck, oracle, est, ds, sc)
    for k in (0, 2):
        pts, ids = pred.frame(k)
        gp = np.asarray(sc["gt/point"][k], np.float64).reshape(-1, 3)
        ok = np.isfinite(gp).all(-1)
        assert len(pts) == ok.sum() > 100
        np.testing.assert_allclose(pts, gp[ok], atol=1e-3)
        np.testing.assert_array_equal(ids, np.asarray(sc["gt/label"][k]).reshape(-1)[ok])
    out = tmp_path / "p.rrd"
    r = CliRunner().invoke(cli, ["view", traced, "--scene", "room_b", "--frames", "0:2", "--report", str(rep),
                                 "--save", str(out)])
    assert r.exit_code == 0, r.output
    assert _rows(out).get("/world/pred/points") == 2


def test_a_checkpoint_draws_its_predicted_points(traced, tmp_path):
    pytest.importorskip("torch")
    from holodata.torch import TrainConfig, train

    run = tmp_path / "run"
    train(traced, run, TrainConfig(epochs=1, depth=3, base_channels=8, max_channels=16, blocks=1, batch_size=2),
          quiet=True)
    out = tmp_path / "c.rrd"
    r = CliRunner().invoke(cli, ["view", traced, "--scene", "room_b", "--frames", "0:3", "--checkpoint", str(run),
                                 "--save", str(out)])
    assert r.exit_code == 0, r.output
    assert _rows(out).get("/world/pred/points") == 3
    r = CliRunner().invoke(cli, ["view", traced, "--report", str(tmp_path), "--save", str(out)])
    assert r.exit_code == 1 and "metrics.json: no such file" in r.output and "Traceback" not in r.output, r.output
