"""``holodata validate`` against ``sha256sum`` of the same files, in the same run, and its peak RSS
(validate as a CI gate; plain script, not a test).

Writes a dataset of about ``--gb`` GB stored (default 10) laid out as ingest + slam + raytrace-gt write
one, scenes of ``--frames`` frames until the size is reached: radar/heatmap float16 (R x 64 x 512,
Blosc-lz4 like ingest's bulk arrays, shards of ~32 MB as ingest sizes them), radar/cycle_ns,
time/timestamp_ns, pose/T_world_radar, lidar/points (ragged, lz4) + lidar/timestamp_ns, gt/range,
gt/label, gt/normal (float16), gt/point, gt/semantic, gt/human_center (zstd, 32-frame shards) and a
mesh; the scene attributes declare the radar, the LiDAR and the GT, so validate's inventory applies.
Values are holodata.dataset.synthetic's random, rule-abiding frames (a pool of 32 frames reused: the
bytes each shard holds are realistic in size and compressibility, not in content). Then, alternating
``--repeat`` times (best of each kept; page cache warm, the dataset fits in memory):

- sha256sum: coreutils ``sha256sum`` of every file of the dataset (one process): what a checksum
  pass costs at the least, reading the same bytes validate reads;
- validate: ``validate_dataset`` in a child process (imports before its clock; its peak RSS its own,
  VmHWM: ru_maxrss would carry this parent's over the fork):
  per shard the commit record, the object's size, sha256, decoding and the value rules.

- hashlib: Python's ``hashlib.sha256`` (OpenSSL) of the same files, one thread, whole-file reads:
  the checksum validate itself computes, alone (coreutils may not use the CPU's SHA extensions).

Prints each in MB/s of stored bytes, the ratio validate / sha256sum (aim >= 0.8) and validate /
hashlib, the CPU seconds of each (the steadier number on a shared machine), validate's peak RSS and
the load average.

    .venv/bin/python benchmarks/validate.py [--gb 10] [--frames 480] [--range-bins 64] [--out DIR]
        [--keep] [--repeat 2]

Results, the command and the machine's load: benchmarks/results/validate.md.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _run import header

CHILD = r"""
import json, re, sys, time
from holodata.dataset.validate import validate_dataset
t, c = time.perf_counter(), time.process_time()
rep = validate_dataset(sys.argv[1])
out = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "ok": rep["ok"],
       "problems": [p["line"] for p in rep["problems"][:5]], "shards": rep["shards_checked"],
       "bytes_stored": rep["bytes_stored"], "bytes_decoded": rep["bytes_decoded"],
       "peak_rss_mb": int(re.search(r"VmHWM:\s+(\d+)", open("/proc/self/status").read()).group(1)) / 1024}
