"""Benchmark: raytrace-gt scale-out on Dask (1 and 2 workers) against the in-process run.

Same inputs as benchmarks/raytrace.py (T-junction SLAM-like mesh, a ~2k-triangle walking human per
frame via --human-dir, paper grid 64x512, 3 bounces), written to local datasets:

  1. in-process (``processes=1``, open3d using every core)        -> the reference, same work
  2. in-process, 1 ray thread (what one worker does, without Dask) -> Dask overhead
  3. the local multiprocessing path (``--processes 2``)
  4. Dask LocalCluster, 1 worker  (1 task thread, 1 ray thread)
  5. Dask LocalCluster, 2 workers (1 task thread, 1 ray thread each)

Cluster start-up (worker processes, imports) and the in-process imports (a warm-up run) are
excluded, start-up reported separately; the first task of each worker (building the static BVH)
is included. Every run's shards must be byte-identical
(manifest sha256) to the reference. Prints frames/s, frames/s per worker, the 2-vs-1-worker
speed-up, the ratio to the in-process run, and the projected cost of a HoloRadar-sized job
(28k frames). The load average is printed too: other processes on the machine skew wall-clock
numbers, so CPU seconds (client + scheduler + workers) are measured as well and give a
contention-free estimate of the speed-up and the cost per frame.

    .venv/bin/python benchmarks/scale.py [--frames 96] [--grid 64x512] [--shard-frames 8] [--repeat 2]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from _run import header
from raytrace import make_inputs  # benchmarks/raytrace.py

HOLORADAR_FRAMES = 28_000


def manifests(url: str) -> dict:
    from holodata.dataset import open_dataset

    ds = open_dataset(url)
    out = {}
    for sid in ds.scenes:
        for name in ds.scene(sid).arrays():
            d = f"scenes/{sid}/{name}/manifest"
            for n in ds.store.list(d):
                out[f"{sid}/{name}/{n}"] = json.loads(ds.store.get(d + "/" + n))["sha256"]
    return out


def _proc_cpu() -> float:
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def cpu_seconds(client=None) -> float:
    """CPU seconds used so far by this process (client, LocalCluster scheduler, local threads), its
    reaped children (``--processes`` pools) and, with ``client``, every Dask worker process."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = r.ru_utime + r.ru_stime + c.ru_utime + c.ru_stime
    if client is not None:
        total += sum(client.run(_proc_cpu).values())
    return total


