"""NLOS reconstruction as a data-scaling curve (issue 42 point 5): stage one + the learned stage two
trained on 4, 16, 64, 256 synthetic training corners at equal stage-one steps, each point scored on
the same held-out corners with every row of the paper's Table 1 (range images) and Table 2 (point
clouds: model = refined, model_no_refine, model_analytic, baseline, oracle_stage1), then the issue's
acceptance floors at the largest point. ``--install`` ships the largest point's run as holodata's
pretrained weights (``holodata evaluate DS --checkpoint pretrained``), with this command, the commit,
the corpora and the scores recorded in it.

    .venv/bin/python benchmarks/nlos.py [--out DIR] [--corners 4,16,64,256] [--frames 4] [--steps 2000]
        [--stage2-frames 64] [--device cpu|cuda] [--grid 32x128|64x512] [--install]
        [--more-steps S --more-lr 0.001] [--raw-corners R --raw-epochs 12 --raw-lr 0.0005]

Data: ``holodata synth --corners`` corpora at the quick demo's 32×128 beams and range bins
(:mod:`holodata.synth.corpus`; corner i's draws depend only on (seed, i), so the 16-corner corpus is
the first 16 corners of the 64-corner one). Training corpus: seed 0. Held-out rule, fixed before any
run and printed: corpus seed 1000000, its corners 0-15 × ``--frames`` (the *report* set, never
trained on or tuned on; developing used seed 500); its first 2 corners × 2 frames are the *check*
set tests/torch_/test_pretrained.py rescores. Stage one: the quick demo's model (depth 6, base 8, max 64,
range pooled ×2) with the per-bin likelihood ("ce", mode estimate), ``--steps`` steps of batch 4 at
every point. Stage two: 3 ray-tracer + 2 refiner epochs on ``--stage2-frames`` training frames
spread over the corners (at least one per corner), its keep threshold and stage one's confidence
gate calibrated on them. ``--more-steps S``: each point's run then trains on, as a run of its own
(``run_..._STEPS+S``): S more stage-one steps from its weights, a second cosine cycle from
``--more-lr`` (warm restart, Loshchilov & Hutter 2017), and stage two fine-tuned from its stage two
for 1 + 1 epochs (``holodata train --init RUN``'s path); that run is the point's, scored and installed.
``--raw-corners R``: then the point's run is scored on the report set recorded as raw samples and
beamformed as ingest does (``synth --corners --radar-output iq``: the road a rig records, the same
corners and ground truth) and fine-tuned as a run of its own (``..._rawR``) on R training corners
(seed 0) recorded that way: ``--raw-epochs`` stage-one epochs from ``--raw-lr``, stage two 1 + 1 epochs;
that run is the point's, scored on both roads (issue 51 point 5: raw-sample NLOS F within 0.8x of the
direct heatmaps').
``--grid 64x512`` (the paper's): corpora store uint8 log-amplitude heatmaps,
stage one and stage two train on 128-column azimuth crops (wrapping), stage one runs on whole rings
in overlapping windows (:meth:`holodata.torch.model.MultiReturnUNet.ring_forward`), the model's human
centres are the motion cue's moving person (``--motion-cue``, :mod:`holodata.evaluate.motion`),
and the floors are the paper-grid ones. Rerunning with the same --out resumes every stage (an
evaluation newer than its run and scored the same way is read back). Measured numbers go to
benchmarks/results/nlos.md, not here.
"""
from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

TRAIN_SEED = 0
HELDOUT_SEED = 1_000_000
HELDOUT_CORNERS = 16
CROP_W = 128   # azimuth columns of a stage-one training crop on grids wider than this (PanoRadar rolls the ring)
ROWS = ("model", "model_no_refine", "model_analytic", "baseline", "oracle_stage1")


def _f(v, scale=1.0, w=6, nd=1):
    return " " * (w - 1) + "–" if v is None or v != v else f"{v * scale:{w}.{nd}f}"