print(json.dumps(out))
"""


def write_dataset(url: str, gb: float, frames: int, n_range: int, seed: int = 0) -> int:
    """Scenes of ``frames`` frames until about ``gb`` GB are stored; returns the bytes stored."""
    from holodata.conventions import Grid, RangeBins
    from holodata.dataset import FrameStorage, create_dataset
    from holodata.dataset.layout import (
        GT_HUMAN_CENTER,
        GT_LABEL,
        GT_NORMAL,
        GT_POINT,
        GT_RANGE,
        GT_SEMANTIC,
        LIDAR_POINTS,
        LIDAR_TIMESTAMP_NS,
        MESH_FACES,
        MESH_VERTICES,
        POSE_T_WORLD_RADAR,
        RADAR_CYCLE_NS,
        RADAR_HEATMAP,
        TIME_TIMESTAMP_NS,
    )
    from holodata.dataset.synthetic import toy_frames

    grid = Grid(64, 512)
    w = create_dataset(url, grid=grid, range_bins=RangeBins(n_range, 9.6 / n_range), created_by="benchmarks/validate.py",
                       shard_frames=32, codec="zstd")
    rng = np.random.default_rng(seed)
    pool = toy_frames(rng, range(32), grid, n_range=n_range)   # 32 distinct frames, reused
    clouds = [rng.normal(0, 5, (int(n), 3)).astype(np.float32) for n in rng.integers(15_000, 25_000, 8)]
    hm_frame = n_range * grid.H * grid.W * 2
    hm_shard = int(max(1, min(32, (32 << 20) // hm_frame)))   # ingest: ~32 MB shards
    attrs = {"frame_sensor": "radar", "sensors": {"radar": {"topic": "/radar"}, "lidar": {"topic": "/lidar"}},
             "gt": {"backend": "synthetic", "max_bounces": 3}, "corner_type": "L", "width_m": 2.0}
    stored, i = 0, 0
    while stored < gb * 1e9:
        sid = f"s{i:02d}"
        t0 = time.perf_counter()
        sc = w.scene(sid, n_frames=frames, attrs=attrs)
        f = np.arange(frames)
        ts = (10**9 + f * 100_000_000).astype(np.int64)
        th = 0.01 * f
        poses = np.zeros((frames, 4, 4))
        poses[:, 0, 0] = poses[:, 1, 1] = np.cos(th)
        poses[:, 0, 1], poses[:, 1, 0] = -np.sin(th), np.sin(th)
        poses[:, 2, 2] = poses[:, 3, 3] = 1.0
        poses[:, 0, 3] = 0.05 * f
        small = {TIME_TIMESTAMP_NS: ((), ts), LIDAR_TIMESTAMP_NS: ((), ts), POSE_T_WORLD_RADAR: ((4, 4), poses),
                 RADAR_CYCLE_NS: ((2,), np.stack([ts - 50_000_000, ts + 50_000_000], axis=1))}
        for name, (per, data) in small.items():
            a = sc.frame_array(name, per)
            for k in range(a.n_shards):
                a.write_shard(k, data[a.frames(k)])
        hm = sc.frame_array(RADAR_HEATMAP, (n_range, grid.H, grid.W), "float16", storage=FrameStorage(hm_shard, "lz4"))
        for k in range(hm.n_shards):
            hm.write_shard(k, [pool[RADAR_HEATMAP][j % 32] for j in range(*hm.frames(k).indices(frames))])
        gt = {n: sc.frame_array(n, pool[n].shape[1:]) for n in (GT_RANGE, GT_LABEL, GT_NORMAL, GT_POINT)}
        gt[GT_SEMANTIC] = sc.frame_array(GT_SEMANTIC, pool[GT_LABEL].shape[1:])
        gt[GT_HUMAN_CENTER] = sc.frame_array(GT_HUMAN_CENTER, (1, 3))
        for k in range(gt[GT_RANGE].n_shards):
            idx = [j % 32 for j in range(*gt[GT_RANGE].frames(k).indices(frames))]
            for n, a in gt.items():
                if n == GT_HUMAN_CENTER:
                    a.write_shard(k, np.full((len(idx), 1, 3), np.nan, np.float32))
                else:
                    a.write_shard(k, [pool[GT_LABEL if n == GT_SEMANTIC else n][j] for j in idx])
        pts = sc.ragged_array(LIDAR_POINTS, codec="lz4")
        for k in range(pts.n_shards):
            pts.write_shard(k, [clouds[j % len(clouds)] for j in range(*pts.frames(k).indices(frames))])
        sc.write_array(MESH_VERTICES, rng.uniform(-5, 5, (5000, 3)))
        sc.write_array(MESH_FACES, rng.integers(0, 5000, (10000, 3)))
        stored = du(url)
        print(f"  scene {sid}: {frames} frames, dataset now {stored / 1e9:.2f} GB ({time.perf_counter() - t0:.0f} s)",
              flush=True)
        i += 1
    w.set_splits(train=[f"s{j:02d}" for j in range(i)], test=[])
    return stored


def du(root: str) -> int:
    return sum(p.stat().st_size for p in Path(root).rglob("*") if p.is_file())


def run_sha256sum(root: str) -> tuple[float, float]:
    """(wall s, CPU s) of sha256sum over every file under ``root`` (one process per xargs batch)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    find = subprocess.Popen(["find", root, "-type", "f", "-print0"], stdout=subprocess.PIPE)
    subprocess.run(["xargs", "-0", "sha256sum"], stdin=find.stdout, stdout=subprocess.DEVNULL, check=True)
    find.wait()
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_hashlib(root: str) -> tuple[float, float]:
    """(wall s, CPU s) of Python's hashlib.sha256 (OpenSSL) over every file under ``root``, one thread,
    whole-file reads: the checksum pass validate itself does, alone."""
    import hashlib

    t, c = time.perf_counter(), time.process_time()
    for p in sorted(Path(root).rglob("*")):
        if p.is_file():
            hashlib.sha256(p.read_bytes()).hexdigest()
    return time.perf_counter() - t, time.process_time() - c


