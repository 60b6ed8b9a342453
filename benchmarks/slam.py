"""Benchmark: ``holodata slam`` accuracy and runtime per corner kind, against bare kiss-icp.

For each corner kind (T, L, cross, oblique): ``holodata.synth.synthesize`` a recording (small radar
grid to keep synth fast; LiDAR ``--lidar``), ``holodata.ingest`` it, run ``slam_scene`` (kiss-icp +
open3d scan-to-map refinement + static mesh), and measure against ``truth/`` with
``holodata.evaluate.slam_accuracy`` (evo ATE/RPE with Umeyama alignment; occlusion-aware mesh Chamfer and
F-score at 2/5/10 cm). The same scans go through bare kiss-icp 1.3 (``KissICP.register_frame``
with the same indoor config) in the same run: its ATE/RPE and the runtime ratio slam / kiss-icp
are printed. ``--mesh-methods`` also meshes the same registered scans with the other open3d
reconstructions (Poisson / ball pivoting) and prints their F-scores and times.
Finally slam runs on the real ROS 1 fixture ``../shared/fixtures/ros1/luminar-test.bag``
(must not crash; few poses).

    .venv/bin/python benchmarks/slam.py [--frames 40] [--lidar 64x1024] [--corners T,L,cross,oblique]
                                        [--walkers N] [--mesh-methods poisson,bpa] [--raytrace] [--keep DIR]
                                        [--mapping-pass]
    .venv/bin/python benchmarks/slam.py --demo quick|full [--keep DIR] [--only L_16,...]

``--mapping-pass``: each corner is synthesised with its mapping pass, which slam maps
first; the data pass is localised in that map (``slam --map-scene``). ``--demo quick|full`` runs the
demo configuration's corners (``holodata.demo.demo_config``: grids, LiDAR, frames, mesh settings)
that way. Every row also prints the mesh's **coverage** of the true surface within the radar's
reach (the corner's radar grid traced from the true radar poses through the true mesh, 3 bounces,
9.6 m; covered = within 5 cm of the SLAM mesh; per bounce) and the **GT NLOS points per frame**
through the SLAM mesh vs the true mesh (same poses). Floors: coverage >= 0.90 on every
demo corner, NLOS per frame within 10 % of the true mesh's. Measurements:
``benchmarks/results/slam-mapping-pass.md``.

``--raytrace`` also times ``raytrace-gt`` (default 64x512 grid, 3 bounces) of the same frames through
the SLAM mesh and radar poses, so the slam runtime can be compared with the stage it feeds.

Floors: ATE < 5 cm, mesh F@5cm >= 0.90 (aim ATE < 3 cm, F >= 0.95).

``--frames`` counts radar cycles (2 Hz); ingest keeps the LiDAR scan (10 Hz) nearest each radar
frame, so slam sees one scan per cycle (400 scans for 400 cycles, 0.5 s apart).

Measurements (per date, with the load and the code they ran): ``benchmarks/results/slam.md``.

``benchmarks/pipeline.py`` prints the ingest / slam / register / raytrace-gt table of one corner.

``--family heldout``: slam and its static mesh (``holodata.mapping.mesh`` +
``background``) on the recordings of :mod:`holodata.synth.heldout`, a family nothing was tuned on
(LiDAR-only, an L corridor driven through with furniture, 32/64/128 beams, a person walking;
``benchmarks/_heldout.py``: ``--variants``, ``--seeds``): ATE and the mesh's F@2/5/10 cm and Chamfer
against ``truth/mesh.ply`` (the same :func:`evaluate_slam` as above, no radar coverage: no radar),
from slam's poses and from the true ones (the mesh step alone). Shares ``--keep DIR`` with
``benchmarks/register.py --family heldout``. Results: ``benchmarks/results/mesh.md``.

    .venv/bin/python benchmarks/slam.py --family heldout [--variants ...] [--seeds 1,2] [--keep DIR]
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from _run import header

from holodata.conventions import Grid, RangeBins
from holodata.dataset import open_dataset
from holodata.evaluate.slam_accuracy import evaluate_slam, lidar_from_scene_json, mesh_errors, pose_alignment
from holodata.ingest import ingest
from holodata.mapping import slam as S
from holodata.mapping.mesh import MeshConfig
from holodata.meshio import read_mesh
from holodata.synth import SynthSpec, synthesize
from holodata.trajectory import Trajectory, read_tum

ROOT = Path(__file__).resolve().parents[1]

LUMINAR = ROOT.parent / "shared" / "fixtures" / "ros1" / "luminar-test.bag"


def bare_kiss(url: str, scene: str) -> tuple[float, Trajectory]:
    """Seconds and trajectory of bare kiss-icp on the scene's scans (same config as slam's stage 1)."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    sc = open_dataset(url).scene(scene)
    scans = S.load_scans(sc)
    cfg = S.SlamConfig()
    mr = S.data_max_range(scans)
    kc = KISSConfig()
    kc.data.max_range, kc.data.min_range, kc.data.deskew = mr, cfg.min_range, scans.times is not None
    kc.mapping.voxel_size = cfg.voxel
    kc.adaptive_threshold.initial_threshold, kc.adaptive_threshold.min_motion_th = 0.5, 0.02
    odo = KissICP(config=kc)
    poses, ref = [], []
    t0 = time.perf_counter()
    for i, p in enumerate(scans.points):
        t = scans.times[i] if scans.times is not None else np.zeros(len(p))
        odo.register_frame(np.ascontiguousarray(p, np.float64), np.ascontiguousarray(t, np.float64))
        poses.append(odo.last_pose.copy())
        ref.append(scans.stamp_ns[i] + (int(round(t.max() * 1e9)) if np.ptp(t) > 0 else 0))
    return time.perf_counter() - t0, Trajectory(np.asarray(ref, np.int64), np.stack(poses))


