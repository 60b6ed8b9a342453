"""Benchmark: LiDAR-grid human segmentation (``holodata.mapping.segment``) — AP50 per corner kind,
LiDAR vertical field of view and LiDAR resolution, and its runtime against a bare labelling.

For each (FOV, LiDAR shape, corner kind): ``holodata.synth.synthesize`` a recording with ``--walkers``
people walking in the robot's corridor (truth instance masks in ``truth/lidar_instances.npz``; small
radar grid to keep synth fast), ``holodata.ingest`` it, write the *true* LiDAR poses
(``human_eval.write_truth_poses``: isolates segmentation from SLAM error), run ``segment_scene`` and
score ``lidar/instance`` with ``human_eval.segmentation_ap50`` (AP at IoU 0.5, truth people with
< 20 returns ignored). FOV 33.2 deg is the synth default (OS1-like), 90 deg OS0-like
(``holodata synth --lidar-fov 90``).

Runtime: the per-scan core ``segment_scan`` (shrink, flood fill, merge, checks; inputs prepared)
vs bare ``scipy.ndimage.label`` (8-connectivity) on the same scans' foreground masks (returns
outside the background) in the same run, best of 3: ratio = segment_scan / label. Also printed:
``segment_scene`` per scan end to end (reading, de-skewing, background lookup, writing) and the
background model's build time (once per scene).

    .venv/bin/python benchmarks/segment.py [--fovs 33.2,90] [--lidars 64x1024,64x512,32x512]
        [--corners T,L,cross,oblique] [--frames 12] [--walkers 2] [--seed 1] [--keep DIR]

``--keep DIR`` keeps (and on a rerun reuses) the recordings and datasets.

Measurements of the default run (per date, with the load and the code they ran):
``benchmarks/results/segment.md``.
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def prepare(root: Path, corner: str, fov: float, lidar: tuple, args) -> tuple[str, Path, float]:
    """Recording -> dataset with true poses; returns (url, truth_dir, seconds)."""
    from holodata.conventions import Grid, RangeBins
    from holodata.dataset import open_dataset
    from holodata.ingest import ingest
    from holodata.mapping.human_eval import write_truth_poses
    from holodata.synth import synthesize

    t0 = time.perf_counter()
    d = root / f"fov{fov:g}_{lidar[0]}x{lidar[1]}_{corner}_s{args.seed}_f{args.frames}_w{args.walkers}"
    url = d / "ds.zarr"
    truth = d / "rec" / "truth"
    if not (d / "ready").is_file():
        shutil.rmtree(d, ignore_errors=True)
        synthesize(d / "rec", corner=corner, frames=args.frames, seed=args.seed, grid=Grid(8, 32),
                   range_bins=RangeBins(n=64), lidar_shape=lidar, camera_shape=(94, 168), quiet=True,
                   visible_walkers=args.walkers, lidar_vertical_fov_deg=fov)
        ingest([d / "rec" / "recording"], str(url), quiet=True)
        write_truth_poses(str(url), open_dataset(str(url)).scenes[0], truth)
        (d / "ready").write_text("ok\n")
    return str(url), truth, time.perf_counter() - t0


def core_timing(url: str, sid: str, bg, cfg) -> dict:
    """Seconds of :func:`segment_scan` on every scan (inputs prepared beforehand: points, background
    masks, grid geometry) and of bare ``scipy.ndimage.label`` (8-connectivity) on the same scans'
    foreground masks (returns outside the background), best of 3 passes each."""
    from scipy import ndimage

    from holodata.dataset import open_dataset
    from holodata.mapping.segment import LidarScans, background_masks, grid_geometry, segment_scan

    scans = LidarScans.open(open_dataset(url).scene(sid), url)
    traj = scans.trajectory()
    shifts, elev = grid_geometry(scans)
    prep = []
    for k in range(len(scans.stamps)):
        valid, P, Pw = scans.scan(k, traj, cfg.deskew)
        if not valid.any():
            continue
        bgm = background_masks(bg, valid, Pw, cfg)
        prep.append((P, valid, bgm, np.where(valid[..., None], Pw, 0.0)))
    st = np.ones((3, 3), bool)
    t_seg, t_lab = np.inf, np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for P, valid, bgm, pw in prep:
            segment_scan(P, valid, bgm, cfg, points_world=pw, floor=bg.floor, shifts=shifts, elev=elev)
        t_seg = min(t_seg, time.perf_counter() - t0)
        masks = [valid & ~bgm for P, valid, bgm, pw in prep]
        t0 = time.perf_counter()
        for m in masks:
            ndimage.label(m, structure=st)
        t_lab = min(t_lab, time.perf_counter() - t0)
    return {"segment_scan_s": t_seg, "label_s": t_lab, "scans": len(prep)}


def run_one(root: Path, corner: str, fov: float, lidar: tuple, args) -> dict:
    from holodata.dataset import open_dataset
    from holodata.mapping.human_eval import segmentation_ap50
    from holodata.mapping.segment import LidarScans, SegmentConfig, build_background, segment_scene

    url, truth, prep = prepare(root, corner, fov, lidar, args)
    sid = open_dataset(url).scenes[0]
    cfg = SegmentConfig()
    scans = LidarScans.open(open_dataset(url).scene(sid), url)
    t0 = time.perf_counter()
    bg = build_background(scans, cfg, scans.trajectory())
    t_bg = time.perf_counter() - t0
    t0 = time.perf_counter()
    s = segment_scene(url, sid, cfg=cfg, overwrite=True, background=bg)
    t_seg = time.perf_counter() - t0
    ap = segmentation_ap50(url, sid, truth)
    ct = core_timing(url, sid, bg, cfg)
    return {"corner": corner, "fov": fov, "lidar": f"{lidar[0]}x{lidar[1]}", "prep_s": prep, "background_s": t_bg,
            "segment_scene_s": t_seg, "scans": ct["scans"], **ct, "ratio": ct["segment_scan_s"] / max(ct["label_s"], 1e-9),
            "instances_per_scan": s["instances_per_scan"], "ap50": ap}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fovs", default="33.2,90")
    ap.add_argument("--lidars", default="64x1024,64x512,32x512")
    ap.add_argument("--corners", default="T,L,cross,oblique")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--walkers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", default=None, help="keep (and reuse) the recordings/datasets in this folder")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="holodata-bench-segment-"))
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"load average at start: {os.getloadavg()[0]:.2f} (2 shared cores; timings are noisy)", flush=True)
    try:
        for fov in (float(v) for v in args.fovs.split(",")):
            for lid in args.lidars.split(","):
                lidar = tuple(int(v) for v in lid.split("x"))
                for c in args.corners.split(","):
                    r = run_one(root, c, fov, lidar, args)
                    rows.append(r)
                    a = r["ap50"]
                    n = max(r["scans"], 1)
                    print(f"fov {fov:5.1f} {r['lidar']:>8s} {c:8s} AP50 {a['ap']:.3f} (P {a['precision']:.2f} "
                          f"R {a['recall']:.2f}, {a['n_truth']} people-scans, {a['n_pred']} predictions) | segment_scan "
                          f"{1000 * r['segment_scan_s'] / n:.1f} ms/scan vs scipy.ndimage.label "
                          f"{1000 * r['label_s'] / n:.2f} ms/scan = x{r['ratio']:.0f} | segment_scene (read, deskew, "
                          f"write) {1000 * r['segment_scene_s'] / n:.0f} ms/scan, background {r['background_s']:.1f} s "
                          f"| load {os.getloadavg()[0]:.2f}", flush=True)
        if args.json:
            print(json.dumps(rows, indent=1, default=float))
        print("\nAP50 table (rows: FOV / LiDAR, columns: corners)")
        corners = args.corners.split(",")
        print(f"{'':16s}" + "".join(f"{c:>9s}" for c in corners) + f"{'min':>9s}")
        for fov in (float(v) for v in args.fovs.split(",")):
            for lid in args.lidars.split(","):
                vals = [r["ap50"]["ap"] for r in rows if r["fov"] == fov and r["lidar"] == lid]
                print(f"{fov:5.1f} {lid:>10s}" + "".join(f"{v:9.3f}" for v in vals) + f"{min(vals):9.3f}")
        ok = all(r["ap50"]["ap"] >= 0.9 for r in rows)
        print("floor (AP50 >= 0.9 everywhere):", "met" if ok else "NOT met")
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