def run_validate(root: str) -> dict:
    p = subprocess.run([sys.executable, "-c", CHILD, root], capture_output=True, text=True, check=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gb", type=float, default=10.0, help="stored size to write (GB)")
    ap.add_argument("--frames", type=int, default=480, help="frames per scene")
    ap.add_argument("--range-bins", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", help="folder for the dataset (default: a temp folder under /tmp)")
    ap.add_argument("--keep", action="store_true", help="keep the dataset (and reuse one already there)")
    a = ap.parse_args()
    header()

    tmp = Path(a.out or tempfile.mkdtemp(prefix="holodata-validate-bench-"))
    url = str(tmp / "bench.zarr")
    try:
        if not (a.keep and Path(url, "zarr.json").exists()):
            shutil.rmtree(url, ignore_errors=True)
            t0 = time.perf_counter()
            print(f"writing ~{a.gb:g} GB to {url}", flush=True)
            write_dataset(url, a.gb, a.frames, a.range_bins)
            print(f"wrote it in {time.perf_counter() - t0:.0f} s", flush=True)
        stored = du(url)
        n_files = sum(1 for p in Path(url).rglob("*") if p.is_file())
        run_sha256sum(url)   # page cache warm for both sides
        best_sha = best_hl = best_val = None
        for _ in range(a.repeat):
            s = run_sha256sum(url)
            v = run_validate(url)
            h = run_hashlib(url)
            assert v["ok"], v["problems"]
            print(f"  sha256sum {s[0]:.2f} s (CPU {s[1]:.2f} s); validate {v['wall_s']:.2f} s (CPU {v['cpu_s']:.2f} s, "
                  f"peak RSS {v['peak_rss_mb']:.0f} MB); hashlib {h[0]:.2f} s (CPU {h[1]:.2f} s); "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
            best_sha = s if best_sha is None or s[0] < best_sha[0] else best_sha
            best_hl = h if best_hl is None or h[0] < best_hl[0] else best_hl
            best_val = v if best_val is None or v["wall_s"] < best_val["wall_s"] else best_val
        assert best_sha is not None and best_hl is not None and best_val is not None
        mb = stored / 1e6
        print(f"dataset: {stored / 1e9:.2f} GB stored in {n_files} files, {best_val['shards']} shards, "
              f"{best_val['bytes_decoded'] / 1e9:.2f} GB decoded by validate")
        print(f"sha256sum : {best_sha[0]:7.2f} s  {mb / best_sha[0]:7.0f} MB/s  (CPU {best_sha[1]:.2f} s)")
        print(f"validate  : {best_val['wall_s']:7.2f} s  {mb / best_val['wall_s']:7.0f} MB/s  (CPU {best_val['cpu_s']:.2f} s)"
              f"  peak RSS {best_val['peak_rss_mb']:.0f} MB")
        print(f"hashlib   : {best_hl[0]:7.2f} s  {mb / best_hl[0]:7.0f} MB/s  (CPU {best_hl[1]:.2f} s; Python's "
              f"OpenSSL sha256, one thread)")
        print(f"ratio validate/sha256sum: {best_sha[0] / best_val['wall_s']:.2f} wall (aim >= 0.8), "
              f"{best_sha[1] / best_val['cpu_s']:.2f} CPU; validate/hashlib: {best_hl[0] / best_val['wall_s']:.2f} wall, "
              f"{best_hl[1] / best_val['cpu_s']:.2f} CPU; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    finally:
        if not a.keep:
            shutil.rmtree(url, ignore_errors=True)
            if not a.out:
                shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