def run_corner(corner: str, work: Path, args) -> dict:
    out = work / corner
    lidar = tuple(int(v) for v in args.lidar.split("x"))
    url = str(out / "ds.zarr")
    if args.reuse and (out / "ds.zarr").is_dir():  # a kept folder of an earlier run: skip synth + ingest
        from types import SimpleNamespace

        sj = json.loads((out / "truth" / "scene.json").read_text())
        syn = SimpleNamespace(width_m=float(sj["width_m"]), truth_dir=out / "truth", mesh=out / "truth" / "mesh.ply",
                              trajectory_radar=out / "truth" / "trajectory_radar.tum")
        t_syn = t_ing = float("nan")
        sid = open_dataset(url).scenes[0]
        for n in ("gt.zarr", "slam_mesh.ply", "radar.tum"):
            p = out / n
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    else:
        t0 = time.perf_counter()
        syn = synthesize(out, SynthSpec(corner=corner, frames=args.frames, seed=args.seed, grid=Grid(16, 64),
                                        range_bins=RangeBins(32), lidar_shape=lidar, camera_shape=(48, 64),
                                        visible_walkers=args.walkers, mapping_pass=args.mapping_pass), quiet=True)
        t_syn = time.perf_counter() - t0
        t0 = time.perf_counter()
        recs = [syn.recording] + ([syn.mapping_recording] if args.mapping_pass else [])
        ing = ingest(recs, url, scene_ids=["data", "map"][:len(recs)], quiet=True)
        t_ing = time.perf_counter() - t0
        sid = ing["scenes"][0]["scene"]
    t0 = time.perf_counter()
    res = S.slam_scene(url, sid, config=S.SlamConfig(global_pass=args.global_pass), quiet=True,
                       outputs=S.SlamOutputs(force=True), map_scene="map" if args.mapping_pass else None)
    t_slam = time.perf_counter() - t0
    t_kiss, ktraj = bare_kiss(url, sid)
    acc = evaluate_slam(res.trajectory(), res.mesh, syn.truth_dir, out_dir=out / "report",
                        extra_trajectories={"kiss-icp (bare)": ktraj})
    row = {"corner": corner, "width_m": round(syn.width_m, 2), "scans": res.summary["scans"],
           "synth_s": round(t_syn, 1), "ingest_s": round(t_ing, 1), "slam_s": round(t_slam, 1),
           "kiss_s": round(t_kiss, 1), "ratio": round(t_slam / max(t_kiss, 1e-9), 2),
           "ate_cm": acc["trajectory"]["ate_rmse_m"] * 100, "rpe_cm": acc["trajectory"]["rpe_frame_rmse_m"] * 100,
           "rpe1m_cm": acc["trajectory"]["rpe_rmse_m"] * 100,
           "kiss_ate_cm": acc["trajectory_kiss-icp (bare)"]["ate_rmse_m"] * 100,
           "kiss_rpe_cm": acc["trajectory_kiss-icp (bare)"]["rpe_frame_rmse_m"] * 100,
           "timings": res.summary["timings"], "mesh_faces": res.summary["mesh"]["faces"],
           "still_scans": (res.summary["health"].get("sequential") or {}).get("still_scans"),
           "kiss_scans": (res.summary["health"].get("sequential") or {}).get("kiss_scans")}
    row.update(_coverage_cols(acc))
    m = acc["mesh"]
    row.update({"chamfer_cm": m["chamfer_m"] * 100, "f2": m["f_2cm"], "f5": m["f_5cm"], "f10": m["f_10cm"],
                "observed": m["observed_fraction"]})
    # radar poses straight against the truth (same world frame when TF anchored the map)
    tr = read_tum(syn.trajectory_radar)
    Tr = res.T_world_radar
    if Tr is not None and len(Tr) == len(tr):
        row["radar_pose_err_cm"] = float(np.sqrt(np.mean(np.sum((Tr[:, :3, 3] - tr.poses[:, :3, 3]) ** 2, 1)))) * 100
    if args.raytrace and Tr is not None:
        # the stage slam must not dominate: raytrace-gt of the same frames at the default 64x512 grid
        from holodata.groundtruth import GTConfig, RaytraceStandalone
        from holodata.meshio import Mesh, write_ply
        from holodata.trajectory import write_tum

        sc = open_dataset(url).scene(sid)
        write_ply(out / "slam_mesh.ply", Mesh(res.mesh[0], res.mesh[1]))
        write_tum(out / "radar.tum", Trajectory(np.asarray(sc["time/timestamp_ns"][...], np.int64), Tr))
        t0 = time.perf_counter()
        RaytraceStandalone(out / "slam_mesh.ply", out / "radar.tum", str(out / "gt.zarr"), cfg=GTConfig(), quiet=True).run()
        row["raytrace_s"] = round(time.perf_counter() - t0, 1)
    methods = [x for x in args.mesh_methods.split(",") if x]
    if methods:
        sc = open_dataset(url).scene(sid)
        scans = S.load_scans(sc)
        mr = S.data_max_range(scans)
        truth = read_tum(syn.truth_dir / "trajectory_lidar.tum")
        A = pose_alignment(res.trajectory(), truth)
        tm = read_mesh(syn.mesh)
        hum = [k for k, n in tm.class_names.items() if str(n) == "human"]
        keep = ~np.isin(tm.face_class, hum) if tm.face_class is not None else np.ones(len(tm.faces), bool)
        row["methods"] = {}
        for meth in methods:
            t0 = time.perf_counter()
            try:
                sm = S.static_mesh(scans, res.scan_poses, S.SlamConfig(), mr, MeshConfig(method=meth))
                v, f = sm.vertices, sm.faces
            except Exception as err:  # noqa: BLE001 - report and go on
                row["methods"][meth] = {"error": str(err)[:120]}
                continue
            dt = time.perf_counter() - t0
            if len(f) == 0:
                row["methods"][meth] = {"s": round(dt, 1), "error": "no faces"}
                continue
            vv = v.astype(np.float64) @ A[:3, :3].T + A[:3, 3]
            me = mesh_errors(vv, f, tm.vertices, tm.faces[keep], sensor_poses=truth.poses,
                             lidar=lidar_from_scene_json(syn.truth_dir))
            row["methods"][meth] = {"s": round(dt, 1), "faces": int(len(f)), "f2": me["f_2cm"], "f5": me["f_5cm"],
                                    "f10": me["f_10cm"], "chamfer_cm": me["chamfer_m"] * 100}
    return row