def run(d: Path, out: Path, grid: str, shard_frames: int, threads: int, client=None, processes: int = 1
        ) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one standalone raytrace-gt run into a new dataset ``out``."""
    from holodata.conventions import Grid
    from holodata.groundtruth import GTConfig, RaytraceStandalone

    cfg = GTConfig(grid=Grid.parse(grid, "-45,45"), shard_frames=shard_frames, nthreads=threads)
    c0 = cpu_seconds(client)
    t = time.perf_counter()
    RaytraceStandalone(d / "scene.ply", d / "radar.tum", str(out), human_dir=d / "humans", cfg=cfg,
                       quiet=True, processes=processes, client=client).run()
    return time.perf_counter() - t, cpu_seconds(client) - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--grid", default="64x512")
    ap.add_argument("--shard-frames", type=int, default=8, help="frames per task (shard)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration; the fastest counts")
    ap.add_argument("--keep", action="store_true")
    a = ap.parse_args()
    header()

    from holodata.distributed import cluster

    tmp = Path(tempfile.mkdtemp(prefix="holodata-scale-"))
    try:
        make_inputs(tmp, a.frames)
        cpus = len(os.sched_getaffinity(0))
        print(f"raytrace-gt scale-out: {a.frames} frames, grid {a.grid}, 3 bounces, {a.shard_frames} frames/task, "
              f"{cpus} cores, load average before {os.getloadavg()[0]:.1f}")
        run(tmp, tmp / "warm.zarr", a.grid, a.shard_frames, threads=0)  # imports, caches: not measured

        def best(name, **kw):
            """fastest of ``--repeat`` runs: (wall s, CPU s)"""
            return min(run(tmp, tmp / f"{name}_{i}.zarr", a.grid, a.shard_frames, **kw) for i in range(a.repeat))

        def line(label, wall, cpu, n=None):
            per = f"; {a.frames / wall / n:.2f} frames/s/worker" if n else ""
            print(f"  {label:43s}: {a.frames / wall:6.2f} frames/s  ({wall:5.1f} s wall, {cpu / a.frames:.3f} "
                  f"CPU s/frame{per})")

        t_ref, c_ref = best("ref", threads=0)
        ref = manifests(str(tmp / "ref_0.zarr"))
        t_ref1, c_ref1 = best("ref1", threads=1)
        t_mp, c_mp = best("mp", threads=1, processes=2)
        line("in-process, 1 process, open3d on all cores", t_ref, c_ref)
        line("in-process, 1 process, 1 ray thread", t_ref1, c_ref1)
        line("local --processes 2 (multiprocessing)", t_mp, c_mp)
        times, cpus_used = {}, {}
        for n in (1, 2):
            t0 = time.perf_counter()
            with cluster(workers=n) as client:
                client.run(lambda: __import__("holodata.groundtruth") and __import__("open3d"))  # warm imports
                t_start = time.perf_counter() - t0
                times[n], cpus_used[n] = best(f"w{n}", threads=1, client=client)
            if not all(manifests(str(tmp / f"w{n}_{i}.zarr")) == ref for i in range(a.repeat)):
                raise SystemExit(f"{n} worker(s): shards differ from the in-process run")
            line(f"dask {n} worker(s), 1 ray thread each", times[n], cpus_used[n], n)
            print(f"  {'':43s}  (cluster start {t_start:.1f} s, not counted; shards identical to in-process: yes)")
        t1, t2 = times[1], times[2]
        fps1, fps2 = a.frames / t1, a.frames / t2
        fps_ref = a.frames / t_ref
        print()
        print(f"speed-up 2 vs 1 worker (wall clock)   : {t1 / t2:.2f}x   (aim >= 1.7x on 2 cores)")
        print(f"  CPU-time estimate, idle machine     : {min(2.0, 2 * cpus_used[1] / cpus_used[2]):.2f}x   "
              f"(2 x CPU(1 worker) / CPU(2 workers): total work grows by {cpus_used[2] / cpus_used[1]:.2f}x)")
        print(f"frames/s per worker                   : {fps1:.2f} (1 worker), {fps2 / 2:.2f} (2 workers); "
              f"{a.frames / cpus_used[2]:.2f} frames per CPU-second (2 workers, everything counted)")
        print(f"ratio vs in-process run (throughput)  : 2 workers / in-process all cores {fps2 / fps_ref:.2f}; "
              f"2 workers / --processes 2 {t_mp / t2:.2f}; 1 worker / in-process 1 thread {t_ref1 / t1:.2f} "
              f"(1.0 = no Dask overhead; CPU ratio {c_ref1 / cpus_used[1]:.2f})")
        print(f"load average after           : {os.getloadavg()[0]:.1f}")
        per = a.frames / cpus_used[2]  # frames per CPU-second, all overheads included
        wh = HOLORADAR_FRAMES / per / 3600
        print(f"\nprojected {HOLORADAR_FRAMES} frames (HoloRadar-sized, grid {a.grid}, 3 bounces) at {per:.2f} "
              f"frames per worker-CPU-second: {wh:.1f} worker-hours (= core-hours); "
              f"{HOLORADAR_FRAMES // 32} tasks at the default 32 frames/shard")
        for n in (2, 16, 64, 256):
            print(f"  {n:4d} single-core workers: {wh / n * 60:8.1f} min wall (assuming linear scaling)")
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            print(f"kept {tmp}")


if __name__ == "__main__":
    main()
