"""Benchmark: runtime of the mapping stages against the ray tracing they feed, on one synthetic corner.

``holodata.synth.synthesize`` one corner (default a 400-cycle L corner: 400 radar cycles at 2 Hz =
200 s; the robot drives ~3.5 m and then stands; LiDAR ``--lidar`` at 10 Hz, of which ingest keeps
the scan nearest each radar frame, so slam sees 400 scans; LiDAR and camera at synth's defaults,
64x1024 and 376x672), then times, each in seconds:

* ``ingest`` (``holodata.ingest.ingest``; radar grid ``--radar-grid`` — small, to keep synth fast);
* ``slam`` (``holodata.mapping.slam.slam_scene``: kiss-icp + scan-to-map refinement + static mesh);
* ``register`` (``holodata.mapping.register.register_scene``: LiDAR segmentation, camera extrinsic,
  human surfaces; its own phases are printed);
* ``raytrace-gt`` of the same corner through the SLAM mesh, radar poses and register's human surfaces,
  ``GTConfig()`` (64x512 beams, 3 bounces): the work of ``holodata raytrace-gt DATASET`` at the paper's
  beam grid;

and prints (slam + register) / raytrace-gt as a ratio (mapping must not dominate; aim < 1) and
slam + register's share of the four stages' wall time, with the load average before and after (2
shared cores: compare ratios from the same run). slam's ATE
and mesh F@5cm against ``truth/`` are printed too, so a speed-up that costs accuracy shows.

``--gt-diff`` also ray-traces the *true* mesh (``truth/mesh.ply``, people removed) at the true radar
poses and prints, per bounce, the median |range(SLAM-mesh GT) - range(truth-mesh GT)| over beams
valid in both (cm).

The measurements (per date, with the load and the code they ran): ``benchmarks/results/pipeline.md``.

    .venv/bin/python benchmarks/pipeline.py [--frames 400] [--corner L] [--lidar 64x1024] [--camera 376x672] [--walkers 0]
                                            [--gt-diff] [--keep DIR] [--reuse] [--repeat N]

``--repeat N``: N passes of slam (recomputed), register and raytrace-gt after the one ingest; the
table shows each stage's median (and range), and the ratio of every pass.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from _run import header

from holodata.conventions import Grid, RangeBins
from holodata.dataset import create_dataset, open_dataset
from holodata.ingest import ingest


def cpu() -> float:
    """CPU seconds of this process and its finished children (ray-tracing workers), all threads."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def load() -> str:
    return "load {:.1f}/{:.1f}/{:.1f}".format(*os.getloadavg())


def gt_range_diff(a_url: str, b_url: str) -> dict:
    """Per bounce: median and p90 |range_a - range_b| (cm) over beams with a return in both."""
    a, b = open_dataset(a_url), open_dataset(b_url)
    sa, sb = a.scene(a.scenes[0]), b.scene(b.scenes[0])
    ra = np.asarray(sa["gt/range"][...], np.float64)
    rb = np.asarray(sb["gt/range"][...], np.float64)
    out = {}
    for k in range(min(ra.shape[1], rb.shape[1])):  # gt/range (T, bounce, H, W)
        x, y = ra[:, k], rb[:, k]
        ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
        d = np.abs(x[ok] - y[ok]) * 100
        out[f"bounce{k + 1}"] = {"median_cm": float(np.median(d)) if len(d) else float("nan"),
                                 "p90_cm": float(np.percentile(d, 90)) if len(d) else float("nan"),
                                 "beams_both": int(ok.sum()),
                                 "only_one": int((np.isfinite(x) & (x > 0)).sum() + (np.isfinite(y) & (y > 0)).sum()
                                                 - 2 * ok.sum())}
    return out


STAGES = ("slam", "register", "raytrace-gt")