def _coverage_cols(acc: dict) -> dict:
    c = acc.get("coverage") or {}
    return {"coverage": c.get("coverage", float("nan")), "coverage_bounce": c.get("coverage_bounce", {}),
            "coverage_nlos": c.get("coverage_nlos", float("nan")),
            "nlos_est": c.get("nlos_per_frame_est", float("nan")), "nlos_true": c.get("nlos_per_frame_true", float("nan")),
            "nlos_ratio": c.get("nlos_ratio", float("nan"))}


def _coverage_text(row: dict) -> str:
    by = "/".join(f"{v:.3f}" for _, v in sorted(row["coverage_bounce"].items()))
    return (f"coverage {row['coverage']:.3f} (b1/2/3 {by}, NLOS pts {row['coverage_nlos']:.3f})  NLOS/frame slam "
            f"{row['nlos_est']:.0f} vs true "
            f"{row['nlos_true']:.0f} ({row['nlos_ratio']:.2f})")


def run_demo_corner(corner: str, seed: int, cfg, work: Path) -> dict:
    """One corner of a demo configuration, mapped first: synth (with its mapping pass), ingest both,
    ``slam --map-scene``, then the accuracy report against the truth."""
    from holodata.demo import map_scene_id, scene_id

    sid = scene_id(corner, seed)
    out = work / sid
    url = str(out / "ds.zarr")
    t_syn = t_ing = float("nan")
    if not (out / "ds.zarr").is_dir():
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        syn = synthesize(out, SynthSpec(corner=corner, frames=cfg.frames, seed=seed, grid=cfg.grid,
                                        range_bins=cfg.range_bins, lidar_shape=cfg.lidar_shape,
                                        camera_shape=cfg.camera_shape, lidar_vertical_fov_deg=cfg.lidar_vertical_fov_deg,
                                        mapping_pass=True, mapping_scan_hz=cfg.mapping_scan_hz), quiet=True)
        t_syn = time.perf_counter() - t0
        t0 = time.perf_counter()
        ingest([syn.recording, syn.mapping_recording], url, scene_ids=[sid, map_scene_id(sid)], quiet=True)
        t_ing = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = S.slam_scene(url, sid, map_scene=map_scene_id(sid), quiet=True, outputs=S.SlamOutputs(force=True),
                       mesh_config=MeshConfig(poisson_depth=cfg.mesh_poisson_depth))
    t_slam = time.perf_counter() - t0
    acc = evaluate_slam(res.trajectory(), res.mesh, out / "truth")
    msum = open_dataset(url).scene(map_scene_id(sid)).attrs["slam"]["summary"]
    row = {"scene": sid, "width_m": float(json.loads((out / "truth" / "scene.json").read_text())["width_m"]),
           "map_scans": msum["scans"], "synth_s": round(t_syn, 1), "ingest_s": round(t_ing, 1),
           "slam_s": round(t_slam, 1), "map_timings": msum["timings"], "localise_timings": res.summary["timings"],
           "ate_cm": acc["trajectory"]["ate_rmse_m"] * 100, "f5": acc["mesh"]["f_5cm"],
           "localisation": res.summary["health"]["localisation"]}
    row.update(_coverage_cols(acc))
    return row


