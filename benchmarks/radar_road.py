"""The road a rig records against the direct heatmaps, beam by beam: one synthetic corner recorded twice.

``holodata synth`` writes the same corner (same seed, same paths) once as direct heatmaps (the radar
model with the beamformer's point-spread function: what the training corpora hold) and once as raw
FMCW samples of every chirp of every rotation (``--radar-output iq``), which ``holodata ingest``
beamforms like a real rig's (``--beamform-grid``). Both datasets then hold heatmaps of the same
frames on the same grid; per beam they are compared on:

- **peak range**: the strongest return beyond 0.25 m (:func:`holodata.evaluate.baseline.strongest_peaks`,
  parabola-refined): |difference| median / p90 in range bins, and the share of beams within one bin;
- **the three strongest returns**: the share of the direct heatmap's that the raw one also has within 2 bins;
- **dynamic range**: the strongest peak over the beam's median, dB (median over beams);
- **range sidelobes**: the strongest local maximum 3-12 bins from the peak, below the peak, dB;
- **by elevation**: the peak-range difference in the upper, middle and lower third of the beams (a
  broader elevation beam lets a wall outshine the floor in the beams that look down);
- **noise floor**: the beam's median below the frame's strongest bin, dB;
- **near field**: the mean level of the bins within 1 m below the beam's peak, dB (leakage and focus).

Levels are relative (dB to a peak or to the frame's maximum), so the two roads' absolute scales do not
matter. The corner, grid and chirps are arguments; the default is the paper's 64×512 grid, whose
synthetic aperture needs 1024 chirp positions per rotation.

    .venv/bin/python benchmarks/radar_road.py [--grid 64x512] [--corner L] [--frames 2] [--seed 3] [--out DIR]

Measured numbers go to benchmarks/results/radar-road.md, not here.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _run import header

SIDELOBE_BINS = (3, 12)      # a range sidelobe: a local maximum this many bins from the peak
NEAR_FIELD_M = 1.0


def holodata(*args: str) -> None:
    """Run a holodata command of this environment; its output only when it fails."""
    exe = str(Path(sys.executable).with_name("holodata"))
    r = subprocess.run([exe, *args, "--quiet"], capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"holodata {' '.join(args)} failed:\n{r.stdout}{r.stderr}")


def record_both(out: Path, grid: str, corner: str, frames: int, seed: int, chirps: int) -> tuple[str, str]:
    """The corner synthesised and ingested twice: (direct heatmaps dataset, beamformed raw samples dataset)."""
    common = ["--corner", corner, "--frames", str(frames), "--grid", grid, "--no-mapping-pass", "--seed", str(seed)]
    holodata("synth", "--out", str(out / "direct"), *common)
    holodata("synth", "--out", str(out / "raw"), *common, "--radar-output", "iq", "--radar-chirps", str(chirps))
    holodata("ingest", str(out / "direct"), "--out", str(out / "direct.zarr"))
    holodata("ingest", str(out / "raw"), "--out", str(out / "raw.zarr"), "--beamform-grid", grid)
    return str(out / "direct.zarr"), str(out / "raw.zarr")


def beam_stats(hm: np.ndarray, rb) -> dict:
    """Per-beam statistics of one heatmap (R,H,W) linear amplitude (see the module docstring)."""
    from holodata.evaluate.baseline import strongest_peaks

    db = 20 * np.log10(np.maximum(hm, 1e-12))
    R, H, W = db.shape
    peaks = strongest_peaks(hm, rb, k=3)                           # (3,H,W) m ascending, NaN = none
    top = strongest_peaks(hm, rb, k=1)[0]                          # (H,W) the strongest
    pk = np.clip(np.nan_to_num(rb.index(np.nan_to_num(top)), nan=0).astype(int), 0, R - 1)
    e, a = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    level = db[pk, e, a]
    med = np.median(db, axis=0)
    r = np.arange(R)[:, None, None]
    off = np.abs(r - pk[None])
    local_max = (db >= np.roll(db, 1, 0)) & (db >= np.roll(db, -1, 0))
    side = np.where(local_max & (off >= SIDELOBE_BINS[0]) & (off <= SIDELOBE_BINS[1]), db, -np.inf).max(0)
    near = rb.centres() < NEAR_FIELD_M
    return {"top": top, "peaks": peaks, "dynamic_db": level - med, "sidelobe_db": level - side,
            "floor_db": db.max() - med, "near_db": level - db[near].mean(0), "valid": np.isfinite(top)}


def compare(direct: str, raw: str) -> list[tuple[str, str, str]]:
    """(quantity, direct heatmaps, beamformed raw samples) rows over every frame of the two datasets."""
    from holodata.dataset import open_dataset
    from holodata.dataset.heatmap import read_heatmap

    dd, dr = open_dataset(direct), open_dataset(raw)
    if dd.grid.to_attrs() != dr.grid.to_attrs():
        raise SystemExit(f"grids differ: {dd.grid} and {dr.grid}")
    rb = dd.range_bins
    sd, sr = dd.scene(dd.scenes[0]), dr.scene(dr.scenes[0])
    S = {"direct": [], "raw": []}
    for k in range(min(sd.n_frames, sr.n_frames)):
        S["direct"].append(beam_stats(read_heatmap(sd, k), rb))
        S["raw"].append(beam_stats(read_heatmap(sr, k), rb))
    dr_bins, found, thirds = [], [], [[], [], []]
    for a, b in zip(S["direct"], S["raw"]):
        ok = a["valid"] & b["valid"]
        diff = np.abs(a["top"] - b["top"]) / rb.dr
        dr_bins.append(diff[ok])
        for t, rows in enumerate(np.array_split(np.arange(diff.shape[0]), 3)):
            thirds[t].append(diff[rows][ok[rows]])
        for j in range(3):
            pa = a["peaks"][j]
            has = np.isfinite(pa)
            near = np.nanmin(np.abs(b["peaks"] - pa[None]), axis=0)[has] <= 2 * rb.dr
            found.append(near)
    dr_bins, found = np.concatenate(dr_bins), np.concatenate(found)

    def med(key: str) -> tuple[str, str]:
        vals = []
        for road in ("direct", "raw"):
            x = [s[key] for s in S[road]]
            v = np.concatenate([np.asarray(xi)[s["valid"]].ravel() for xi, s in zip(x, S[road])]) if key != "floor_db" \
                else np.asarray(x, float).ravel()
            v = v[np.isfinite(v)]
            vals.append(f"{np.median(v):6.1f}" if len(v) else "     –")
        return tuple(vals)

    rows = [("peak range |direct − raw|, bins: median / p90 / share ≤ 1 bin",
             f"{np.median(dr_bins):.2f} / {np.percentile(dr_bins, 90):.1f} / {np.mean(dr_bins <= 1):.2f}", "(vs direct)"),
            ("the direct heatmap's 3 strongest returns the raw one has within 2 bins", f"{found.mean():.2f}", "(vs direct)")]
    rows.append(("dynamic range: peak over the beam's median, dB", *med("dynamic_db")))
    rows.append((f"range sidelobe ({SIDELOBE_BINS[0]}-{SIDELOBE_BINS[1]} bins) below the peak, dB", *med("sidelobe_db")))
    for name, t in zip(("upper", "middle", "lower"), thirds):
        v = np.concatenate(t)
        rows.append((f"peak range |direct − raw| in the {name} third of the elevations, bins: median / share ≤ 1 bin",
                     f"{np.median(v):.1f} / {np.mean(v <= 1):.2f}", "(vs direct)"))
    rows.append(("noise floor: beam median below the frame's maximum, dB", *med("floor_db")))
    rows.append((f"near field (< {NEAR_FIELD_M:g} m): mean below the beam's peak, dB", *med("near_db")))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--grid", default="64x512")
    ap.add_argument("--corner", default="L")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--chirps", type=int, default=None, help="chirp positions per rotation (default: 2x the azimuth beams)")
    ap.add_argument("--out", help="keep the recordings and datasets here (default: a temporary folder)")
    a = ap.parse_args(argv)
    header()
    from holodata.conventions import Grid

    chirps = a.chirps or 2 * Grid.parse(a.grid).W
    out = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="hd_road_"))
    out.mkdir(parents=True, exist_ok=True)
    try:
        direct, raw = record_both(out, a.grid, a.corner, a.frames, a.seed, chirps)
        print(f"corner {a.corner} (seed {a.seed}), {a.frames} rotations, grid {a.grid}, raw samples of {chirps} chirp "
              f"positions per rotation beamformed by holodata ingest")
        print(f"  {'per beam (median over beams and frames)':<100} {'direct':>14} {'raw':>12}")
        for name, d, r in compare(direct, raw):
            print(f"  {name:<100} {d:>14} {r:>12}")
    finally:
        if not a.out:
            shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
