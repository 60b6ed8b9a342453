"""Benchmark: `holodata raytrace-gt` (standalone form, writing included) on a T-junction corridor.

Builds a T-junction mesh from subdivided planes (~10 cm triangles, like a SLAM mesh), a walking
box-and-prism human (one mesh per frame via --human-dir), a radar trajectory through the junction,
then:
  1. runs the whole standalone pipeline (read inputs, trace 64x512 beams x 3 bounces + LOS checks,
     write gt/* shards) and reports frames/s (in this process, which has cast already: a helper
     process, when raytrace-gt takes one, is spawned here, forked by the command in 3.);
  2. replays, on a sample of frames, the ray batches of the straightforward trace (the tracer with
     its human culling switched off: every ray also against the human) through bare open3d
     ``RaycastingScene.cast_rays`` / ``test_occlusions`` (the LOS checks) (static scene built once,
     human scene per frame) in the same run, and prints the ratio  bare time / pipeline time  per
     frame (1.0 = no overhead), wall and CPU;
  3. runs the ``holodata raytrace-gt`` command itself as a subprocess (start-up and imports
     included) and prints its ratios (--skip-cli to skip), then the same command on the first
     frame alone: its fixed cost (interpreter, imports, inputs, output, exit), and the ratios that
     cost leaves reachable at this frame count even if every frame were traced at the bare speed;
     and bare open3d as a process of its own doing the same work (interpreter, ``import open3d``,
     reading the mesh, building the scene, then the frames at the bare speed of 2.), the ratio of
     the raw library to the command that counts both sides' start-up;
  4. runs the pipeline in subprocesses for 100 and 1000 frames and prints their peak RSS;
  5. extrapolates to HoloRadar scale (28k frames).

    .venv/bin/python benchmarks/raytrace.py [--frames 600] [--processes N] [--rss-grid 64x512] [--skip-rss]
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

from holodata.conventions import Grid
from holodata.meshio import Mesh, merge_meshes, write_ply
from holodata.trajectory import Trajectory, read_tum, write_tum


def plane(p0, u, v, nu, nv):
    """Rectangle p0 + a u + b v (a, b in [0,1]) as an nu x nv grid of quads (2 nu nv triangles)."""
    a, b = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    verts = np.asarray(p0, float) + a.reshape(-1, 1) * np.asarray(u, float) + b.reshape(-1, 1) * np.asarray(v, float)
    idx = np.arange(verts.shape[0]).reshape(nu + 1, nv + 1)
    q0, q1, q2, q3 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return verts, np.concatenate([np.stack([q0, q1, q2], 1), np.stack([q0, q2, q3], 1)])


def merge(parts):
    v, f = merge_meshes(parts)
    return v, f.astype(np.int32)


def t_junction(res=0.1, width=2.0, length=12.0, height=2.6):
    """Corridor A along x (y in [0,width], x in [-length, length]); corridor B leaves at x in
    [0,width] towards +y up to y = length. Walls, floor and ceiling as ~res triangles."""
    w, L, h = width, length, height
    walls = [((-L, 0), (L, 0)), ((L, 0), (L, w)), ((L, w), (w, w)), ((w, w), (w, L)), ((w, L), (0, L)),
             ((0, L), (0, w)), ((0, w), (-L, w)), ((-L, w), (-L, 0))]
    parts = []
    for (x0, y0), (x1, y1) in walls:
        ln = np.hypot(x1 - x0, y1 - y0)
        parts.append(plane([x0, y0, 0], [x1 - x0, y1 - y0, 0], [0, 0, h], max(1, int(ln / res)), max(1, int(h / res))))
    for z in (0.0, h):  # floor and ceiling: corridor A strip + corridor B strip
        parts.append(plane([-L, 0, z], [2 * L, 0, 0], [0, w, 0], int(2 * L / res), int(w / res)))
        parts.append(plane([0, w, z], [w, 0, 0], [0, L - w, 0], int(w / res), int((L - w) / res)))
    return merge(parts)


def human_at(center, phase):
    """A ~2k-triangle walking human: torso box + 4 swinging limbs + head (subdivided boxes)."""
    parts = []

    def cuboid(c, s, n=4):
        c, s = np.asarray(c, float), np.asarray(s, float)
        out = []
        for ax in range(3):
            for sgn in (-1, 1):
                u, v = [np.eye(3)[k] * s[k] for k in range(3) if k != ax]
                p0 = c - s / 2 + (sgn > 0) * np.eye(3)[ax] * s[ax]
                out.append(plane(p0, u, v, n, n))
        return merge(out)

    sw = 0.25 * np.sin(phase)
    parts.append(cuboid([0, 0, 1.2], [0.25, 0.4, 0.6], 8))
    parts.append(cuboid([0, 0, 1.65], [0.2, 0.2, 0.25], 6))
    for side, s in ((-0.1, sw), (0.1, -sw)):
        parts.append(cuboid([s, side, 0.45], [0.12, 0.12, 0.9], 8))
        parts.append(cuboid([-s, side * 2.4, 1.15], [0.08, 0.08, 0.6], 6))
    v, f = merge(parts)
    return v + np.asarray(center, float), f


def make_inputs(d: Path, frames: int) -> None:
    v, f = t_junction()
    write_ply(d / "scene.ply", Mesh(v, f))
    t = np.arange(frames) * 500_000_000 + 10**9  # 2 Hz rotation cycles
    x = np.linspace(-9.0, -1.0, frames)  # radar drives along corridor A towards the junction
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3] = x, 1.0, 0.9
    write_tum(d / "radar.tum", Trajectory(t, poses))
    hd = d / "humans"
    hd.mkdir(exist_ok=True)
    for k in range(frames):  # the human walks up corridor B, around the corner
        hv, hf = human_at([1.0, 3.0 + 4.0 * k / max(frames - 1, 1), 0.0], k * 0.6)
        write_ply(hd / f"{k:06d}.ply", Mesh(hv, hf))


def run_pipeline(d: Path, grid: str, out: Path, quiet=True, codec=None, processes: int = 0) -> dict:
    from holodata.groundtruth import GTConfig, RaytraceStandalone

    cfg = GTConfig(grid=Grid.parse(grid, "-45,45"), codec=codec)
    return RaytraceStandalone(d / "scene.ply", d / "radar.tum", str(out), human_dir=d / "humans", cfg=cfg, quiet=quiet,
                              processes=processes).run()


def bare_replay(d: Path, grid: str, sample: list[int]) -> tuple[float, float, int]:
    """Wall and CPU seconds per frame of bare open3d casts replaying the tracer's own ray batches."""
    import open3d as o3d

    from holodata.groundtruth import GTConfig, trace_frame
    from holodata.meshio import read_mesh
    from holodata.raytrace import RayScene
    from holodata.trajectory import read_tum

    m = read_mesh(d / "scene.ply")
    traj = read_tum(d / "radar.tum")
    cfg = GTConfig(grid=Grid.parse(grid, "-45,45"))
    sc = RayScene(m.vertices, m.faces)
    sc.cull_dynamic = False  # the straightforward ray set: every ray also against the human (see main's note)
    static = o3d.t.geometry.RaycastingScene()
    static.add_triangles(o3d.core.Tensor(m.vertices.astype(np.float32)), o3d.core.Tensor(m.faces.astype(np.uint32)))
    total, cpu, n_rays = 0.0, 0.0, 0
    for k in sample:
        h = read_mesh(d / "humans" / f"{k:06d}.ply")
        sc.cast_log = []
        trace_frame(sc, cfg, traj, k, (h.vertices, h.faces))
        log, sc.cast_log = sc.cast_log, None
        t0, c0 = time.perf_counter(), time.process_time()
        dyn = o3d.t.geometry.RaycastingScene()
        dyn.add_triangles(o3d.core.Tensor(h.vertices.astype(np.float32)), o3d.core.Tensor(h.faces.astype(np.uint32)))
        for which, rays in log:
            target = static if which.startswith("static") else dyn
            if which.endswith(":occluded"):
                target.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=1.0).numpy()
            else:
                target.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy()
        total += time.perf_counter() - t0
        cpu += time.process_time() - c0
        n_rays += sum(len(r) for _, r in log)
    return total / len(sample), cpu / len(sample), n_rays // len(sample)