def main_demo(args) -> None:
    from holodata.demo import demo_config

    cfg = demo_config(args.demo == "quick")
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="holodata-slam-demo-"))
    work.mkdir(parents=True, exist_ok=True)
    only = [x for x in (args.only or "").split(",") if x]
    rows = []
    try:
        print(f"demo {args.demo}: {len(cfg.corners)} corners, {cfg.frames} radar frames, grid {cfg.grid.H}x{cfg.grid.W}, "
              f"LiDAR {cfg.lidar_shape[0]}x{cfg.lidar_shape[1]}, mapping pass {cfg.mapping_scan_hz:g} scans/s, "
              f"Poisson depth {cfg.mesh_poisson_depth or 'auto'}", flush=True)
        for corner, seed in cfg.corners:
            if only and f"{corner}_{seed}" not in only:
                continue
            r = run_demo_corner(corner, seed, cfg, work)
            rows.append(r)
            lo = r["localisation"]
            print(f"{r['scene']:11s} w {r['width_m']:.2f} m  map scans {r['map_scans']:3d}  {_coverage_text(r)}  "
                  f"ATE {r['ate_cm']:.2f} cm  F@5 {r['f5']:.3f}  first scan corrected {lo['first_correction_m'] * 100:.1f} cm "
                  f"| synth {r['synth_s']} s, ingest {r['ingest_s']} s, slam {r['slam_s']} s (map {r['map_timings']}) ",
                  flush=True)
        if rows:
            ok_c = all(r["coverage"] >= 0.90 for r in rows)
            ok_n = all(abs(r["nlos_ratio"] - 1) <= 0.10 for r in rows)
            print(f"floors: coverage >= 0.90 {'met' if ok_c else 'NOT met'} (min {min(r['coverage'] for r in rows):.3f}); "
                  f"NLOS/frame within 10 % {'met' if ok_n else 'NOT met'} (ratios "
                  f"{', '.join(format(r['nlos_ratio'], '.2f') for r in rows)})")
        if args.json:
            print(json.dumps(rows, default=float))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


