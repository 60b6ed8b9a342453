"""NLOS reconstruction benchmark (issue 22 point 7): stage one + the learned stage two on synthetic
corners, printed as the paper's Table 1 (range images), Table 2 (point clouds, every row of
evaluate: model = refined, model_no_refine, model_analytic, baseline, oracle_stage1) and Table 3
(NLOS breakdown of the refined model by corner shape, width and attenuation).

    .venv/bin/python benchmarks/nlos.py [--out DIR] [--device cpu|cuda] [--paper]
        [--grid 32x128] [--frames 16] [--corners 6] [--epochs 60] [--rt-epochs 12] [--refine-epochs 10]

The default size is for a CPU; ``--paper`` (with ``--device cuda``) is the paper-size run: 64×512
beams, 8 corners × 40 frames, 30 + 30 + 30 epochs.
Data: holodata demo's synthetic corners (synth → ingest → mapping from the recordings' truth →
raytrace-gt), so the ground truth is exact and the numbers measure learning, not mapping.
Rerunning with the same --out resumes every stage. Measured numbers go to
benchmarks/results/nlos.md, not here.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from holodata.conventions import Grid  # noqa: E402
from holodata.demo import DEMO_CORNERS, demo_config  # noqa: E402

ROWS = ("model", "model_no_refine", "model_analytic", "baseline", "oracle_stage1")


def _f(v, scale=100.0, w=6, nd=1):
    return " " * (w - 1) + "–" if v is None else f"{v * scale:{w}.{nd}f}"


def print_tables(doc: dict) -> None:
    M = doc["methods"]
    s = doc["settings"]
    print(f"test: {doc['n_frames']} frames, scenes {', '.join(doc['scenes'])}; "
          f"GT NLOS points per frame {s.get('gt_nlos_points_per_frame', 0):.0f}; stage two: {s.get('stage2')}")
    print("\nTable 1 (range images, cm)   b1 mean / median / 90th / PSNR dB   b2 …   b3 …")
    for m in ("model", "baseline"):
        r = M[m]["range"]
        cells = "   ".join(" ".join(_f(r[f"bounce_{b}"][k], 1.0) for k in ("mean_cm", "median_cm", "p90_cm", "psnr_db"))
                           for b in (1, 2, 3))
        print(f"  {m:<16}{cells}")
    print("\nTable 2 (point clouds)     LOS CD cm / MHD cm / F %    NLOS CD cm / MHD cm / F %    human F %")
    for m in ROWS:
        if m not in M:
            continue
        p = M[m]["points"]
        print(f"  {m:<16}" + " ".join(_f(p["los"][k]) for k in ("cd", "mhd", "f_score")) + "   "
              + " ".join(_f(p["nlos"][k]) for k in ("cd", "mhd", "f_score")) + "   " + _f(M[m]["human"]["f_score"]))
    print("\nTable 3 (refined model, NLOS)   group / band: scenes, frames, CD cm, MHD cm, F %")
    for group, bands in M["model"]["breakdown"].items():
        for band, c in bands.items():
            print(f"  {group:<12} {band:<10} {c['n_scenes']:3d} {c['n_frames']:4d} "
                  + " ".join(_f(c.get(k)) for k in ("cd", "mhd", "f_score")))


def floors(doc: dict) -> list[str]:
    """The issue's acceptance floors, one line each (PASS/FAIL)."""
    M = doc["methods"]
    g = lambda m, p: M[m]["points"][p]["f_score"] or 0.0  # noqa: E731
    checks = [
        ("oracle_stage1 NLOS F >= 0.60", g("oracle_stage1", "nlos") >= 0.60),
        ("model NLOS F >= 0.20", g("model", "nlos") >= 0.20),
        ("model NLOS F >= 2x baseline", g("model", "nlos") >= 2 * g("baseline", "nlos")),
        ("model NLOS F > model_analytic", g("model", "nlos") > g("model_analytic", "nlos")),
        ("model LOS F >= 0.70", g("model", "los") >= 0.70),
        ("model human F >= 0.5", (M["model"]["human"]["f_score"] or 0.0) >= 0.5),
    ]
    return [f"  {'PASS' if ok else 'FAIL'}  {name}" for name, ok in checks]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/holodata-bench-nlos")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--paper", action="store_true", help="paper size (64x512, 8 corners x 40 frames; use with --device cuda)")
    ap.add_argument("--grid", default=None, help="beam grid HxW (default 32x128; --paper 64x512)")
    ap.add_argument("--frames", type=int, default=None, help="radar frames per corner (default 16; --paper 40)")
    ap.add_argument("--corners", type=int, default=None, help="corners (the last 1 (2 with --paper) are the test split)")
    ap.add_argument("--epochs", type=int, default=None, help="stage-one epochs (default 60; --paper 30)")
    ap.add_argument("--rt-epochs", type=int, default=None, help="stage-two ray-tracer epochs (default 12; --paper 30)")
    ap.add_argument("--refine-epochs", type=int, default=None, help="stage-two refiner epochs (default 10; --paper 30)")
    ap.add_argument("--channels", type=int, default=None, help="hybrid-block channels (default 16; --paper 32)")
    a = ap.parse_args(argv)

    from holodata.demo import run_demo
    from holodata.torch.stage2_train import Stage2Config

    base = demo_config(quick=not a.paper)
    pick = lambda v, cpu, paper: v if v is not None else (paper if a.paper else cpu)  # noqa: E731
    grid = Grid.parse(pick(a.grid, "32x128", "64x512"))
    n_corners = pick(a.corners, 6, 8)
    over = {"corners": DEMO_CORNERS[:n_corners], "n_test": 2 if a.paper else 1, "frames": pick(a.frames, 16, 40),
            "grid": grid, "epochs": pick(a.epochs, 60, 30),
            "mapping_pass": False}  # mapping comes from the recordings' truth: no LiDAR mapping drive needed
    s2 = Stage2Config(epochs_rt=pick(a.rt_epochs, 12, 30), epochs_refine=pick(a.refine_epochs, 10, 30),
                      channels=pick(a.channels, 16, 32), device=a.device)
    over["stage2"] = s2.to_dict()  # run_demo trains stage two after stage one, then evaluates every row
    cfg = base.__class__(**{**base.__dict__, **over})
    print(f"corners {', '.join(f'{k}_{s}' for k, s in cfg.corners)} (test: the last {cfg.n_test}); "
          f"{cfg.frames} frames each; grid {grid.H}x{grid.W}; stage one {cfg.epochs} epochs (depth {cfg.depth}); "
          f"stage two {s2.epochs_rt} ray-tracer + {s2.epochs_refine} refiner epochs (channels {s2.channels}, "
          f"voxel {s2.voxel * 100:.0f} cm); device {a.device}", flush=True)
    out = Path(a.out)
    t0 = time.perf_counter()
    res = run_demo(out, mapping="truth", quiet=True, config=cfg, log=lambda m: print("  " + m, flush=True))
    t1 = time.perf_counter()
    doc = res.metrics
    print(f"  total        {t1 - t0:6.1f} s\n")
    print_tables(doc)
    print("\nacceptance floors (issue 22):")
    print("\n".join(floors(doc)))
    (out / "nlos_summary.json").write_text(json.dumps({"seconds": {**res.timings, "total": t1 - t0}, "rows": {
        m: {"points": doc["methods"][m]["points"], "human_f": doc["methods"][m]["human"]["f_score"]}
        for m in ROWS if m in doc["methods"]}}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