def print_point(n: int, steps: int, doc: dict) -> None:
    """One point of the curve: Table 1 (median / 90th cm per bounce) and Table 2 (F % per cloud)."""
    M = doc["methods"]
    print(f"\n{n} training corners ({steps} steps), {doc['n_frames']} held-out frames; stage two: "
          f"{doc['settings'].get('stage2')}")
    print("  row               b1 med / p90 cm   b2 med / p90 cm   b3 med / p90 cm    LOS CD cm / F %   "
          "NLOS CD cm / F %   human (50 cm) all: P / R / F %, loc med cm | hidden: P / R / F %, loc med cm")
    for m in ROWS:
        if m not in M:
            continue
        r, p = M[m]["range"], M[m]["points"]
        rng = "  ".join(_f(r[f"bounce_{b}"]["median_cm"]) + " " + _f(r[f"bounce_{b}"]["p90_cm"]) + "    "
                        for b in (1, 2, 3))
        print(f"  {m:<16}{rng}  {_f(p['los']['cd'], 100)} {_f(p['los']['f_score'], 100)}    "
              f"{_f(p['nlos']['cd'], 100)} {_f(p['nlos']['f_score'], 100)}    " + " |".join(
                  " ".join(_f(x.get(k), 100) for k in ("precision", "recall", "f_score")) + " " + _f(x.get("loc_median_cm"))
                  for x in (M[m]["human"], M[m].get("human_hidden") or {})))


def floors(doc: dict, paper_grid: bool = False) -> list[str]:
    """The acceptance floors on the held-out corners, one line each (PASS/FAIL): at 32×128 the first
    trained model's (NLOS F ≥ 0.25, bounce 2/3 ≤ 10/20 cm); at the paper's grid the paper-grid and
    hidden-person floors (NLOS F ≥ 0.35, LOS F ≥ 0.85, bounce 2/3 ≤ 5/15 cm; human F ≥ 0.7 over
    all frames, ≥ 0.6 with localisation median ≤ 25 cm on the frames whose person is hidden)."""
    M = doc["methods"]
    f = lambda m, p: M[m]["points"][p]["f_score"] or 0.0  # noqa: E731
    med = lambda b: M["model"]["range"][f"bounce_{b}"]["median_cm"] or math.inf  # noqa: E731
    hum = lambda k, key="f_score": M["model"][k].get(key)  # noqa: E731
    ok = lambda v, cmp: v is not None and v == v and cmp(v)  # noqa: E731
    nh = doc["settings"]["frames_hidden_person"]
    if paper_grid:
        checks = [("held-out bounce-2 median <= 5 cm", med(2) <= 5), ("held-out bounce-3 median <= 15 cm", med(3) <= 15),
                  ("model NLOS F >= 0.35", f("model", "nlos") >= 0.35),
                  ("model NLOS F >= 2x baseline", f("model", "nlos") >= 2 * f("baseline", "nlos")),
                  ("model LOS F >= 0.85", f("model", "los") >= 0.85),
                  ("model human F >= 0.7 over all frames", ok(hum("human"), lambda v: v >= 0.7)),
                  (f"model human F >= 0.6 on the {nh} frames with a hidden person",
                   ok(hum("human_hidden"), lambda v: v >= 0.6)),
                  ("hidden-person localisation median <= 25 cm",
                   ok(hum("human_hidden", "loc_median_cm"), lambda v: v <= 25))]
    else:
        checks = [("held-out bounce-2 median <= 10 cm", med(2) <= 10), ("held-out bounce-3 median <= 20 cm", med(3) <= 20),
                  ("model NLOS F >= 0.25", f("model", "nlos") >= 0.25),
                  ("model NLOS F >= 2x baseline", f("model", "nlos") >= 2 * f("baseline", "nlos")),
                  ("model NLOS F > model_analytic", f("model", "nlos") > f("model_analytic", "nlos")),
                  ("model LOS F >= 0.75", f("model", "los") >= 0.75),
                  (f"model human F >= 0.5 on the {nh} frames with a hidden person",
                   ok(hum("human_hidden"), lambda v: v >= 0.5))]
    return [f"  {'PASS' if passed else 'FAIL'}  {name}" for name, passed in checks]