def run_heldout(variant: str, seed: int, root: Path) -> dict:
    """One held-out recording: slam (``ds.zarr``, skipped when done) and its mesh, and the mesh step on
    the true poses (``ds_truth.zarr``), against the truth."""
    from _heldout import person_ghost_m2, prepare_heldout, scene_static_mesh, scene_trajectory, write_true_lidar_poses

    from holodata.conventions import transform_points
    from holodata.mapping.register import scene_mesh

    out = {"variant": variant, "seed": seed}
    truth, url, sid = prepare_heldout(variant, seed, root)
    S.slam_scene(url, sid, quiet=True)                 # skipped when done (a kept folder)
    sc = open_dataset(url).scene(sid)
    summ = sc.attrs["slam"]["summary"]
    tm = summ["timings"]                               # slam's own run (when it was done)
    out["slam_s"] = float(tm.get("total_s", sum(v for k, v in tm.items() if k != "read_wait_s")))
    mesh = scene_mesh(sc)
    acc = evaluate_slam(scene_trajectory(url, sid), mesh, truth, coverage=False)
    out["slam"] = {"ate_cm": acc["trajectory"]["ate_rmse_m"] * 100, "scans": summ["scans"], "faces": len(mesh[1]),
                   **acc["mesh"], **person_ghost_m2(transform_points(np.asarray(acc["mesh_alignment"]), mesh[0]),
                                                    mesh[1], truth)}
    truth, url, sid = prepare_heldout(variant, seed, root, dataset="ds_truth.zarr")
    write_true_lidar_poses(url, sid, truth)
    t0 = time.perf_counter()
    v, f = scene_static_mesh(url, sid)
    out["mesh_s"] = time.perf_counter() - t0
    acc = evaluate_slam(scene_trajectory(url, sid), (v, f), truth, coverage=False)
    out["truth"] = {"ate_cm": acc["trajectory"]["ate_rmse_m"] * 100, "faces": len(f), **acc["mesh"],
                    **person_ghost_m2(v, f, truth)}
    return out


def _mesh_cells(m: dict) -> str:
    return (f"{m['f_2cm']:.3f} {m['f_5cm']:.3f} {m['f_10cm']:.3f}  {m['precision_5cm']:.3f} {m['recall_5cm']:.3f}  "
            f"{m['chamfer_m'] * 100:5.2f}  {m['observed_fraction']:.2f}  {m['person_m2']:6.3f} {m['other_m2']:6.3f}")


