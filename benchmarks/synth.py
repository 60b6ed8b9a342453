"""Benchmark: the synthetic radar forward model at the full 256x64x512 grid, and a whole recording.

1. Radar frames/s on an L corner with a walking human (trace 64x512 beams x 3 bounces through
   world + human, per-path amplitudes, range responses, angular PSF, noise, magnitude, float16
   encoding), with a per-step breakdown and the peak traced memory of one frame (tracemalloc).
2. The same frames' ray batches replayed through bare open3d ``RaycastingScene.cast_rays`` in this
   run: ratio  synth time / bare casting time  (how much the physics costs on top of the casts).
3. A whole default recording (``synthesize``: radar + 64x1024 LiDAR at 10 Hz + VGA depth camera at
   5 Hz + odometry, MCAP writing) for --record-frames frames: wall time, size, peak RSS.

    .venv/bin/python benchmarks/synth.py [--frames 10] [--record-frames 6] [--skip-record]
"""
from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from holodata.conventions import Grid, RangeBins  # noqa: E402
from holodata.synth.radar import encode_heatmap  # noqa: E402
from holodata.synth.scenario import Sensors, build_scenario  # noqa: E402


def bare_replay(log) -> float:
    """Seconds for open3d to cast the same ray batches (scene rebuilt as the tracer's was)."""
    import open3d as o3d

    t = 0.0
    for rays in log:
        r = o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32))
        t0 = time.perf_counter()
        _scene_cache["s"].cast_rays(r)
        t += time.perf_counter() - t0
    return t


_scene_cache: dict = {}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--record-frames", type=int, default=6)
    ap.add_argument("--skip-record", action="store_true")
    args = ap.parse_args()
    import open3d as o3d

    grid, rb = Grid(64, 512), RangeBins(256)
    sc = build_scenario("L", width=2.0, frames=args.frames, seed=3, grid=grid, range_bins=rb,
                        lidar_shape=(8, 64), camera_shape=(8, 16))
    s = Sensors(sc)
    s.radar_frame(0)  # warm-up (FFT plans, BVH, page faults)
    steps = {"trace": 0.0, "paths": 0.0, "cube": 0.0, "encode": 0.0}
    bare = 0.0
    n_rays = 0
    t_all = time.perf_counter()
    for k in range(args.frames):
        cfg = sc.radar_cfg
        start, end = sc.radar_cycle(k)
        t0 = time.perf_counter()
        t_cols = start + np.round((np.arange(grid.W) + 0.5) / grid.W * (end - start)).astype(np.int64)
        T_cols = sc.truth.interpolate(t_cols) @ sc.T_base_radar
        D = np.einsum("wij,hwj->hwi", T_cols[:, :3, :3], grid.directions()).reshape(-1, 3)
        O = np.broadcast_to(T_cols[None, :, :3, 3], (grid.H, grid.W, 3)).reshape(-1, 3)
        s.cast_log = []
        tr = s.trace(O, D, sc.human_mesh((start + end) // 2), cfg.max_bounces, rb.max_range)
        t1 = time.perf_counter()
        paths = s.radar.paths(tr, O, D)
        t2 = time.perf_counter()
        hm = s.radar.cube(paths, np.random.default_rng(k))
        t3 = time.perf_counter()
        encode_heatmap(hm, cfg.encoding)
        t4 = time.perf_counter()
        steps["trace"] += t1 - t0
        steps["paths"] += t2 - t1
        steps["cube"] += t3 - t2
        steps["encode"] += t4 - t3
        # bare open3d on the same batches, against the same merged mesh
        m = s.last_scene.static
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(m.vertices.astype(np.float32)), o3d.core.Tensor(m.faces.astype(np.uint32)))
        _scene_cache["s"] = scene
        log = [e[-1] if e[-1].ndim == 2 and e[-1].shape[1] == 6 else np.concatenate(e[1:], 1) for e in s.cast_log]
        n_rays += sum(len(r) for r in log)
        bare += bare_replay(log)
    total = time.perf_counter() - t_all
    synth_s = sum(steps.values())
    fps = args.frames / synth_s
    print(f"radar forward model, grid 256x64x512, L corner + human, {args.frames} frames")
    print(f"  frames/s: {fps:.2f}   ({1000 * synth_s / args.frames:.0f} ms/frame; loop incl. bare replay {total:.1f} s)")
    for k, v in steps.items():
        print(f"    {k:7s} {1000 * v / args.frames:7.1f} ms/frame")
    print(f"  bare open3d cast_rays of the same {n_rays // args.frames} rays/frame: {1000 * bare / args.frames:.1f} ms/frame")
    print(f"  ratio synth / bare casting: {synth_s / max(bare, 1e-9):.1f}x")
    tracemalloc.start()
    s.radar_frame(0)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"  peak traced memory of one frame: {peak / 2**20:.0f} MiB (heatmap float32 = {256 * 64 * 512 * 4 / 2**20:.0f} MiB)")
    print(f"  process peak RSS so far: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")

    if args.skip_record:
        return
    from holodata.synth import synthesize

    tmp = Path(tempfile.mkdtemp(prefix="holodata-synth-bench-"))
    try:
        t0 = time.perf_counter()
        res = synthesize(tmp / "rec", corner="T", frames=args.record_frames, seed=5, quiet=True)
        dt = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in res.recording.rglob("*") if p.is_file())
        print(f"whole recording (defaults: radar 256x64x512 float16, LiDAR 64x1024 @10 Hz, camera 376x672 @5 Hz, MCAP), "
              f"{args.record_frames} radar frames:")
        print(f"  {dt:.1f} s = {dt / args.record_frames:.2f} s per radar frame (real time: 0.5 s); "
              f"{sum(res.counts.values())} messages, {size / 2**20:.0f} MiB")
        print(f"  process peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