def cpu_seconds() -> float:
    """CPU seconds of this process plus its finished children (the tracing workers)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def rss_child(frames: int, grid: str) -> None:
    d = Path(tempfile.mkdtemp(prefix="hd_rss_"))
    try:
        make_inputs(d, frames)
        t0 = time.perf_counter()
        run_pipeline(d, grid, d / "out.zarr")
        dt = time.perf_counter() - t0
        print(json.dumps({"frames": frames, "grid": grid, "seconds": dt,
                          "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                          "peak_rss_worker_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))
    finally:
        shutil.rmtree(d, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--grid", default="64x512")
    ap.add_argument("--sample", type=int, default=20, help="frames replayed through bare cast_rays")
    ap.add_argument("--rss-grid", default="64x512", help="grid of the 100/1000-frame RSS runs")
    ap.add_argument("--skip-rss", action="store_true")
    ap.add_argument("--skip-cli", action="store_true", help="skip the run of the holodata raytrace-gt command itself")
    ap.add_argument("--codec", choices=["lz4", "zstd"], default="lz4", help="gt codec (raytrace-gt's default: lz4)")
    ap.add_argument("--processes", type=int, default=0, help="raytrace-gt --processes (0: its automatic choice)")
    ap.add_argument("--rss-child", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.rss_child:
        rss_child(a.rss_child, a.rss_grid)
        return
    header()
    d = Path(tempfile.mkdtemp(prefix="hd_bench_"))
    try:
        make_inputs(d, a.frames)
        v, f = t_junction()
        print(f"T-junction mesh: {len(f)} triangles; human ~{len(human_at([0, 0, 0], 0)[1])} triangles; "
              f"grid {a.grid}, 3 bounces, {a.frames} frames, codec {a.codec}, {os.cpu_count()} CPUs")
        # bare casts are replayed half before and half after the pipeline run (the machine is shared)
        sample = list(np.linspace(0, a.frames - 1, min(a.sample, a.frames)).astype(int))
        b1, c1, n_rays = bare_replay(d, a.grid, sample[0::2])
        cpu0, t0 = cpu_seconds(), time.perf_counter()
        summary = run_pipeline(d, a.grid, d / "out.zarr", codec=a.codec, processes=a.processes)
        dt = time.perf_counter() - t0
        cpu = cpu_seconds() - cpu0
        b2, c2, _ = bare_replay(d, a.grid, sample[1::2])
        bare, bare_cpu = (b1 + b2) / 2, (c1 + c2) / 2
        fps = a.frames / dt
        ratio = bare / (dt / a.frames)
        print(f"raytrace-gt (standalone, writing included): {dt:.2f} s, {fps:.2f} frames/s "
              f"({1e3 * dt / a.frames:.1f} ms/frame); dataset {du(d / 'out.zarr'):.0f} MB")
        print(f"bare open3d cast_rays/test_occlusions, same {n_rays} rays/frame: {1e3 * bare:.1f} ms/frame "
              f"(before {1e3 * b1:.1f}, after {1e3 * b2:.1f}) -> ratio {ratio:.2f} (floor 0.5, aim 0.8)")
        print(f"CPU time (all processes): raytrace-gt {1e3 * cpu / a.frames:.1f} ms/frame, bare {1e3 * bare_cpu:.1f} "
              f"ms/frame -> CPU ratio {bare_cpu / (cpu / a.frames):.2f} (insensitive to other load on the machine)")
        sm = summary["scenes"][0]
        steady = (sm["seconds"] - sm["first_frame_s"]) / (a.frames - 1)
        helper = f", helper process {sm['helper']}ed" if sm.get("helper") else ""
        print(f"  of which start-up (inputs, {sm['processes']} tracing processes{helper}, first frame): "
              f"{dt - sm['seconds'] + sm['first_frame_s']:.2f} s; steady state {1e3 * steady:.1f} ms/frame "
              f"-> steady-state ratio {bare / steady:.2f}")
        print(f"extrapolated to 28000 frames: {(dt + 27999 * steady) / 60:.1f} min "
              f"(start-up + steady state; {28000 / fps / 60:.1f} min at this run's average)")
        if not a.skip_cli:  # the command itself: interpreter start-up and imports included
            cdt, ccpu = run_command(d, a.grid, a.processes)
            print(f"holodata raytrace-gt command (subprocess, start-up and imports included): {cdt:.2f} s, "
                  f"{1e3 * cdt / a.frames:.1f} ms/frame -> ratio {bare / (cdt / a.frames):.2f}; CPU "
                  f"{1e3 * ccpu / a.frames:.1f} ms/frame -> CPU ratio {bare_cpu / (ccpu / a.frames):.2f}")
            # the command's fixed cost (interpreter, imports, reading the mesh, creating the output, exit):
            # the same command on the first frame alone; it bounds the ratio a run of N frames can reach
            one = d / "one"
            (one / "humans").mkdir(parents=True)
            traj = read_tum(d / "radar.tum")
            write_tum(one / "radar.tum", Trajectory(traj.timestamp_ns[:1], traj.poses[:1]))
            shutil.copy(d / "humans" / "000000.ply", one / "humans" / "000000.ply")
            shutil.copy(d / "scene.ply", one / "scene.ply")
            fdt, fcpu = run_command(one, a.grid, a.processes)
            n_bare, n_bare_cpu = a.frames * bare, a.frames * bare_cpu
            print(f"  its fixed cost (the command on 1 frame): {fdt:.2f} s wall, {fcpu:.2f} s CPU -> even tracing at the "
                  f"bare speed, {a.frames} frames reach at most ratio {n_bare / (n_bare + fdt):.2f}, CPU ratio "
                  f"{n_bare_cpu / (n_bare_cpu + fcpu):.2f}")
            sdt, scpu = bare_process_startup(d)
            print(f"bare open3d as its own process (interpreter, import open3d, read the mesh, build the scene): "
                  f"{sdt:.2f} s wall, {scpu:.2f} s CPU; with {a.frames} frames at the bare speed -> command ratio "
                  f"{(sdt + n_bare) / cdt:.2f}, CPU ratio {(scpu + n_bare_cpu) / ccpu:.2f} (both sides' start-up counted)")
        if not a.skip_rss:
            for n in (100, 1000):
                r = subprocess.run([sys.executable, __file__, "--rss-child", str(n), "--rss-grid", a.rss_grid],
                                   capture_output=True, text=True, check=True)
                info = json.loads(r.stdout.strip().splitlines()[-1])
                print(f"peak RSS {n:5d} frames ({info['grid']}): main process {info['peak_rss_mb']:.0f} MB, "
                      f"largest tracing worker {info['peak_rss_worker_mb']:.0f} MB ({n / info['seconds']:.2f} frames/s)")
        print(json.dumps({"frames_per_s": round(fps, 3), "ratio": round(ratio, 3),
                          "cpu_ratio": round(bare_cpu / (cpu / a.frames), 3), "summary": summary["scenes"][0]}))
    finally:
        shutil.rmtree(d, ignore_errors=True)


def run_command(d: Path, grid: str, processes: int) -> tuple[float, float]:
    """Wall and CPU seconds of ``holodata raytrace-gt`` (standalone form) on the inputs in ``d``, as a subprocess."""
    r0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run([str(Path(sys.executable).with_name("holodata")), "raytrace-gt", "--mesh", str(d / "scene.ply"),
                    "--poses", str(d / "radar.tum"), "--human-dir", str(d / "humans"), "--out",
                    str(d / "cli.zarr"), "--grid", grid, "--processes", str(processes)],
                   check=True, capture_output=True)
    dt = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    shutil.rmtree(d / "cli.zarr", ignore_errors=True)
    return dt, r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime


BARE_STARTUP = """
import sys
import numpy as np
import open3d as o3d
m = o3d.io.read_triangle_mesh(sys.argv[1])
scene = o3d.t.geometry.RaycastingScene()
scene.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)), o3d.core.Tensor(np.asarray(m.triangles, np.uint32)))
"""


def bare_process_startup(d: Path) -> tuple[float, float]:
    """Wall and CPU seconds of a Python process that imports open3d, reads ``d``/scene.ply with it and
    builds its raycasting scene: the start-up bare open3d pays as a program of its own."""
    r0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run([sys.executable, "-c", BARE_STARTUP, str(d / "scene.ply")], check=True, capture_output=True)
    dt = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return dt, r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime


def du(p: Path) -> float:
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) / 1e6 if p.exists() else 0.0


if __name__ == "__main__":
    main()
