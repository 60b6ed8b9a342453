"""Benchmark: LiDAR-grid human segmentation (``holodata.mapping.segment``) — AP50 per corner kind,
LiDAR vertical field of view and LiDAR resolution, and its runtime against a bare labelling.

For each (FOV, LiDAR shape, corner kind): ``holodata.synth.synthesize`` a recording with ``--walkers``
people walking in the robot's corridor (truth instance masks in ``truth/lidar_instances.npz``; small
radar grid to keep synth fast), ``holodata.ingest`` it, write the *true* LiDAR poses
(``register_accuracy.write_truth_poses``: isolates segmentation from SLAM error), run ``segment_scene`` and
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

``--family heldout``: the same segmentation on the recordings of
:mod:`holodata.synth.heldout`, a family nothing was tuned on (LiDAR-only, an L corridor driven
through, furniture, 32/64/128 beams over 45 or 90 deg, a human-shaped or boxy person walking in the
hidden leg; ``benchmarks/_heldout.py``: ``--variants``, ``--seeds``), scored against the held-out
truth's exact masks (``truth/lidar_instances.npz``: the returns on the person) with the true LiDAR
poses and, with ``--poses truth,slam``, with slam's. Besides AP50 it prints recall by the person's
range (median range of its returns) and the false positives per 100 scans, which say *why* a cell
is low. Shares its ``--keep DIR`` with ``benchmarks/register.py --family heldout`` and
``benchmarks/slam.py --family heldout``. Results: ``benchmarks/results/segment.md``.

    .venv/bin/python benchmarks/segment.py --family heldout [--variants ...] [--seeds 1,2]
        [--poses truth,slam] [--keep DIR]

Measurements of the default run (per date, with the load and the code they ran):
``benchmarks/results/segment.md``.
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


def prepare(root: Path, corner: str, fov: float, lidar: tuple, args) -> tuple[str, Path, float]:
    """Recording -> dataset with true poses; returns (url, truth_dir, seconds)."""
    from holodata.conventions import Grid, RangeBins
    from holodata.dataset import open_dataset
    from holodata.evaluate.register_accuracy import write_truth_poses
    from holodata.ingest import ingest
    from holodata.synth import SynthSpec, synthesize

    t0 = time.perf_counter()
    d = root / f"fov{fov:g}_{lidar[0]}x{lidar[1]}_{corner}_s{args.seed}_f{args.frames}_w{args.walkers}"
    url = d / "ds.zarr"
    truth = d / "rec" / "truth"
    if not (d / "ready").is_file():
        shutil.rmtree(d, ignore_errors=True)
        synthesize(d / "rec", SynthSpec(corner=corner, frames=args.frames, seed=args.seed, grid=Grid(8, 32),
                                        range_bins=RangeBins(n=64), lidar_shape=lidar, camera_shape=(94, 168),
                                        visible_walkers=args.walkers, lidar_vertical_fov_deg=fov), quiet=True)
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
    from holodata.evaluate.register_accuracy import segmentation_ap50
    from holodata.mapping.segment import SegmentConfig

    url, truth, prep = prepare(root, corner, fov, lidar, args)
    sid = open_dataset(url).scenes[0]
    seg = _segment(url, sid)
    ap = segmentation_ap50(url, sid, truth)
    ct = core_timing(url, sid, seg["background"], SegmentConfig())
    return {"corner": corner, "fov": fov, "lidar": f"{lidar[0]}x{lidar[1]}", "prep_s": prep,
            "background_s": seg["background_s"], "segment_scene_s": seg["segment_scene_s"], "scans": ct["scans"], **ct,
            "ratio": ct["segment_scan_s"] / max(ct["label_s"], 1e-9), "instances_per_scan": seg["instances_per_scan"],
            "ap50": ap}


RANGE_BINS_M = (0.0, 3.0, 6.0, 10.0, np.inf)     # recall by the person's range (m)


CHECKS = {"min_points": 1, "min_height_m": 0.0, "max_width_m": np.inf, "min_depth_m": 0.0, "max_height_m": np.inf}


def miss_cause(scans, k: int, truth_mask: np.ndarray, bg, min_truth_pixels: int = 20) -> str:
    """Why scan ``k`` of ``scans`` (:class:`LidarScans`) lost its person (``truth_mask`` (H,W) bool):
    "background" when at least half its returns fall in the background model ``bg`` (voxels or floor),
    else the name of the :class:`SegmentConfig` check that, switched off alone (:data:`CHECKS`), lets
    :func:`segment_scan` find it, else "split" (no cluster reaches IoU 0.5 whatever the checks)."""
    import dataclasses

    from holodata.evaluate.register_accuracy import match_scan
    from holodata.mapping.segment import SegmentConfig, background_masks, grid_geometry, segment_scan

    cfg = SegmentConfig()
    valid, P, Pw = scans.scan(k, scans.trajectory(), cfg.deskew)
    bgm = background_masks(bg, valid, Pw, cfg)
    if (bgm & truth_mask).sum() >= 0.5 * truth_mask.sum():
        return "background"
    shifts, elev = grid_geometry(scans)
    pw = np.where(valid[..., None], Pw, 0.0)
    for name, off in CHECKS.items():
        lab = segment_scan(P, valid, bgm, dataclasses.replace(cfg, **{name: off}), points_world=pw, floor=bg.floor,
                           shifts=shifts, elev=elev)
        if any(ok for _, ok in match_scan(lab, truth_mask.astype(np.uint16), min_truth_pixels)[0]):
            return name
    return "split"


def score_scans(url: str, sid: str, truth: Path, bg=None, min_truth_pixels: int = 20) -> dict:
    """AP50 (:func:`holodata.evaluate.register_accuracy.segmentation_ap50`) and per scan what it hides: the
    truth people counted (>= ``min_truth_pixels`` returns) and found (a prediction at IoU >= 0.5) by
    the person's range (median ``lidar/range`` of its returns, bins :data:`RANGE_BINS_M`), the
    false positives (predictions on no person at IoU 0.5: a fragment of the person counts) and, given
    the background model ``bg`` the masks were made with, the people missed by cause (:func:`miss_cause`)."""
    from holodata.dataset import open_dataset
    from holodata.dataset.layout import LIDAR_INSTANCE, LIDAR_RANGE, LIDAR_TIMESTAMP_NS
    from holodata.evaluate.register_accuracy import match_scan, segmentation_ap50
    from holodata.mapping.segment import LidarScans
    from holodata.synth.truth import read_lidar_instances

    out = {"ap50": segmentation_ap50(url, sid, truth, min_truth_pixels)}
    tr = read_lidar_instances(Path(truth) / "lidar_instances.npz")
    where = {int(t): i for i, t in enumerate(tr["stamp_ns"])}
    sc = open_dataset(url).scene(sid)
    inst, rng = sc[LIDAR_INSTANCE], sc[LIDAR_RANGE]
    nb = len(RANGE_BINS_M) - 1
    counted, found = np.zeros(nb, int), np.zeros(nb, int)
    fp = scans = 0
    causes: dict[str, int] = {}
    scans_ = None
    for k, st in enumerate(np.asarray(sc[LIDAR_TIMESTAMP_NS][...], np.int64)):
        i = where.get(int(st))
        if i is None:
            continue
        scans += 1
        t = tr["mask"](i)
        res, n = match_scan(np.asarray(inst[k]), t, min_truth_pixels)
        fp += sum(not ok for _, ok in res)
        if n:
            r = float(np.median(np.asarray(rng[k], float)[t > 0]))
            b = int(np.searchsorted(RANGE_BINS_M, r, side="right") - 1)
            counted[b] += n
            hit = sum(ok for _, ok in res)
            found[b] += hit
            if bg is not None and hit < n:
                if scans_ is None:
                    scans_ = LidarScans.open(sc, url)
                c = miss_cause(scans_, k, t > 0, bg, min_truth_pixels)
                causes[c] = causes.get(c, 0) + 1
    out.update({"scans": scans, "counted_by_range": counted.tolist(), "found_by_range": found.tolist(),
                "false_positives": int(fp), "miss_causes": causes})
    return out


def _segment(url: str, sid: str) -> dict:
    """Background model and :func:`segment_scene` with the default :class:`SegmentConfig`; seconds."""
    from holodata.dataset import open_dataset
    from holodata.mapping.segment import LidarScans, SegmentConfig, build_background, segment_scene

    cfg = SegmentConfig()
    scans = LidarScans.open(open_dataset(url).scene(sid), url)
    t0 = time.perf_counter()
    bg = build_background(scans, cfg, scans.trajectory())
    t_bg = time.perf_counter() - t0
    t0 = time.perf_counter()
    s = segment_scene(url, sid, cfg=cfg, overwrite=True, background=bg)
    return {"background_s": t_bg, "segment_scene_s": time.perf_counter() - t0,
            "instances_per_scan": s["instances_per_scan"], "background": bg}


def run_heldout(variant: str, seed: int, poses: list, root: Path) -> dict:
    """One held-out recording: segmentation with the true LiDAR poses (a copy of the dataset,
    ``ds_truth.zarr``) and/or slam's (``ds.zarr``, as register's held-out run uses), scored."""
    from _heldout import prepare_heldout, write_true_lidar_poses

    out = {"variant": variant, "seed": seed}
    for p in poses:
        truth, url, sid = prepare_heldout(variant, seed, root, instances=True,
                                          dataset="ds_truth.zarr" if p == "truth" else "ds.zarr")
        if p == "truth":
            write_true_lidar_poses(url, sid, truth)
        else:
            from holodata.mapping.slam import slam_scene

            slam_scene(url, sid, quiet=True)          # skipped when done (a kept folder)
        seg = _segment(url, sid)
        bg = seg.pop("background")
        out[p] = {**seg, **score_scans(url, sid, truth, bg)}
    return out


def _recall_text(r: dict) -> str:
    return " ".join(f"{f}/{c}" if c else "-" for f, c in zip(r["found_by_range"], r["counted_by_range"]))


def main_heldout(args) -> int:
    from _heldout import heldout_cells

    poses = [p.strip() for p in args.poses.split(",")]
    bins = " ".join(f"{a:g}-{b:g}" for a, b in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:]))
    print(f"load average at start: {os.getloadavg()[0]:.2f} (2 shared cores; timings are noisy)", flush=True)
    print("held-out family (holodata.synth.heldout): AP50 of lidar/instance vs truth/lidar_instances.npz")
    print(f"  {'variant':26s} seed poses   AP50   P     R    people-scans  found by range ({bins} m)   "
          "FP/100 scans  inst/scan  s/scan  missed by cause")
    rows = []
    with heldout_cells(args, "holodata-bench-segment-heldout-") as (root, cells):
        for v, seed in cells:
            r = run_heldout(v, seed, poses, root)
            rows.append(r)
            for p in poses:
                x = r[p]
                a = x["ap50"]
                print(f"  {v:26s} {seed:4d} {p:5s}  {a['ap']:.3f}  {a['precision']:.2f}  {a['recall']:.2f}  "
                      f"{a['n_truth']:4d}/{x['scans']:4d}   {_recall_text(x):30s}  "
                      f"{100 * x['false_positives'] / max(x['scans'], 1):6.1f}     {x['instances_per_scan']:.2f}"
                      f"     {x['segment_scene_s'] / max(x['scans'], 1):.3f}  "
                      + " ".join(f"{c} {n}" for c, n in sorted(x["miss_causes"].items(), key=lambda t: -t[1])),
                      flush=True)
        if args.json:
            print(json.dumps(rows, indent=1, default=float))
        for p in poses:
            vals = [r[p]["ap50"]["ap"] for r in rows]
            print(f"{p} poses: AP50 min {min(vals):.3f}, mean {np.mean(vals):.3f}; floor (AP50 >= 0.9): "
                  + ("met" if all(v >= 0.9 for v in vals) else "NOT met ("
                     + ", ".join(f"{r['variant']}_{r['seed']}" for r in rows if r[p]["ap50"]["ap"] < 0.9) + ")"))
    return 0


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
    ap.add_argument("--family", choices=("tuned", "heldout"), default="tuned",
                    help="heldout: the recordings of holodata.synth.heldout (--variants, --seeds, --poses)")
    ap.add_argument("--variants", default=None, help="--family heldout: comma list (default all; benchmarks/_heldout.py)")
    ap.add_argument("--seeds", default="1,2", help="--family heldout: comma list of synth seeds")
    ap.add_argument("--poses", default="truth,slam", help="--family heldout: truth and/or slam LiDAR poses")
    args = ap.parse_args()
    header()
    if args.family == "heldout":
        return main_heldout(args)
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
