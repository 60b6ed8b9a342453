"""Datasets on S3 through fsspec: a real S3-compatible server (moto's server mode) on 127.0.0.1.

Credentials and the endpoint come only from the environment (``AWS_*`` incl. ``AWS_ENDPOINT_URL``,
or fsspec's ``FSSPEC_S3_*``); nothing S3-specific is passed on the command line.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _recordings import write_recording
from click.testing import CliRunner
from test_distributed import free_port, gt_args, make_inputs, manifests

import holodata.dataset as hds
from holodata.cli.main import cli

pytestmark = pytest.mark.slow   # Dask clusters / a moto S3 server / whole recordings: the full tier

BUCKET = "holodata-test"


def _clear_fs_cache() -> None:
    """Drop s3fs's cached filesystems and close their HTTP sessions (else aiohttp warns "Unclosed client
    session" at interpreter exit, when fsspec's IO loop is gone)."""
    import gc

    import s3fs
    from fsspec.asyn import get_loop

    for fs in [o for o in gc.get_objects() if issubclass(type(o), s3fs.S3FileSystem)]:
        if getattr(fs, "_s3", None) is not None:
            s3fs.S3FileSystem.close_session(get_loop(), fs._s3)
            fs._s3 = None
    s3fs.S3FileSystem.clear_instance_cache()


@pytest.fixture(scope="module")
def s3():
    """moto S3 server on a free port; AWS_* env pointing at it for this module. Yields the endpoint."""
    from moto.server import ThreadedMotoServer

    port = free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    endpoint = f"http://127.0.0.1:{port}"
    with pytest.MonkeyPatch.context() as mp:
        for k in list(os.environ):
            if k.startswith(("AWS_", "FSSPEC_S3")):
                mp.delenv(k)
        mp.setenv("AWS_ENDPOINT_URL", endpoint)
        mp.setenv("AWS_ACCESS_KEY_ID", "testing")
        mp.setenv("AWS_SECRET_ACCESS_KEY", "testing")
        mp.setenv("AWS_DEFAULT_REGION", "us-east-1")
        _clear_fs_cache()
        import fsspec

        fsspec.filesystem("s3").mkdir(BUCKET)
        try:
            yield endpoint
        finally:
            _clear_fs_cache()
            server.stop()


def test_api_write_read_validate_and_detect_corruption(s3):
    from holodata.conventions import Grid, RangeBins

    url = f"s3://{BUCKET}/api.zarr"
    w = hds.create_dataset(url, grid=Grid(4, 8), range_bins=RangeBins(16, 0.1), shard_frames=2)
    sc = w.scene("a", n_frames=5, attrs={"frame_sensor": "radar"})
    ts = sc.frame_array("time/timestamp_ns", (), "int64", dims=["frame"], units="ns")
    hm = sc.frame_array("radar/heatmap", (16, 4, 8), "float32", dims=["frame", "range", "elevation", "azimuth"])
    pts = sc.ragged_array("lidar/points", width=3, units="m")
    rng = np.random.default_rng(0)
    data = rng.random((5, 16, 4, 8)).astype(np.float32)
    clouds = [rng.random((n, 3)).astype(np.float32) for n in (3, 0, 7, 1, 2)]
    for k in range(ts.n_shards):
        sl = ts.frames(k)
        ts.write_shard(k, np.arange(5)[sl] * 10)
        hm.write_shard(k, data[sl])
        pts.write_shard(k, clouds[sl])
    sc.write_array("mesh/vertices", np.eye(3, dtype=np.float32), dims=["vertex", "xyz"], units="m")
    # a second writer process would see the same state: reopen = resume, nothing left to write
    again = hds.create_dataset(url, grid=Grid(4, 8), range_bins=RangeBins(16, 0.1))
    assert again.scene("a").frame_array("radar/heatmap", (16, 4, 8), "float32").complete

    ds = hds.open_dataset(url)
    s = ds.scene("a")
    np.testing.assert_array_equal(s["radar/heatmap"][...], data)
    np.testing.assert_array_equal(s["time/timestamp_ns"][...], np.arange(5) * 10)
    for i, c in enumerate(clouds):
        np.testing.assert_array_equal(s.ragged("lidar/points", i), c)
    rep = hds.validate_dataset(url)
    assert rep["ok"], rep["problems"][:3]
    info = hds.dataset_info(url)
    assert info["scenes"][0]["scene" if "scene" in info["scenes"][0] else "id"] == "a"

    # object stores have no rename: a shard is one PUT; garbage under a committed key is detected
    import fsspec

    fs = fsspec.filesystem("s3")
    fs.pipe_file(f"{BUCKET}/api.zarr/scenes/a/radar/heatmap/c/1/0/0/0", b"garbage")
    rep = hds.validate_dataset(url)
    assert not rep["ok"] and any("radar/heatmap" in str(p) for p in rep["problems"])


