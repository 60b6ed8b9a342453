"""holodata view: an .rrd of a traced scene that Rerun's own reader opens, with the panels and the
frame counts expected; one-line errors for bad input."""
from __future__ import annotations

import re
from pathlib import Path

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


def _listening(port: int) -> set[str]:
    """Local addresses (IPv4 dotted / IPv6 hex) with a TCP socket listening on ``port`` (/proc/net/tcp*)."""
    import socket
    import struct

    out = set()
    for f, fam in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 6)):
        try:
            rows = Path(f).read_text().splitlines()[1:]
        except FileNotFoundError:
            continue
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            addr, p = local.split(":")
            if state != "0A" or int(p, 16) != port:   # 0A: LISTEN
                continue
            out.add(socket.inet_ntoa(struct.pack("<I", int(addr, 16))) if fam == 4 else addr)
    return out


def test_web_serves_on_loopback_only_while_the_stream_is_held(traced):
    """Issue 50 point 1: the data server binds 127.0.0.1 (not every interface, as rerun's serve_grpc
    does), and no page server is started on every interface."""
    import socket

    from holodata.view import PAGE_PORT, SceneView, web_instructions

    with socket.socket() as a:
        a.bind(("127.0.0.1", 0))
        port = a.getsockname()[1]
    page_before = _listening(PAGE_PORT)
    r = SceneView(traced, "room_a", "0:2", web=True, port=port).run()
    try:
        assert r["stream"] is not None
        with socket.create_connection(("127.0.0.1", port), timeout=5):   # the gRPC data server answers
            pass
        assert _listening(port) == {"127.0.0.1"}, _listening(port)
        assert _listening(PAGE_PORT) == page_before
        lines = web_instructions(port)
        assert any(f"rerun rerun+http://127.0.0.1:{port}/proxy" in x for x in lines) and any("ssh -L" in x for x in lines)
    finally:
        r["stream"].disconnect()


def test_an_oracle_report_draws_the_gt_hit_points_as_predictions(traced, tmp_path):
    """A perfect prediction (an oracle evaluation's report) must land exactly on the traced hit
    points, with the GT labels: the view runs the same stage two as evaluate, in the world frame."""
    pytest.importorskip("torch")
    import numpy as np

    from holodata.dataset import open_dataset
    from holodata.evaluate import Evaluation
    from holodata.view import _Predictions, run_of_report

    rep = tmp_path / "oracle"
    Evaluation(traced, None, rep, split="all", oracle=True, report=False, quiet=True).run()
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
    rows = _rows(out)
    assert rows.get("/world/pred/points") == 2
    assert rows.get("/world/person/true") == rows.get("/world/person/predicted") == 2   # one per frame, even empty


def test_the_person_is_marked_where_evaluate_finds_it():
    """``world/person/*``: the centre of each cluster of human-labelled points, as evaluate matches."""
    pytest.importorskip("rerun")
    import numpy as np

    from holodata.conventions import Label
    from holodata.view import _log_person

    rng = np.random.default_rng(1)
    person = np.array([2.0, 1.0, 0.9]) + rng.normal(0, 0.05, (12, 3))
    wall = np.stack([np.full(30, 4.0), np.linspace(-2, 2, 30), np.zeros(30)], 1)
    pts = np.concatenate([person, wall])
    ids = np.array([int(Label.NLOS_HUMAN)] * 12 + [int(Label.NLOS_STRUCTURE)] * 30, np.uint8)
    got = {}
    _log_person(lambda path, obj: got.setdefault(path, obj), "world/person/true", pts, ids, "true person")
    pos = got["world/person/true"].positions.as_arrow_array().to_numpy(zero_copy_only=False)
    np.testing.assert_allclose(np.stack(pos).reshape(-1, 3), person.mean(0)[None], atol=1e-5)
    got.clear()
    _log_person(lambda path, obj: got.setdefault(path, obj), "world/person/true", wall, ids[12:], "true person")
    assert len(got["world/person/true"].positions.as_arrow_array()) == 0


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