def mapping_and_gt(url: str, sid: str, work: Path) -> tuple[dict, dict, object, dict]:
    """One timed pass of slam (recomputed), register and raytrace-gt on the ingested dataset ``url``:
    (wall s by stage, CPU s by stage, slam's result, register's summary)."""
    from holodata.groundtruth import GTConfig, HumanDataset, RaytraceStandalone
    from holodata.mapping import slam as S
    from holodata.mapping.register import register_scene
    from holodata.meshio import Mesh, write_ply
    from holodata.trajectory import Trajectory, write_tum

    rows, cpus = {}, {}
    t0, c0 = time.perf_counter(), cpu()
    res = S.slam_scene(url, sid, quiet=True, outputs=S.SlamOutputs(force=True))
    rows["slam"], cpus["slam"] = time.perf_counter() - t0, cpu() - c0
    ds = open_dataset(url)
    w = create_dataset(url, grid=ds.grid, range_bins=ds.range_bins).scene(sid)
    if "lidar/instance" in w.arrays():       # (a later pass's register segments again, as the first one does)
        w.remove("lidar/instance")
    t0, c0 = time.perf_counter(), cpu()
    reg = {}
    try:
        reg = register_scene(url, sid, quiet=True, force=True)
    except Exception as err:  # noqa: BLE001 - report and go on: the table still times it
        reg = {"error": str(err)[:200]}
    rows["register"], cpus["register"] = time.perf_counter() - t0, cpu() - c0
    sc = open_dataset(url).scene(sid)
    write_ply(work / "slam_mesh.ply", Mesh(res.mesh[0], res.mesh[1]))
    write_tum(work / "radar.tum", Trajectory(np.asarray(sc["time/timestamp_ns"][...], np.int64), res.T_world_radar))
    shutil.rmtree(work / "gt.zarr", ignore_errors=True)
    t0, c0 = time.perf_counter(), cpu()
    # what `holodata raytrace-gt DATASET` traces: the mesh and register's human surfaces, at 64x512
    # (the dataset's own radar grid is kept small to keep synth and ingest fast)
    RaytraceStandalone(work / "slam_mesh.ply", work / "radar.tum", str(work / "gt.zarr"), cfg=GTConfig(),
                       human=HumanDataset(url, sid), quiet=True).run()
    rows["raytrace-gt"], cpus["raytrace-gt"] = time.perf_counter() - t0, cpu() - c0
    return rows, cpus, res, reg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=400, help="radar cycles (2 Hz)")
    ap.add_argument("--corner", default="L")
    ap.add_argument("--lidar", default="64x1024", help="beams x columns (holodata synth's default)")
    ap.add_argument("--camera", default="376x672", help="rows x cols (holodata synth's default)")
    ap.add_argument("--radar-grid", default="16x64x32", help="synth radar heatmap H x W x range bins (ingest cost)")
    ap.add_argument("--walkers", type=int, default=0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--gt-diff", action="store_true", help="also compare SLAM-mesh GT with truth-mesh GT per bounce")
    ap.add_argument("--keep", default=None)
    ap.add_argument("--reuse", action="store_true", help="with --keep: reuse the synthesised recording there")
    ap.add_argument("--repeat", type=int, default=1, help="passes of slam, register and raytrace-gt (medians printed: "
                    "this 2-core machine's wall times vary by 10-20 %% from run to run)")
    args = ap.parse_args()
    header()
    from holodata.evaluate.slam_accuracy import evaluate_slam
    from holodata.groundtruth import GTConfig, RaytraceStandalone
    from holodata.meshio import Mesh, write_ply
    from holodata.synth import SynthSpec, synthesize

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="holodata-pipeline-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        rec = work / "syn" / "recording"
        truth_dir = work / "syn" / "truth"
        H, W, B = (int(v) for v in args.radar_grid.split("x"))
        if not (args.reuse and rec.exists()):
            shutil.rmtree(work / "syn", ignore_errors=True)
            t0 = time.perf_counter()
            synthesize(work / "syn", SynthSpec(corner=args.corner, frames=args.frames, seed=args.seed, grid=Grid(H, W),
                                               range_bins=RangeBins(B), lidar_shape=tuple(int(v) for v in args.lidar.split("x")),
                                               camera_shape=tuple(int(v) for v in args.camera.split("x")),
                                               visible_walkers=args.walkers), quiet=True)
            print(f"synth {time.perf_counter() - t0:.1f} s", flush=True)
        url = str(work / "ds.zarr")
        for p in (work / "ds.zarr", work / "gt.zarr", work / "gt_truth.zarr", work / "gt_slam_truthposes.zarr"):
            shutil.rmtree(p, ignore_errors=True)
        l0 = load()
        t0, c0 = time.perf_counter(), cpu()
        ingest([rec], url, quiet=True)
        ingest_s, ingest_cpu = time.perf_counter() - t0, cpu() - c0
        sid = open_dataset(url).scenes[0]
        passes = []
        for _ in range(max(1, args.repeat)):
            passes.append(mapping_and_gt(url, sid, work))
        rows = {"ingest": ingest_s, **{k: float(np.median([p[0][k] for p in passes])) for k in STAGES}}
        cpus = {"ingest": ingest_cpu, **{k: float(np.median([p[1][k] for p in passes])) for k in STAGES}}
        res, reg = passes[-1][2], passes[-1][3]
        l1 = load()
        acc = evaluate_slam(res.trajectory(), res.mesh, truth_dir)
        print(f"{args.corner} corner, {args.frames} radar cycles, LiDAR {args.lidar}, {res.summary['scans']} scans, "
              f"walkers {args.walkers} | slam ATE {acc['trajectory']['ate_rmse_m'] * 100:.2f} cm, mesh F@5cm "
              f"{acc['mesh']['f_5cm']:.3f} | {os.cpu_count()} cores, {l0} before, {l1} after")
        print(f"  slam phases {json.dumps(res.summary['timings'])}  health {json.dumps(res.summary['health'])}")
        print(f"  register phases {json.dumps(reg.get('timings', reg.get('error')))}")
        many = len(passes) > 1
        print(f"  {'stage':14s} {'wall s':>8s} {'CPU s':>8s}   (CPU: all threads and worker processes"
              + (f"; medians of {len(passes)} passes of slam, register, raytrace-gt, one ingest)" if many else ")"))
        for k, v in rows.items():
            spread = ""
            if many and k in STAGES:
                w = [p[0][k] for p in passes]
                spread = f"   ({min(w):.1f}-{max(w):.1f})"
            print(f"  {k:14s} {v:8.1f} {cpus[k]:8.1f}{spread}")
        sr, sc_ = rows["slam"] + rows["register"], cpus["slam"] + cpus["register"]
        print(f"  {'slam+register':14s} {sr:8.1f} {sc_:8.1f}   = {sr / rows['raytrace-gt']:.2f}x raytrace-gt wall, "
              f"{sc_ / cpus['raytrace-gt']:.2f}x its CPU (slam alone {rows['slam'] / rows['raytrace-gt']:.2f}x wall, "
              f"{cpus['slam'] / cpus['raytrace-gt']:.2f}x CPU)", flush=True)
        if many:
            ratios = [(p[0]["slam"] + p[0]["register"]) / p[0]["raytrace-gt"] for p in passes]
            print("  (slam+register) / raytrace-gt per pass: " + ", ".join(f"{r:.2f}x" for r in ratios))
        total = sum(rows.values())
        print(f"  slam+register = {100 * sr / total:.0f} % of the pipeline's wall time (ingest + slam + register + "
              f"raytrace-gt = {total:.1f} s); largest stage: {max(rows, key=rows.get)}", flush=True)
        if args.gt_diff:
            from holodata.meshio import read_mesh

            tm = read_mesh(truth_dir / "mesh.ply")
            hum = [k for k, n in tm.class_names.items() if str(n) == "human"]
            keep = ~np.isin(tm.face_class, hum) if tm.face_class is not None else np.ones(len(tm.faces), bool)
            write_ply(work / "truth_static.ply", Mesh(tm.vertices, tm.faces[keep]))
            RaytraceStandalone(work / "truth_static.ply", truth_dir / "trajectory_radar.tum",
                               str(work / "gt_truth.zarr"), cfg=GTConfig(), quiet=True).run()
            # the SLAM GT again at the true radar poses: the difference is the mesh's alone
            RaytraceStandalone(work / "slam_mesh.ply", truth_dir / "trajectory_radar.tum",
                               str(work / "gt_slam_truthposes.zarr"), cfg=GTConfig(), quiet=True).run()
            d = gt_range_diff(str(work / "gt_slam_truthposes.zarr"), str(work / "gt_truth.zarr"))
            print("  GT range |slam mesh - true mesh| (true radar poses): " + "  ".join(
                f"{k} median {v['median_cm']:.1f} cm p90 {v['p90_cm']:.1f} cm ({v['beams_both']} beams)"
                for k, v in d.items()))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