def test_cli_raytrace_on_dask_workers_to_s3_validate_info(s3, tmp_path):
    make_inputs(tmp_path, 6)
    r = CliRunner().invoke(cli, gt_args(tmp_path, tmp_path / "ref.zarr"))
    assert r.exit_code == 0, r.output
    url = f"s3://{BUCKET}/gt.zarr"
    # LocalCluster workers are new processes: they get the endpoint/credentials from the environment
    r = CliRunner().invoke(cli, gt_args(tmp_path, url) + ["--workers", "2"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["scenes"][0]["dask_workers"] == 2
    assert manifests(url) == manifests(tmp_path / "ref.zarr")
    r = CliRunner().invoke(cli, ["validate", url, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["ok"]
    r = CliRunner().invoke(cli, ["info", url, "--json"])
    assert r.exit_code == 0 and "gt/range" in r.output
    # resume on S3 (in-process this time): every shard is committed, nothing rewritten
    r = CliRunner().invoke(cli, gt_args(tmp_path, url))
    assert r.exit_code == 0 and json.loads(r.output)["scenes"][0]["shards_skipped"] == 3

    # a fresh process configured only through fsspec's FSSPEC_S3_* variables (no AWS_ENDPOINT_URL)
    env = {k: v for k, v in os.environ.items() if k != "AWS_ENDPOINT_URL"}
    env.update(FSSPEC_S3_ENDPOINT_URL=s3, FSSPEC_S3_KEY="testing", FSSPEC_S3_SECRET="testing")
    env.pop("AWS_ACCESS_KEY_ID"), env.pop("AWS_SECRET_ACCESS_KEY")
    p = subprocess.run([str(Path(sys.executable).parent / "holodata"), "validate", url, "--json"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["ok"]
    assert p.stderr.strip() == "", p.stderr   # no "Unclosed client session" (or any warning) after the result


def test_cli_ingest_out_s3_and_missing_dataset(s3, tmp_path):
    write_recording(tmp_path / "rec", "mcap", n_radar=4)
    url = f"s3://{BUCKET}/ingest.zarr"
    r = CliRunner().invoke(cli, ["ingest", str(tmp_path / "rec"), "--out", url, "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["ingest", str(tmp_path / "rec"), "--out", str(tmp_path / "ref.zarr"), "--quiet"])
    assert r.exit_code == 0, r.output
    assert manifests(url) == manifests(tmp_path / "ref.zarr")
    assert hds.validate_dataset(url)["ok"]
    r = CliRunner().invoke(cli, ["validate", f"s3://{BUCKET}/nothing.zarr"])
    assert r.exit_code == 1 and "nothing.zarr" in r.output
    # fresh processes (as a user runs them): nothing on stderr after the result, no "Unclosed client
    # session" from aiohttp or any other warning, for a write, a read and a one-line error alike
    holo = str(Path(sys.executable).parent / "holodata")
    for cmd, code in ((["ingest", str(tmp_path / "rec"), "--out", f"s3://{BUCKET}/fresh.zarr", "--quiet"], 0),
                      (["info", f"s3://{BUCKET}/fresh.zarr"], 0), (["validate", f"s3://{BUCKET}/fresh.zarr"], 0),
                      (["validate", f"s3://{BUCKET}/nothing.zarr"], 1)):
        p = subprocess.run([holo, *cmd], capture_output=True, text=True, timeout=300)
        assert p.returncode == code, p.stderr
        expect = [ln for ln in p.stderr.splitlines() if ln.startswith("error:")] if code else []
        assert p.stderr.splitlines() == expect and len(expect) == code, (cmd, p.stderr)


def test_training_reader_on_s3(s3, tmp_path):
    torch = pytest.importorskip("torch")
    import _eval_dataset as E
    import fsspec

    from holodata.torch import HeatmapDataset

    E.build(str(tmp_path / "train.zarr"))  # built locally, uploaded as is (an `aws s3 sync` of a dataset)
    url = f"s3://{BUCKET}/train.zarr"
    fsspec.filesystem("s3").put(str(tmp_path / "train.zarr"), url, recursive=True)
    assert hds.open_dataset(url).scenes == ["room_a", "room_b", "room_c"]
    tr = HeatmapDataset(url, split="train")
    s = tr[1]
    raw = hds.open_dataset(url).scene(s["scene"])
    np.testing.assert_array_equal(s["range"].numpy(), np.asarray(raw["gt/range"][s["frame"]]))
    assert isinstance(s["heatmap"], torch.Tensor)


def test_non_object_store_put_goes_through_a_partial_object(tmp_path):
    """fsspec filesystems other than object stores may write in place: a put writes a hidden
    ``.partial`` sibling and moves it over the key, leaving nothing else behind."""
    from holodata.dataset.store import Store

    st = Store(f"local://{tmp_path}/ds")
    assert not st.local and not st.atomic_put
    st.put("a/b.json", b"{}")
    st.put("a/b.json", b"[1]")
    assert st.get("a/b.json") == b"[1]" and st.list("a") == ["b.json"]
    assert Store(f"s3://{BUCKET}/x").atomic_put and Store("memory://x").atomic_put


# Loaded into every process of a run (the CLI and each Dask worker it spawns) through PYTHONPATH.
# At the start of interpreter shutdown (threading's exit hooks run before any atexit handler, so before
# s3fs's own exit-time close, which gives itself 0.1 s and then gives up) it reports every aiohttp
# session still open; as the last atexit handler it drops s3fs's instance cache and collects garbage,
# which is what interpreter teardown does with whatever was left open when it happens to collect it:
# aiohttp then prints "Unclosed client session" / "client_session: <aiohttp.client.ClientSession ...>".
EXIT_PROBE = '''
import atexit, os, sys, threading


def _open_sessions():
    if "aiohttp" not in sys.modules:
        return 0
    import gc

    import aiohttp

    return sum(1 for o in gc.get_objects() if isinstance(o, aiohttp.ClientSession) and not o.closed)


def _at_shutdown():
    n = _open_sessions()
    if n:
        sys.stderr.write(f"exit probe: {n} aiohttp session(s) still open in pid {os.getpid()}\\n")


def _collect():
    if "s3fs" in sys.modules:
        import gc

        import s3fs

        s3fs.S3FileSystem.clear_instance_cache()
        gc.collect()


threading._register_atexit(_at_shutdown)
atexit.register(_collect)
'''


def test_a_dask_cluster_run_on_s3_closes_its_http_sessions_before_exit(s3, tmp_path):
    """issue 43 point 5: a cluster run that writes to S3 printed "Unclosed client session" and
    "client_session: <aiohttp.client.ClientSession ...>" on stderr at exit. Its HTTP sessions (s3fs's, in
    the CLI process and in every LocalCluster worker, whose stderr is the CLI's) were left open for
    interpreter shutdown: s3fs closes a synchronous filesystem's session at exit within 0.1 s or not at
    all, and never the asynchronous filesystems zarr opens to read arrays. Now the CLI closes its own
    before it returns and the workers' (client.run) before the cluster stops: stderr is empty."""
    probe = tmp_path / "probe"
    probe.mkdir()
    (probe / "sitecustomize.py").write_text(EXIT_PROBE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(probe), *filter(None, [os.environ.get("PYTHONPATH")])])}
    holo = str(Path(sys.executable).parent / "holodata")
    make_inputs(tmp_path, 4)
    url = f"s3://{BUCKET}/exit.zarr"
    # standalone raytrace-gt: the workers trace and write every shard to S3
    p = subprocess.run([holo, *gt_args(tmp_path, url), "--workers", "2"], env=env, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["scenes"][0]["dask_workers"] == 2
    assert p.stderr == "", p.stderr
    # dataset form after dropping gt/: the CLI reads the mesh and poses from S3 (through zarr), the
    # workers trace and write again
    w = hds.create_dataset(url, grid=hds.open_dataset(url).grid)
    for name in [n for n in w.scene("scene").arrays() if n.startswith("gt/")]:
        w.scene("scene").remove(name)
    _clear_fs_cache()
    p = subprocess.run([holo, "raytrace-gt", url, "--scene", "scene", "--quiet", "--json", "--workers", "2"], env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["scenes"][0]["shards_written"] == 2
    assert p.stderr == "", p.stderr