def main_heldout(args) -> None:
    from _heldout import heldout_cells

    print("held-out family (holodata.synth.heldout): static mesh vs truth/mesh.ply (occlusion-aware, as above)")
    print("  (ghost m2: mesh area > 10 cm off the true static mesh, within 30 cm of the person at some scan / elsewhere)")
    print(f"  {'variant':26s} seed poses  ATE cm  F@2   F@5   F@10   P@5   R@5    CD cm  obs   ghost m2 person other"
          "   faces  slam s mesh s")
    rows = []
    with heldout_cells(args, "holodata-slam-heldout-") as (root, cells):
        for v, seed in cells:
            r = run_heldout(v, seed, root)
            rows.append(r)
            for p, t in (("slam", r["slam_s"]), ("truth", r["mesh_s"])):
                m = r[p]
                print(f"  {v:26s} {seed:4d} {p:5s}  {m['ate_cm']:5.2f}  {_mesh_cells(m)}  {m['faces']:7d}  "
                      + (f"{t:6.1f}" if p == "slam" else f"{'':6s} {t:6.1f}"), flush=True)
        for p in ("slam", "truth"):
            f5 = [r[p]["f_5cm"] for r in rows]
            print(f"{p} poses: F@5 min {min(f5):.3f}, mean {np.mean(f5):.3f}; floors (ATE < 5 cm, F@5 >= 0.90): "
                  + ("met" if all(r[p]["ate_cm"] < 5 and r[p]["f_5cm"] >= 0.9 for r in rows) else "NOT met"))
        if args.json:
            print(json.dumps(rows, default=float))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=40, help="radar frames (2 Hz) per corner")
    ap.add_argument("--lidar", default="64x1024")
    ap.add_argument("--corners", default="T,L,cross,oblique")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--walkers", type=int, default=0, help="people walking in the robot's corridor (visible to LiDAR)")
    ap.add_argument("--mesh-methods", default="", help="also compare these mesh methods, e.g. poisson,bpa")
    ap.add_argument("--global-pass", action="store_true", help="slam's second refinement pass against the whole map")
    ap.add_argument("--raytrace", action="store_true", help="also time raytrace-gt (64x512, 3 bounces) of the same frames")
    ap.add_argument("--skip-luminar", action="store_true")
    ap.add_argument("--keep", default=None, help="keep the work folder here")
    ap.add_argument("--reuse", action="store_true", help="with --keep: reuse corners synthesised and ingested there")
    ap.add_argument("--mapping-pass", action="store_true", help="map each corner first (its mapping pass), localise the data")
    ap.add_argument("--demo", choices=["quick", "full"], default=None, help="the demo configuration's corners, mapped first")
    ap.add_argument("--only", default=None, help="with --demo: these scene ids only (comma-separated)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--family", choices=("tuned", "heldout"), default="tuned",
                    help="heldout: the recordings of holodata.synth.heldout (--variants, --seeds)")
    ap.add_argument("--variants", default=None, help="--family heldout: comma list (default all; benchmarks/_heldout.py)")
    ap.add_argument("--seeds", default="1,2", help="--family heldout: comma list of synth seeds")
    args = ap.parse_args()
    header()
    if args.family == "heldout":
        main_heldout(args)
        return
    if args.demo:
        main_demo(args)
        return
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="holodata-slam-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        for corner in args.corners.split(","):
            row = run_corner(corner, work, args)
            rows.append(row)
            print(f"{corner:8s} scans {row['scans']:4d} (at rest {row['still_scans']}, fed to kiss-icp {row['kiss_scans']})  "
                  f"ATE {row['ate_cm']:.2f} cm  RPE {row['rpe_cm']:.2f} cm/frame "
                  f"({row['rpe1m_cm']:.2f} cm/m)  | kiss-icp ATE {row['kiss_ate_cm']:.2f} cm RPE {row['kiss_rpe_cm']:.2f}"
                  f"  | mesh F@2/5/10 {row['f2']:.3f}/{row['f5']:.3f}/{row['f10']:.3f} CD {row['chamfer_cm']:.2f} cm"
                  f" (obs {row['observed']:.2f})  | radar pose err {row.get('radar_pose_err_cm', float('nan')):.2f} cm"
                  f"  | slam {row['slam_s']:.1f} s = {row['ratio']:.2f}x bare kiss-icp ({row['kiss_s']:.1f} s)  "
                  f"{json.dumps(row['timings'])}"
                  + (f"  | raytrace-gt 64x512 {row['raytrace_s']:.1f} s" if "raytrace_s" in row else "")
                  + f"  | {_coverage_text(row)}", flush=True)
            for meth, r in (row.get("methods") or {}).items():
                print(f"    mesh {meth:8s} {json.dumps(r)}", flush=True)
        if not args.skip_luminar and LUMINAR.is_file():
            url = str(work / "luminar.zarr")
            ingest([LUMINAR], url, quiet=True)
            sid = open_dataset(url).scenes[0]
            t0 = time.perf_counter()
            res = S.slam_scene(url, sid, quiet=True)
            dt = time.perf_counter() - t0
            t_k, _ = bare_kiss(url, sid)
            path = float(np.sum(np.linalg.norm(np.diff(res.scan_poses[:, :3, 3], axis=0), axis=1)))
            print(f"luminar-test.bag: {res.summary['scans']} scans, path {path:.2f} m, mesh {res.summary['mesh']['faces']} "
                  f"faces, slam {dt:.1f} s = {dt / max(t_k, 1e-9):.2f}x bare kiss-icp ({t_k:.1f} s), health "
                  f"{json.dumps(res.summary['health'])}")
        if rows:
            ok = all(r["ate_cm"] < 5 and r["f5"] >= 0.90 for r in rows)
            print(f"floors (ATE < 5 cm, F@5cm >= 0.90): {'met' if ok else 'NOT met'} on {len(rows)} corner(s); "
                  f"mean ATE {np.mean([r['ate_cm'] for r in rows]):.2f} cm, mean F@5 {np.mean([r['f5'] for r in rows]):.3f}")
        if args.json:
            print(json.dumps(rows, default=float))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
