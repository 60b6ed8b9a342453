"""The README's "Your own recording" recipe, with default settings, on 8 synthetic corners of every
kind and widths 1.3-4.7 m (the recipe's acceptance test): per step its wall time; per data pass whether
register placed the person, the person's centroid error against the truth (median / p90 cm), and
whether the ground truth holds the person in every frame where ground truth traced from the true
mesh and person does; then evaluate's scores on the test split.

    .venv/bin/python benchmarks/own_recording.py --out /tmp/own8 [--frames 6] [--keep]

The corners (kind, seed, width) are fixed below, chosen before any result was seen; the test split
is the last two (a fixed rule: seeds 16 and 17). Every command is the CLI exactly as a user types it.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _run import header

CORNERS = [("T", 10, 1.3), ("L", 11, 4.7), ("cross", 12, 2.3), ("oblique", 13, 3.7),
           ("T", 14, 4.2), ("L", 15, 1.8), ("cross", 16, 3.2), ("oblique", 17, 2.8)]
HOLODATA = str(Path(sys.executable).with_name("holodata"))


def run(args: list[str]) -> float:
    """Run ``holodata ARGS``; its wall seconds (stops the script with the command's output on failure)."""
    t0 = time.perf_counter()
    r = subprocess.run([HOLODATA, *args], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"holodata {' '.join(args)} failed (exit {r.returncode}):\n{r.stdout}{r.stderr}")
    return time.perf_counter() - t0


def has_person(url: str, scene: str) -> np.ndarray:
    """(T,) whether each frame's ground truth holds human returns (labels LOS/NLOS human)."""
    from holodata.conventions import is_human
    from holodata.dataset import open_dataset

    lab = np.asarray(open_dataset(url).scene(scene)["gt/label"][...])
    return is_human(lab).reshape(len(lab), -1).any(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--keep", action="store_true", help="keep the recordings and the dataset")
    a = ap.parse_args()
    header()
    out, ds = a.out, str(a.out / "ds.zarr")
    ids = [f"{k}{s}" for k, s, _ in CORNERS]
    t: dict[str, float] = {"synth": 0.0}
    for (kind, seed, width), sid in zip(CORNERS, ids):
        t["synth"] += run(["synth", "--out", str(out / sid), "--corner", kind, "--frames", str(a.frames),
                           "--grid", "32x128", "--seed", str(seed), "--width", str(width)])
    t["ingest"] = run(["ingest", *[str(out / s) for s in ids], "--out", ds])
    t["slam"] = run(["slam", ds])
    t["register"] = run(["register", ds])
    t["raytrace-gt"] = run(["raytrace-gt", ds])
    t["split"] = run(["split", ds, "--test", ids[-2], "--test", ids[-1]])
    t["validate"] = run(["validate", ds])
    t["train"] = run(["train", ds, "--out", str(out / "run"), "--epochs", "2"])
    t["evaluate"] = run(["evaluate", ds, "--checkpoint", str(out / "run"), "--out", str(out / "report")])

    from holodata.dataset import open_dataset
    from holodata.dataset.splits import scene_role
    from holodata.evaluate.register_accuracy import human_centroid_errors

    d = open_dataset(ds)
    rows = []
    for (kind, seed, width), sid in zip(CORNERS, ids):
        truth = out / sid / "truth"
        reg = d.scene(sid).attrs.get("register")
        c = human_centroid_errors(ds, sid, truth) if reg else None
        tgt = str(out / f"truth_gt_{sid}.zarr")   # GT from the true mesh and person, the same grid
        run(["raytrace-gt", "--mesh", str(truth / "mesh.ply"), "--poses", str(truth / "trajectory_radar.tum"),
             "--human-dir", str(truth / "human"), "--out", tgt, "--scene-id", sid, "--grid", "32x128", "--quiet"])
        want, have = has_person(tgt, sid), has_person(ds, sid)
        per = np.asarray(c["per_frame_cm"], float) if c else np.zeros(0)
        rows.append({"scene": sid, "kind": kind, "seed": seed, "width_m": width, "registered": bool(reg),
                     "centroid_median_cm": float(np.median(per)) if per.size else None,
                     "centroid_p90_cm": float(np.percentile(per, 90)) if per.size else None,
                     "frames_truth_person": int(want.sum()), "frames_gt_person": int(have.sum()),
                     "frames_person_lost": int((want & ~have).sum())})
    metrics = json.loads((out / "report" / "metrics.json").read_text())
    model = metrics["methods"]["model"]
    summary = {"seconds": {k: round(v, 1) for k, v in t.items()}, "scenes": rows,
               "roles": {s: scene_role(d.scene(s).attrs) for s in d.scenes}, "splits": d.splits,
               "evaluate": {"los_f": model["points"]["los"]["f_score"], "nlos_f": model["points"]["nlos"]["f_score"],
                            "human_f": model["human"]["f_score"], "frames": metrics["n_frames"]}}
    print(json.dumps(summary, indent=1))
    print("| scene | kind | width m | registered | centroid median / p90 cm | frames with the person: truth GT / GT / lost |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        cm = "–" if r["centroid_median_cm"] is None else f"{r['centroid_median_cm']:.1f} / {r['centroid_p90_cm']:.1f}"
        print(f"| {r['scene']} | {r['kind']} | {r['width_m']} | {'yes' if r['registered'] else 'NO'} | {cm} | "
              f"{r['frames_truth_person']} / {r['frames_gt_person']} / {r['frames_person_lost']} |")
    print("steps (s): " + ", ".join(f"{k} {v:.1f}" for k, v in t.items()))
    if not a.keep:
        shutil.rmtree(out)


if __name__ == "__main__":
    main()
