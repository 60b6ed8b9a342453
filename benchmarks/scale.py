"""Benchmark: raytrace-gt scale-out on Dask (1 and 2 workers) against the in-process run.

Same inputs as benchmarks/raytrace.py (T-junction SLAM-like mesh, a ~2k-triangle walking human per
frame via --human-dir, paper grid 64x512, 3 bounces), written to local datasets:

  1. in-process (``processes=1``, open3d using every core)        -> the reference, same work
  2. Dask LocalCluster, 1 worker  (1 task thread, 1 ray thread)
  3. Dask LocalCluster, 2 workers (1 task thread, 1 ray thread each)

Cluster start-up (worker processes, imports) and the in-process imports (a warm-up run) are
excluded, start-up reported separately; the first task of each worker (building the static BVH)
is included. Every run's shards must be byte-identical
(manifest sha256) to the reference. Prints frames/s, frames/s per worker, the 2-vs-1-worker
speed-up, the ratio to the in-process run, and the projected cost of a HoloRadar-sized job
(28k frames). The load average is printed too: other processes on the machine skew the numbers.

    .venv/bin/python benchmarks/scale.py [--frames 64] [--grid 64x512] [--shard-frames 4]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from raytrace import make_inputs  # noqa: E402  (benchmarks/raytrace.py)

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


def run(d: Path, out: Path, grid: str, shard_frames: int, threads: int, client=None) -> tuple[float, dict]:
    from holodata.conventions import Grid
    from holodata.groundtruth import GTConfig, raytrace_standalone

    cfg = GTConfig(grid=Grid.parse(grid, "-45,45"), shard_frames=shard_frames, nthreads=threads)
    t = time.perf_counter()
    s = raytrace_standalone(d / "scene.ply", d / "radar.tum", str(out), human_dir=d / "humans", cfg=cfg,
                            quiet=True, processes=1, client=client)
    return time.perf_counter() - t, s["scenes"][0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--grid", default="64x512")
    ap.add_argument("--shard-frames", type=int, default=4, help="frames per task (shard)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration; the fastest counts")
    ap.add_argument("--keep", action="store_true")
    a = ap.parse_args()

    from holodata.distributed import cluster

    tmp = Path(tempfile.mkdtemp(prefix="holodata-scale-"))
    try:
        make_inputs(tmp, a.frames)
        cpus = len(os.sched_getaffinity(0))
        print(f"raytrace-gt scale-out: {a.frames} frames, grid {a.grid}, 3 bounces, {a.shard_frames} frames/task, "
              f"{cpus} cores, load average before {os.getloadavg()[0]:.1f}")
        run(tmp, tmp / "warm.zarr", a.grid, a.shard_frames, threads=0)  # imports, caches: not measured
        t_ref = min(run(tmp, tmp / f"ref{i}.zarr", a.grid, a.shard_frames, threads=0)[0] for i in range(a.repeat))
        ref = manifests(str(tmp / "ref0.zarr"))
        rows = [("in-process (open3d on all cores)", 0, t_ref, None)]
        print(f"  in-process          : {a.frames / t_ref:6.2f} frames/s  ({t_ref:.1f} s)")
        for n in (1, 2):
            t0 = time.perf_counter()
            with cluster(workers=n) as client:
                client.run(lambda: __import__("holodata.groundtruth") and __import__("open3d"))  # warm imports
                t_start = time.perf_counter() - t0
                t = min(run(tmp, tmp / f"w{n}_{i}.zarr", a.grid, a.shard_frames, threads=1, client=client)[0]
                        for i in range(a.repeat))
            same = manifests(str(tmp / f"w{n}_0.zarr")) == ref
            if not same:
                raise SystemExit(f"{n} worker(s): shards differ from the in-process run")
            rows.append((f"dask {n} worker(s)", n, t, t_start))
            print(f"  dask {n} worker(s)   : {a.frames / t:6.2f} frames/s  ({t:.1f} s; {a.frames / t / n:.2f} "
                  f"frames/s/worker; cluster start {t_start:.1f} s; shards identical: {same})")
        t1, t2 = rows[1][2], rows[2][2]
        fps1, fps2 = a.frames / t1, a.frames / t2
        per_worker = fps2 / 2
        print()
        print(f"speed-up 2 vs 1 worker       : {t1 / t2:.2f}x   (aim >= 1.7x on 2 cores)")
        print(f"frames/s per worker          : {fps1:.2f} (1 worker), {per_worker:.2f} (2 workers)")
        print(f"ratio vs in-process run      : 1 worker {fps1 / (a.frames / t_ref):.2f}, "
              f"2 workers {fps2 / (a.frames / t_ref):.2f}  (throughput / in-process throughput)")
        print(f"load average after           : {os.getloadavg()[0]:.1f}")
        wh = HOLORADAR_FRAMES / fps1 / 3600
        print(f"\nprojected {HOLORADAR_FRAMES} frames (HoloRadar-sized, grid {a.grid}, 3 bounces) at "
              f"{fps1:.2f} frames/s per single-core worker: {wh:.1f} worker-hours (core-hours)")
        for n in (2, 16, 64, 256):
            print(f"  {n:4d} workers: {wh / n * 60:8.1f} min wall (linear scaling; tasks = {HOLORADAR_FRAMES // a.shard_frames} "
                  f"shards of {a.shard_frames} frames, or 875 of 32)")
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            print(f"kept {tmp}")


if __name__ == "__main__":
    main()
