"""Benchmark: the synthetic radar forward model at the full 256x64x512 grid, and a whole recording.

1. Radar frames/s on an L corner with a walking human (trace 64x512 beams x 3 bounces through
   world + human, per-path amplitudes, range responses, angular PSF, noise, magnitude, float16
   encoding), with a per-step breakdown and the peak traced memory of one frame (tracemalloc).
2. The same frames' ray batches replayed through bare open3d ``RaycastingScene.cast_rays`` in this
   run: ratio  synth time / bare casting time  (how much the physics costs on top of the casts).
3. Raw I/Q (``synth --radar-output iq``): rotations/s of every chirp position (1024 + the 2x128 the
   first and last beams need) x 8 antennas x 256 samples from the same frames' paths (Gaussian-
   gridded beat samples, :mod:`holodata.radar._iq_kernel`), next to the plain direct sum
   (:func:`holodata.radar.simulate.simulate_chirps`, numpy) of the same scatterers on every 128th
   chirp in the same run, extrapolated to the rotation: ratio.
4. A whole default recording (``synthesize``: radar + 64x1024 LiDAR at 10 Hz + VGA depth camera at
   5 Hz + odometry, MCAP writing) for --record-frames frames: wall time, size, peak RSS.

    .venv/bin/python benchmarks/synth.py [--frames 10] [--iq-frames 3] [--record-frames 6] [--skip-record]
"""
from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from _run import header

from holodata.conventions import Grid, RangeBins
from holodata.synth.radar import encode_heatmap
from holodata.synth.scenario import SceneSpec, Sensors, build_scenario


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


def iq_rotations(s, sc, n: int) -> None:
    """Section 3 of the module docstring."""
    from holodata.radar.simulate import simulate_chirps

    cfg = sc.radar_cfg
    chirp, n_syn = cfg.imaging()
    N, pad = cfg.chirps_per_rotation, n_syn // 2
    idx = np.arange(-pad, N + pad)
    t_iq = t_direct = 0.0
    n_direct = 0
    for k in range(n + 1):          # rotation 0 warms up (numba's compiled code, FFT plans)
        paths, O, D = s._radar_paths(k)
        start, end = sc.radar_cycle(k)
        t = start + np.round((idx + 0.5) / N * (end - start)).astype(np.int64)
        poses = sc.truth.interpolate(t) @ sc.T_base_radar
        t0 = time.perf_counter()
        out = s.radar.iq(paths, O, D, poses, idx, np.random.default_rng(k))
        if k:
            t_iq += time.perf_counter() - t0
        if k == n:                  # the direct sum of the same scatterers, every 128th chirp
            sub = idx[::128]
            X = O[paths["pix"]] + paths["range"][:, None] * D[paths["pix"]]
            a = np.abs(paths["amp"]) * s.radar.raw_scale()[0]
            T0 = np.linalg.inv(poses[pad])           # scatterers in the radar frame at chirp 0
            Xr = X @ T0[:3, :3].T + T0[:3, 3]
            reach = np.deg2rad(cfg.azimuth_fov_deg / 2 + cfg.azimuth_support_deg)
            t0 = time.perf_counter()
            for c in sub:                    # the scatterers within the same reach of each chirp's facing
                off = np.angle(np.exp(1j * (np.arctan2(Xr[:, 1], Xr[:, 0]) + 2 * np.pi * c / N)))
                m = np.abs(off) <= reach
                simulate_chirps(Xr[m], a[m], chirp, chirp_index=np.array([c]), n_chirps=N)
            t_direct, n_direct = time.perf_counter() - t0, sub.size
    per_rot = t_iq / n
    direct_rot = t_direct / n_direct * idx.size
    print(f"raw I/Q rotations ({idx.size} chirps x {chirp.n_virtual} antennas x {chirp.n_samples} samples, "
          f"{len(paths['pix'])} paths as scatterers), {n} rotations:")
    print(f"  rotations/s: {1 / per_rot:.2f}   ({1000 * per_rot:.0f} ms/rotation, {out.nbytes / 2**20:.0f} MiB each)")
    print(f"  plain numpy direct sum of the same scatterers: {direct_rot:.0f} s/rotation "
          f"(timed on {n_direct} chirps)   ratio: {direct_rot / per_rot:.0f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--record-frames", type=int, default=6)
    ap.add_argument("--iq-frames", type=int, default=3)
    ap.add_argument("--skip-record", action="store_true")
    args = ap.parse_args()
    header()
    import open3d as o3d

    grid, rb = Grid(64, 512), RangeBins(256)
    sc = build_scenario(SceneSpec("L", width=2.0, frames=args.frames, seed=3, grid=grid, range_bins=rb,
                                  lidar_shape=(8, 64), camera_shape=(8, 16)))
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

    if args.iq_frames > 0:
        iq_rotations(s, sc, args.iq_frames)
    if args.skip_record:
        return
    from holodata.synth import SynthSpec, synthesize

    tmp = Path(tempfile.mkdtemp(prefix="holodata-synth-bench-"))
    try:
        t0 = time.perf_counter()
        res = synthesize(tmp / "rec", SynthSpec(corner="T", frames=args.record_frames, seed=5), quiet=True)
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
