"""Stage one's range loss side by side: L1 on the soft-argmax mean against the
per-bin cross-entropy with two-hot sub-bin targets, the same training corpus, the same steps, the
same seed, scored on corners neither run trained on.

    .venv/bin/python benchmarks/stage1_loss.py [--out DIR] [--corners 64] [--frames 4] [--steps 600]
        [--losses l1,ce] [--heldout report|tune]

Data: ``holodata synth --corners`` corpora at 32×128 beams (:mod:`holodata.synth.corpus`). Training:
corpus seed 0, the first ``--corners`` corners. Held-out corners, by a rule fixed before any run:
``--heldout report`` is corpus seed 1000000, corners 0-15 (4 of each kind), never used while
developing; ``--heldout tune`` (seed 500) is the set to tune on. Printed per loss and estimator:
range-image error per bounce on the held-out corners (median / 90th cm, share of GT returns within
10 cm), the training loss at the end, and the bounce-2/3 error over the NLOS-labelled returns alone
(median cm, within 10 cm): the returns that make the hidden side's points. Numbers go to benchmarks/results/, not here.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from _run import header

HELDOUT = {"report": 1_000_000, "tune": 500}
HELDOUT_CORNERS = 16


def corpus(path: Path, corners: int, seed: int, frames: int, n_test: int) -> str:
    from holodata.synth.corpus import CorpusConfig, synth_corpus

    r = synth_corpus(str(path), CorpusConfig(corners=corners, frames=frames, seed=seed, n_test=n_test), quiet=True)
    if r["written"]:
        print(f"  corpus {path.name}: {corners} corners x {frames} frames, seed {seed} ({r['seconds']:.0f} s)", flush=True)
        for line in r["span"]:
            print("    " + line)
    return str(path)


def score(run_dir: Path, test_url: str, estimators) -> dict:
    """{estimator: {bounce: metrics}} of the run's stage one on the test split of ``test_url``."""
    import numpy as np
    import torch

    from holodata.metrics import range_image_metrics
    from holodata.torch.checkpoint import load_checkpoint
    from holodata.torch.data import HeatmapDataset, HeatmapNorm, SampleTransform
    from holodata.torch.train import model_from_checkpoint

    ck = load_checkpoint(run_dir)
    model = model_from_checkpoint(ck)
    data = HeatmapDataset(test_url, split="test", norm=HeatmapNorm.from_dict(ck["norm"]),
                          transform=SampleTransform(**ck["transform"]))
    preds: dict = {e: [] for e in estimators}
    gts, labs = [], []
    with torch.no_grad():
        for i in range(len(data)):
            s = data[i]
            x = s["heatmap"][None]
            for e in estimators:
                preds[e].append(model.predict(x, estimator=e)["range"][0].numpy())
            gts.append(s["range"].numpy())
            labs.append(s["label"].numpy())
    gt, lab = np.stack(gts), np.stack(labs)
    nlos = np.isin(lab, (2, 4))   # NLOS structure / human (conventions.Label)
    out = {}
    for e in estimators:
        p = np.stack(preds[e])
        rows = {}
        for b in range(gt.shape[1]):
            m = range_image_metrics(p[:, b], gt[:, b], max_range=float(ck["model_config"]["max_range"]))
            g = np.isfinite(gt[:, b])
            err = np.abs(p[:, b] - gt[:, b])[g]
            m["within_10cm"] = float(np.mean(np.nan_to_num(err, nan=np.inf) <= 0.10)) if g.any() else float("nan")
            e_n = np.abs(np.nan_to_num(p[:, b], nan=0.0) - gt[:, b])[g & nlos[:, b]]
            m["nlos_median_cm"] = float(np.median(e_n) * 100) if e_n.size else float("nan")
            m["nlos_within_10cm"] = float(np.mean(e_n <= 0.10)) if e_n.size else float("nan")
            rows[b + 1] = m
        out[e] = rows
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/holodata-bench-stage1-loss")
    ap.add_argument("--corners", type=int, default=64, help="training corners (corpus seed 0)")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--steps", type=int, default=600, help="gradient steps per run (batch 4)")
    ap.add_argument("--losses", default="l1,ce")
    ap.add_argument("--heldout", choices=sorted(HELDOUT), default="report")
    a = ap.parse_args(argv)
    header()

    from holodata.torch import TrainConfig, train

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train_url = corpus(out / f"train_s0_{a.corners}.zarr", a.corners, 0, a.frames, 0)
    seed = HELDOUT[a.heldout]
    test_url = corpus(out / f"heldout_{a.heldout}.zarr", HELDOUT_CORNERS, seed, a.frames, HELDOUT_CORNERS)
    print(f"held-out rule: corpus seed {seed}, corners 0-{HELDOUT_CORNERS - 1} ({a.heldout} set); training: corpus "
          f"seed 0, corners 0-{a.corners - 1}; {a.steps} steps of batch 4 per run", flush=True)
    n_frames = a.corners * a.frames
    epochs = max(1, math.ceil(a.steps * 4 / n_frames))
    print("\nloss  estimator   b1 median / p90 cm / within 10 cm     b2 ...     b3 ...     train loss   seconds")
    for loss in a.losses.split(","):
        cfg = TrainConfig(epochs=epochs, depth=6, base_channels=8, max_channels=64, range_pool=2, range_loss=loss)
        t1 = time.perf_counter()
        res = train(train_url, out / f"run_{loss}_{a.corners}_{a.steps}", cfg, quiet=True)
        dt = time.perf_counter() - t1
        sc = score(res.out_dir, test_url, ("mean", "median", "mode"))
        for est, rows in sc.items():
            cells = "   ".join(f"{rows[b]['median_cm']:6.1f} {rows[b]['p90_cm']:6.1f} {100 * rows[b]['within_10cm']:5.1f} %"
                               for b in (1, 2, 3))
            nl = "   ".join(f"{rows[b]['nlos_median_cm']:6.1f} {100 * rows[b]['nlos_within_10cm']:5.1f} %" for b in (2, 3))
            print(f"  {loss:<4}{est:<8}{cells}   {res.final_loss:8.4f}   {dt:6.0f}   NLOS-labelled b2/b3: {nl}", flush=True)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