def evaluated(ev_dir: Path, run: Path, cue) -> dict | None:
    """A point's evaluation already on disk (``ev_dir``/metrics.json) when it is newer than the run's
    checkpoints and was scored with the same motion cue; None otherwise (evaluate again)."""
    doc_path = ev_dir / "metrics.json"
    if not doc_path.is_file():
        return None
    t = doc_path.stat().st_mtime
    if any((run / f).is_file() and (run / f).stat().st_mtime > t for f in ("checkpoint.pt", "stage2.pt")):
        return None
    doc = json.loads(doc_path.read_text())
    return doc if doc["settings"].get("motion_cue") == (cue.to_dict() if cue is not None else None) else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/holodata-bench-nlos")
    ap.add_argument("--corners", default="4,16,64,256", help="training corners at each point of the curve")
    ap.add_argument("--frames", type=int, default=4, help="radar rotations per corner")
    ap.add_argument("--steps", type=int, default=2000, help="stage-one gradient steps (batch 4) at every point")
    ap.add_argument("--stage2-frames", type=int, default=64, help="stage-two training frames (>= 1 per corner)")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--grid", default="32x128", help="beam grid HxW: 32x128 (the quick demo's) or 64x512 (the paper's: "
                                                   "uint8 log-amplitude corpora, stage one trained on 128-column azimuth "
                                                   "crops and run on the whole ring)")
    ap.add_argument("--install", action="store_true", help="ship the largest point's run as the pretrained weights")
    ap.add_argument("--more-steps", type=int, default=0, help="then this many more stage-one steps from each point's "
                                                              "run, a second cosine cycle (module docstring)")
    ap.add_argument("--more-lr", type=float, default=1e-3, help="the second cycle's starting learning rate")
    ap.add_argument("--raw-corners", type=int, default=0, help="then fine-tune each point's run on this many training "
                    "corners recorded as raw samples and beamformed (the road a rig records; module docstring)")
    ap.add_argument("--raw-epochs", type=int, default=12, help="stage-one epochs of that fine-tune")
    ap.add_argument("--raw-lr", type=float, default=5e-4, help="its learning rate")
    a = ap.parse_args(argv)
    from _run import header

    header()

    from holodata.conventions import Grid
    from holodata.evaluate.motion import MotionCue
    from holodata.evaluate.pipeline import Evaluation
    from holodata.synth.corpus import CorpusConfig, synth_corpus
    from holodata.torch import TrainConfig, train
    from holodata.torch.pretrained import CHECK_SET, GRID_DIRS, grid_key, install, scores
    from holodata.torch.stage2_train import Stage2Config, train_stage2

    points = sorted({int(n) for n in a.corners.split(",")})
    grid = Grid.parse(a.grid)
    paper = grid.W > CROP_W      # train on azimuth crops, store log codes
    cue = MotionCue() if paper else None   # the hidden person's motion cue (holodata.evaluate.motion) at the paper grid
    grid_kw = {"grid": grid, "heatmap_dtype": "uint8" if paper else "float16"}
    tag = "" if a.grid == "32x128" else f"_{grid.H}x{grid.W}"
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print(f"held-out rule (fixed before any run): corpus seed {HELDOUT_SEED}, corners 0-{HELDOUT_CORNERS - 1} x "
          f"{a.frames} frames, never trained or tuned on; training: corpus seed {TRAIN_SEED}, the first N corners; "
          f"{a.steps} stage-one steps of batch 4 at every N", flush=True)

    def corpus(name: str, cc) -> str:
        url = str(out / f"{name}_s{cc.seed}_{cc.corners}x{cc.frames}{tag}.zarr")
        r = synth_corpus(url, cc, quiet=True)
        if r["written"]:
            print(f"  corpus {Path(url).name}: {r['seconds']:.0f} s", flush=True)
        return url

    report_cc = CorpusConfig(corners=HELDOUT_CORNERS, frames=a.frames, seed=HELDOUT_SEED, n_test=HELDOUT_CORNERS,
                             **grid_kw)
    check_cc = CorpusConfig(**{**CHECK_SET, **grid_kw})
    report, check = corpus("report", report_cc), corpus("check", check_cc)
    if a.raw_corners:   # the same held-out corners recorded as raw samples, beamformed as ingest does
        raw_report = corpus("report_iq", replace(report_cc, radar_output="iq"))
    timings, docs, runs, raw_docs = {}, {}, {}, {}
    for n in points:
        train_cc = CorpusConfig(corners=n, frames=a.frames, seed=TRAIN_SEED, n_test=0, **grid_kw)
        url = corpus("train", train_cc)
        frames = n * a.frames
        epochs = max(1, math.ceil(a.steps * 4 / frames))
        cfg = TrainConfig(epochs=epochs, depth=6, base_channels=8, max_channels=64, range_pool=2, range_loss="ce",
                          device=a.device, crop_w=CROP_W if paper else None)
        s2 = Stage2Config(epochs_rt=3, epochs_refine=2, channels=16, device=a.device,
                          frames_per_scene=max(1, min(a.frames, a.stage2_frames // n)), crop_w=CROP_W if paper else None)
        run = out / f"run_{n}x{a.frames}_{a.steps}{tag}"
        t1 = time.perf_counter()
        train(url, run, cfg, quiet=True)
        t2 = time.perf_counter()
        train_stage2(url, run, s2, quiet=True)
        t3 = time.perf_counter()
        steps, s1_s, s2_s = epochs * math.ceil(frames / cfg.batch_size), t2 - t1, t3 - t2
        if a.more_steps:   # the second cycle: a run of its own, fine-tuned from this one (module docstring)
            first, run = run, out / f"run_{n}x{a.frames}_{a.steps}+{a.more_steps}{tag}"
            more = max(1, math.ceil(a.more_steps * 4 / frames))
            cfg, s2 = replace(cfg, epochs=more, lr=a.more_lr), replace(s2, epochs_rt=1, epochs_refine=1)
            t1 = time.perf_counter()
            train(url, run, cfg, quiet=True, init=first)
            t2 = time.perf_counter()
            train_stage2(url, run, s2, quiet=True, init=first)
            t3 = time.perf_counter()
            steps, s1_s, s2_s = steps + more * math.ceil(frames / cfg.batch_size), s1_s + t2 - t1, s2_s + t3 - t2
        ev = out / (f"eval_{n}+{a.more_steps}{tag}" if a.more_steps else f"eval_{n}{tag}")
        if a.raw_corners:   # the direct heatmaps' run on the raw road, then fine-tuned on it: the point's run
            raw_ev = ev.with_name(ev.name.replace("eval_", "eval_rawroad_"))
            raw_docs[f"{n} before"] = evaluated(raw_ev, run, cue) or Evaluation(
                raw_report, run, raw_ev, split="test", quiet=True, report=False, motion=cue).run()
            raw_cc = CorpusConfig(corners=a.raw_corners, frames=a.frames, seed=TRAIN_SEED, n_test=0, radar_output="iq",
                                  **grid_kw)
            raw_url = corpus("train_iq", raw_cc)
            first, run = run, run.with_name(f"{run.name}_raw{a.raw_corners}")
            cfg, s2 = replace(cfg, epochs=a.raw_epochs, lr=a.raw_lr), replace(s2, epochs_rt=1, epochs_refine=1)
            t1 = time.perf_counter()
            train(raw_url, run, cfg, quiet=True, init=first)
            t2 = time.perf_counter()
            train_stage2(raw_url, run, s2, quiet=True, init=first)
            t3 = time.perf_counter()
            steps += a.raw_epochs * math.ceil(a.raw_corners * a.frames / cfg.batch_size)
            s1_s, s2_s = s1_s + t2 - t1, s2_s + t3 - t2
            ev, raw_ev = (e.with_name(f"{e.name}_raw{a.raw_corners}") for e in (ev, raw_ev))
            raw_docs[n] = evaluated(raw_ev, run, cue) or Evaluation(raw_report, run, raw_ev, split="test", quiet=True,
                                                                    report=False, motion=cue).run()
        docs[n] = evaluated(ev, run, cue) or Evaluation(report, run, ev, split="test", quiet=True, report=False,
                                                        motion=cue).run()
        t4 = time.perf_counter()
        timings[n] = {"stage_one_s": s1_s, "stage_two_s": s2_s, "evaluate_s": t4 - t3, "steps": steps}
        runs[n] = (run, train_cc, cfg, s2)
        print(f"  N={n}: stage one {steps} steps {s1_s:.0f} s, stage two {s2_s:.0f} s, evaluate {t4 - t3:.0f} s",
              flush=True)
        print_point(n, timings[n]["steps"], docs[n])
        for key, what in ((f"{n} before", "before the raw-sample fine-tune"), (n, "the point's run")):
            if key in raw_docs:
                print(f"  the same held-out corners recorded as raw samples and beamformed, {what}:", end="")
                print_point(n, timings[n]["steps"], raw_docs[key])

    print("\ndata-scaling curve (held-out): N   b2 / b3 median cm   model LOS F / NLOS F / human F (hidden)   baseline NLOS F")
    for n in points:
        M = docs[n]["methods"]
        r, p = M["model"]["range"], M["model"]["points"]
        print(f"  {n:5d}   {_f(r['bounce_2']['median_cm'])} {_f(r['bounce_3']['median_cm'])}     "
              f"{_f(p['los']['f_score'], 100)} {_f(p['nlos']['f_score'], 100)} {_f(M['model']['human']['f_score'], 100)} "
              f"({_f(M['model']['human_hidden']['f_score'], 100)})     {_f(M['baseline']['points']['nlos']['f_score'], 100)}")
    top = points[-1]
    print(f"\nacceptance floors at N={top} ({grid.H}x{grid.W}):")
    print("\n".join(floors(docs[top], paper)))
    if top in raw_docs:
        direct_f, raw_f = (d["methods"]["model"]["points"]["nlos"]["f_score"] or 0.0 for d in (docs[top], raw_docs[top]))
        print(f"  {'PASS' if raw_f >= 0.8 * direct_f else 'FAIL'}  raw-sample NLOS F {100 * raw_f:.1f} % >= 0.8x the direct "
              f"heatmaps' {100 * direct_f:.1f} %")
    total = time.perf_counter() - t0
    print(f"\ntotal {total:.0f} s")
    (out / "nlos_summary.json").write_text(json.dumps({"seconds": {**{str(k): v for k, v in timings.items()},
                                                                   "total": total},
                                                       "scores": {str(n): scores(d) for n, d in docs.items()},
                                                       "raw_road_scores": {str(n): scores(d) for n, d in raw_docs.items()}},
                                                      indent=2))
    if a.install:
        run, train_cc, cfg, s2 = runs[top]
        key = grid_key(train_cc.grid)
        half = key != "32x128"   # the paper grid's weights ship as float16 (<= 25 MB a file)
        # the check set (what tests/torch_/test_pretrained.py rescores) is scored with the weights as
        # shipped: float16 storage moves a score by tenths of a point
        shipped = install(run, {}, dest=out / f"shipped{tag}", half=True) if half else run
        recorded = {"report": scores(docs[top]), **({"report_raw_samples": scores(raw_docs[top])} if raw_docs else {}),
                    "check": scores(Evaluation(check, shipped, out / f"eval_check{tag}", split="test", quiet=True,
                                               report=False, motion=cue).run()),
                    "scored_with": {"report": "the run (float32)", "check": "the weights as shipped"}}

        def cc_dict(cc) -> dict:
            return {"corners": cc.corners, "frames": cc.frames, "seed": cc.seed, "n_test": cc.n_test,
                    "grid": cc.grid.to_attrs(), "range_bins": cc.range_bins.to_attrs(), "heatmap_dtype": cc.heatmap_dtype,
                    "radar_output": cc.radar_output}

        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout
        record = {"command": " ".join(shlex.quote(x) for x in ["python", *sys.argv]), "commit": commit.strip(),
                  "train_corpus": cc_dict(train_cc), "heldout_report": cc_dict(report_cc),
                  "heldout_check": cc_dict(check_cc), "train_config": cfg.to_dict(), "stage2_config": s2.to_dict(),
                  **({"raw_train_corpus": cc_dict(raw_cc), "heldout_report_raw_samples":
                      cc_dict(replace(report_cc, radar_output="iq"))} if a.raw_corners else {}),
                  "train_seconds": round(timings[top]["stage_one_s"] + timings[top]["stage_two_s"], 1),
                  "scores": recorded, "motion_cue": cue.to_dict() if cue is not None else None}
        print(f"installed {install(run, record, dest=GRID_DIRS[key], half=half)}")   # each grid's in its own folder
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
