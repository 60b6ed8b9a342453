"""Scale-out on a real Dask cluster: a `dask scheduler` and two `dask worker` processes on 127.0.0.1.

raytrace-gt and ingest run through them (CLI ``--scheduler``) and must give byte-identical shards
(manifest sha256 of every shard of every array) to the in-process run; a worker killed (SIGKILL)
while the job runs must not change the result.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from _recordings import write_recording
from _scenes import HUMAN, l_corridor
from click.testing import CliRunner
from test_groundtruth import pose

import holodata.dataset as hds
from holodata.cli.main import cli
from holodata.meshio import Mesh, write_ply
from holodata.trajectory import Trajectory, write_tum

pytestmark = pytest.mark.slow   # Dask clusters / a moto S3 server / whole recordings: the full tier

BIN = Path(sys.executable).parent
START_TIMEOUT_S = 60


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs) -> None:
    """Workers are killed outright (nothing to flush), then the scheduler is asked to stop."""
    sched, workers = procs[:1], procs[1:]
    for p in workers:
        if p.poll() is None:
            p.kill()
    for p in sched:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=5)


@contextmanager
def dask_cluster(tmp: Path, n_workers: int = 2):
    """A scheduler and ``n_workers`` single-thread workers (no nanny: a killed worker stays dead).
    Yields (address, {worker name: Popen})."""
    port = free_port()
    addr = f"tcp://127.0.0.1:{port}"
    dask = [str(BIN / "dask")] if (BIN / "dask").exists() else [sys.executable, "-m", "dask"]
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    logs = []
    procs = []
    workers = {}
    try:
        log = open(tmp / "scheduler.log", "wb")  # noqa: SIM115 - closed with the processes below
        logs.append(log)
        procs.append(subprocess.Popen(dask + ["scheduler", "--host", "127.0.0.1", "--port", str(port),
                                              "--no-dashboard", "--scheduler-file", str(tmp / "scheduler.json")],
                                      stdout=log, stderr=subprocess.STDOUT, env=env))
        for i in range(n_workers):
            log = open(tmp / f"worker{i}.log", "wb")  # noqa: SIM115
            logs.append(log)
            p = subprocess.Popen(dask + ["worker", addr, "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1",
                                         "--no-dashboard", "--name", f"w{i}", "--local-directory",
                                         str(tmp / f"w{i}"), "--death-timeout", "60"],
                                 stdout=log, stderr=subprocess.STDOUT, env=env)
            procs.append(p)
            workers[f"w{i}"] = p
        from distributed import Client

        deadline = time.monotonic() + START_TIMEOUT_S
        while True:  # the scheduler may not listen yet
            try:
                with Client(addr, timeout="5s") as c:
                    c.wait_for_workers(n_workers, timeout=max(1.0, deadline - time.monotonic()))
                break
            except (OSError, TimeoutError) as err:
                if time.monotonic() > deadline or procs[0].poll() is not None:
                    raise RuntimeError("dask cluster did not start: " + (tmp / "scheduler.log").read_text()[-2000:]) from err
                time.sleep(0.5)
        yield addr, workers
    finally:
        _stop(procs)
        for log in logs:
            log.close()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dask")
    with dask_cluster(tmp) as (addr, workers):
        yield addr, workers, str(tmp / "scheduler.json")


def manifests(url) -> dict:
    """{scene/array/shard: sha256} of every committed shard of a dataset (read through the API)."""
    ds = hds.open_dataset(str(url))
    out = {}
    for sid in ds.scenes:
        st = ds.store
        for name in ds.scene(sid).arrays():
            d = f"scenes/{sid}/{name}/manifest"
            for n in st.list(d):
                out[f"{sid}/{name}/{n}"] = json.loads(st.get(f"{d}/{n}"))["sha256"]
    return out


def make_inputs(tmp: Path, T: int) -> Path:
    v, f = l_corridor()
    write_ply(tmp / "scene.ply", Mesh(v, f))
    poses = np.stack([pose(x, 1.0, 0.05 * k) for k, x in enumerate(np.linspace(5.0, 7.5, T))])
    write_tum(tmp / "radar.tum", Trajectory(np.arange(T) * 500_000_000 + 10**9, poses))
    hdir = tmp / "humans"
    hdir.mkdir()
    for k in range(T):
        write_ply(hdir / f"{k:06d}.ply", Mesh(HUMAN[0] + [0, 0.05 * k, 0], HUMAN[1]))
    return tmp


def gt_args(tmp: Path, out: Path, grid="16x64", shard_frames=2) -> list[str]:
    return ["raytrace-gt", "--mesh", str(tmp / "scene.ply"), "--poses", str(tmp / "radar.tum"), "--human-dir",
            str(tmp / "humans"), "--out", str(out), "--grid", grid, "--shard-frames", str(shard_frames),
            "--processes", "1", "--quiet", "--json"]


def test_raytrace_gt_on_cluster_matches_in_process(cluster, tmp_path, monkeypatch):
    addr, *_ = cluster
    make_inputs(tmp_path, 10)
    r = CliRunner().invoke(cli, gt_args(tmp_path, tmp_path / "ref.zarr"))
    assert r.exit_code == 0, r.output
    # relative paths: the workers run in another directory and get absolute ones
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, gt_args(Path("."), Path("dask.zarr")) + ["--scheduler", addr])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)["scenes"][0]
    assert s["dask_workers"] == 2 and s["shards_written"] == 5
    ref, got = manifests(tmp_path / "ref.zarr"), manifests(tmp_path / "dask.zarr")
    assert len([k for k in ref if "/gt/" in k]) == 6 * 5  # 6 gt arrays x 5 shards
    assert got == ref
    rep = hds.validate_dataset(str(tmp_path / "dask.zarr"))
    assert rep["ok"], rep["problems"][:3]
    # the workers' manifest records were folded into the array attributes
    meta = json.loads((tmp_path / "dask.zarr" / "scenes/scene/gt/range/zarr.json").read_text())
    assert [s["sha256"] for s in meta["attributes"]["holodata"]["shards"]] == \
        [ref[f"scene/gt/range/{k}.json"] for k in range(5)]
    # rerun through the cluster: everything committed, nothing traced
    r = CliRunner().invoke(cli, gt_args(tmp_path, tmp_path / "dask.zarr") + ["--scheduler", addr])
    assert r.exit_code == 0 and json.loads(r.output)["scenes"][0]["shards_skipped"] == 5
    # dataset form (mesh, poses from the dataset; no human there) after dropping gt/: in-process vs cluster
    import shutil

    w = hds.create_dataset("dask.zarr", grid=hds.open_dataset("dask.zarr").grid)
    for name in [n for n in w.scene("scene").arrays() if n.startswith("gt/")]:
        w.scene("scene").remove(name)
    shutil.copytree("dask.zarr", "ds_ref.zarr")
    form = ["raytrace-gt", "--scene", "scene", "--quiet", "--json"]
    r = CliRunner().invoke(cli, form + ["ds_ref.zarr", "--processes", "1"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, form + ["dask.zarr", "--scheduler", addr])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["scenes"][0]["shards_written"] == 5
    got2 = manifests(tmp_path / "dask.zarr")
    assert got2 == manifests(tmp_path / "ds_ref.zarr") and got2 != ref  # no human this time


def test_ingest_on_cluster_matches_in_process(cluster, tmp_path):
    addr, _, sched_file = cluster
    write_recording(tmp_path / "a", "mcap", n_radar=5)
    write_recording(tmp_path / "b.bag", "rosbag1", n_radar=6)
    recs = [str(tmp_path / "a"), str(tmp_path / "b.bag")]
    r = CliRunner().invoke(cli, ["ingest", *recs, "--out", str(tmp_path / "ref.zarr"), "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    # the scheduler file (as dask-jobqueue / `dask scheduler --scheduler-file` write it) instead of the address
    r = CliRunner().invoke(cli, ["ingest", *recs, "--out", str(tmp_path / "dask.zarr"), "--scheduler", sched_file,
                                 "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    assert [s["scene"] for s in json.loads(r.output)["scenes"]] == ["a", "b"]
    ref, got = manifests(tmp_path / "ref.zarr"), manifests(tmp_path / "dask.zarr")
    assert any(k.startswith("a/radar/heatmap/") for k in ref) and any(k.startswith("b/lidar/points/") for k in ref)
    assert got == ref
    assert hds.validate_dataset(str(tmp_path / "dask.zarr"))["ok"]
    # shard_frames reaches the workers' writers as it does the local one (one ingest_one for both)
    from distributed import Client

    from holodata.ingest import IngestOptions, ingest

    ingest(recs, str(tmp_path / "ref2.zarr"), IngestOptions(shard_frames=2))
    with Client(addr) as client:
        ingest(recs, str(tmp_path / "dask2.zarr"), IngestOptions(shard_frames=2), client=client)
    ref2 = manifests(tmp_path / "ref2.zarr")
    assert manifests(tmp_path / "dask2.zarr") == ref2
    assert len([k for k in ref2 if k.startswith("b/radar/heatmap/")]) > len([k for k in ref if k.startswith("b/radar/heatmap/")])
    # a recording that fails is reported and the other still ingested (exit 1)
    (tmp_path / "bad.bag").write_bytes(b"not a bag")
    r = CliRunner().invoke(cli, ["ingest", str(tmp_path / "bad.bag"), recs[0], "--out", str(tmp_path / "c.zarr"),
                                 "--scheduler", addr, "--quiet"])
    assert r.exit_code == 1
    assert hds.open_dataset(str(tmp_path / "c.zarr")).scenes == ["a"]
    # every recording fails on the workers (camera-only passes the grid pre-pass): no empty dataset left
    write_recording(tmp_path / "cam", "mcap", radar=False, lidar=False)
    r = CliRunner().invoke(cli, ["ingest", str(tmp_path / "cam"), "--out", str(tmp_path / "d.zarr"),
                                 "--scheduler", addr, "--quiet"])
    assert r.exit_code == 1 and "camera" in r.output, r.output
    assert not (tmp_path / "d.zarr").exists()


def test_bad_scheduler_address_is_one_line_error(tmp_path, monkeypatch):
    import holodata.distributed as hd

    monkeypatch.setattr(hd, "CONNECT_TIMEOUT_S", 2)
    make_inputs(tmp_path, 2)
    r = CliRunner().invoke(cli, gt_args(tmp_path, tmp_path / "o.zarr")[:-2] + ["--scheduler", f"tcp://127.0.0.1:{free_port()}"])
    assert r.exit_code == 1 and "cannot connect to the Dask scheduler" in r.output
    r = CliRunner().invoke(cli, gt_args(tmp_path, tmp_path / "o.zarr") + ["--workers", "2", "--scheduler", "x:1"])
    assert r.exit_code == 1 and "either --workers or --scheduler" in r.output


def test_worker_killed_mid_job_still_completes_identically(tmp_path):
    T, S = 96, 2   # 48 tasks: enough that a worker is still busy after the first one commits
    make_inputs(tmp_path, T)
    args = gt_args(tmp_path, tmp_path / "ref.zarr", grid="24x96", shard_frames=S)
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    out = tmp_path / "dask.zarr"
    man = out / "scenes" / "scene" / "gt" / "label" / "manifest"  # gt/label: the last array a task writes
    with dask_cluster(tmp_path, 2) as (addr, workers):
        from distributed import Client

        job = subprocess.Popen([str(BIN / "holodata"), *gt_args(tmp_path, out, grid="24x96", shard_frames=S),
                                "--scheduler", addr], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            with Client(addr, timeout="10s") as c:
                deadline = time.monotonic() + 60
                victim = None
                while victim is None:  # after the first task completed: a worker that is busy now
                    assert job.poll() is None, job.communicate()
                    assert time.monotonic() < deadline, "no task completed in 60 s"
                    if man.is_dir() and any(man.iterdir()):
                        info = c.scheduler_info(n_workers=-1)["workers"]
                        busy = [info[a]["name"] for a, ts in c.processing().items() if ts and a in info]
                        victim = busy[0] if busy else None
                    time.sleep(0.05)
                done_at_kill = len(list(man.iterdir()))
                workers[victim].send_signal(signal.SIGKILL)
                workers[victim].wait(timeout=10)
            stdout, stderr = job.communicate(timeout=120)
        finally:
            if job.poll() is None:
                job.kill()
                job.wait()
    assert done_at_kill < T // S, "the job finished before the worker was killed"
    assert job.returncode == 0, stderr.decode()[-2000:]
    assert json.loads(stdout)["scenes"][0]["shards_written"] == T // S
    assert manifests(out) == manifests(tmp_path / "ref.zarr")
    assert hds.validate_dataset(str(out))["ok"]


def test_synth_count_on_cluster_matches_in_process(cluster, tmp_path):
    import hashlib

    addr, *_ = cluster
    args = ["synth", "--count", "2", "--seed", "5", "--frames", "2", "--grid", "8x32", "--range-bins", "16",
            "--lidar", "16x128", "--camera", "24x32", "--quiet", "--json"]
    r = CliRunner().invoke(cli, args + ["--out", str(tmp_path / "ref")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, args + ["--out", str(tmp_path / "dask"), "--scheduler", addr])
    assert r.exit_code == 0, r.output
    assert [s["seed"] for s in json.loads(r.output)] == [5, 6]

    from holodata.ownership import MANIFEST

    def digest(root: Path) -> dict:   # the recordings (not holodata's manifest of what it wrote, which names inodes)
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file() and p.name != MANIFEST}

    ref, got = digest(tmp_path / "ref"), digest(tmp_path / "dask")
    assert any(k.endswith(".mcap") for k in ref) and len(ref) > 4
    assert got == ref
    # an existing recording is refused before any task runs
    r = CliRunner().invoke(cli, args + ["--out", str(tmp_path / "dask"), "--scheduler", addr])
    assert r.exit_code == 1 and "already exists" in r.output


def test_shard_task_rerun_is_idempotent(tmp_path, monkeypatch):
    """A task rerun after its worker died: committed arrays are skipped without tracing, an array
    whose manifest is missing (the worker died between two puts) is traced and rewritten identically."""
    import holodata.groundtruth as gtm
    from holodata.conventions import Grid
    from holodata.meshio import read_mesh
    from holodata.trajectory import read_tum

    make_inputs(tmp_path, 4)
    out = tmp_path / "o.zarr"
    assert CliRunner().invoke(cli, gt_args(tmp_path, out)).exit_code == 0
    before = manifests(out)
    ds = hds.open_dataset(str(out))
    m = read_mesh(tmp_path / "scene.ply")
    traj = read_tum(tmp_path / "radar.tum")
    payload = {"mesh": (m.vertices, m.faces, None, None), "cfg": gtm.GTConfig(grid=Grid.parse("16x64", "-45,45")),
               "traj": traj, "human": gtm.HumanDir(tmp_path / "humans", len(traj)), "url": str(out),
               "grid": ds.grid, "range_bins": ds.range_bins, "scene_id": "scene",
               # the column times the command traced with: the rotations it stored as radar/cycle_ns
               "cycles": gtm.standalone_cycles(traj)[0]}
    traced = []
    real = gtm.trace_shard
    monkeypatch.setattr(gtm, "trace_shard", lambda tr, frames, names: traced.append(list(names)) or real(tr, frames, names))
    res = gtm._gt_shard_task("t1", payload, 1, list(gtm.GT_ARRAYS), 2, 4)
    assert res["written"] == [] and traced == []
    (out / "scenes/scene/gt/label/manifest/1.json").unlink()
    (out / "scenes/scene/gt/label/c/1/0/0/0").write_bytes(b"torn")  # an uncommitted object
    res = gtm._gt_shard_task("t2", payload, 1, list(gtm.GT_ARRAYS), 2, 4)
    assert res["written"] == ["gt/label"] and traced == [["gt/label"]]
    assert manifests(out) == before
    assert hds.validate_dataset(str(out))["ok"]


def _kill_own_worker(x):
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_task_that_kills_every_worker_is_a_one_line_error_within_seconds():
    """A Dask task whose worker dies each time (as under the OOM killer): Dask reruns it on a fresh
    worker (allowed-failures, here 1), then run_tasks gives up with one WorkerError line naming the
    step and the task, within seconds, instead of a KilledWorker repr or a hang."""
    import dask

    import holodata.distributed as hd
    from holodata.parallel import WorkerError

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}), hd.cluster(workers=1) as client:
        t = time.monotonic()
        with pytest.raises(WorkerError) as e:
            hd.run_tasks(client, _kill_own_worker, [(1,)], ["doomed-task"], description="test step")
        took = time.monotonic() - t
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("test step: task 'doomed-task' killed 2 Dask workers"), msg
    assert took < 60, took
