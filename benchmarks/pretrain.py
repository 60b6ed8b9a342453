"""Train the weights holodata ships (``holodata evaluate DS --checkpoint pretrained``, issue 42
point 6): stage one + stage two at the quick demo's settings on a synthetic training corpus,
scored on held-out corners, everything recorded in the checkpoint, then copied (without optimiser
state) into ``holodata/torch/pretrained/``.

    .venv/bin/python benchmarks/pretrain.py [--out DIR] [--corners 64] [--frames 4] [--steps 600]
        [--stage2-frames 2] [--no-install]

Data: ``holodata synth --corners`` corpora at the quick demo's 32×128 beams and range bins
(:mod:`holodata.synth.corpus`). Training: corpus seed 0, corners 0..N-1. Held-out corners, by the
rule of benchmarks/stage1_loss.py fixed before any run: corpus seed 1000000 (never trained or
tuned on); the *check* set (its first 2 corners × 2 frames) is what tests/test_pretrained.py
rebuilds and rescores, the *report* set (16 corners × ``--frames``) gives the numbers to quote.
"""
from __future__ import annotations

import argparse
import math
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HELDOUT_SEED = 1_000_000


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/holodata-pretrain")
    ap.add_argument("--corners", type=int, default=64, help="training corners (corpus seed 0)")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--steps", type=int, default=600, help="stage-one gradient steps (batch 4)")
    ap.add_argument("--stage2-frames", type=int, default=2, help="frames per training corner for stage two")
    ap.add_argument("--no-install", action="store_true", help="do not copy the weights into the package")
    a = ap.parse_args(argv)

    from holodata.evaluate.pipeline import evaluate
    from holodata.synth.corpus import CorpusConfig, synth_corpus
    from holodata.torch import TrainConfig, train
    from holodata.torch.pretrained import CHECK_SET, install, scores
    from holodata.torch.stage2_train import Stage2Config, train_stage2

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train_cfg = CorpusConfig(corners=a.corners, frames=a.frames, seed=0, n_test=0)
    report_cfg = CorpusConfig(corners=16, frames=a.frames, seed=HELDOUT_SEED, n_test=16)
    check_cfg = CorpusConfig(**CHECK_SET)
    urls = {}
    for name, cc in (("train", train_cfg), ("report", report_cfg), ("check", check_cfg)):
        urls[name] = str(out / f"{name}_s{cc.seed}_{cc.corners}x{cc.frames}.zarr")
        synth_corpus(urls[name], cc, quiet=True)
    print(f"corpora ready ({time.perf_counter() - t0:.0f} s); held-out rule: corpus seed {HELDOUT_SEED}", flush=True)

    epochs = max(1, math.ceil(a.steps * 4 / (a.corners * a.frames)))
    cfg = TrainConfig(epochs=epochs, depth=6, base_channels=8, max_channels=64, range_pool=2, range_loss="ce")
    s2 = Stage2Config.from_dict({"epochs_rt": 3, "epochs_refine": 2, "channels": 16,
                                 "frames_per_scene": a.stage2_frames})
    run = out / f"run_{a.corners}x{a.frames}_{a.steps}"
    t1 = time.perf_counter()
    train(urls["train"], run, cfg, quiet=True)
    train_stage2(urls["train"], run, s2, quiet=True)
    train_s = time.perf_counter() - t1
    print(f"trained stage one ({epochs} epochs) and stage two in {train_s:.0f} s", flush=True)

    recorded = {}
    for name in ("check", "report"):
        doc = evaluate(urls[name], run, out / f"eval_{name}", split="test", quiet=True, report=False)
        recorded[name] = scores(doc)
        print(f"{name} set:")
        for method, row in recorded[name].items():
            print(f"  {method:<16}" + "  ".join(f"{k} {v:.4g}" for k, v in row.items()))
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    def corpus(cc) -> dict:
        return {"corners": cc.corners, "frames": cc.frames, "seed": cc.seed, "n_test": cc.n_test,
                "grid": cc.grid.to_attrs(), "range_bins": cc.range_bins.to_attrs()}

    record = {"command": " ".join(shlex.quote(x) for x in ["python", *sys.argv]), "commit": commit,
              "train_corpus": corpus(train_cfg), "heldout_report": corpus(report_cfg),
              "heldout_check": corpus(check_cfg), "train_config": cfg.to_dict(), "stage2_config": s2.to_dict(),
              "train_seconds": round(train_s, 1), "scores": recorded}
    if not a.no_install:
        dest = install(run, record)
        print(f"installed {dest}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
