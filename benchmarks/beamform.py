"""Benchmark: rotating-array beamforming (:func:`holodata.radar.beamform.beamform`) at full size.

One rotation of raw FMCW samples (1024 chirp positions x 8 virtual antennas x 256 samples, a few
point scatterers plus noise and leakage from :mod:`holodata.radar.simulate`) becomes a
64 x 512 x 256 heatmap, at rest (FFT over the chirp axis) and on a moving platform (direct sum
over each beam's window), with PanoRadar's far-field compensation and with near-field focusing
(``focus="near"``, :mod:`holodata.radar.beamform_near`). In the same run the plain direct-sum
formulation of the same algorithm (``tests/_radar_reference.py``, ``beamform_direct`` and
``beamform_direct_near``: no FFT over chirps, nothing shared between beams) forms a sample of the
beams, and its time is scaled to a full rotation; the script prints rotations/s of both and their
ratio. ``--device cuda`` times the torch path as well (the ``device`` tool's GPU machine; far
field only).

    .venv/bin/python benchmarks/beamform.py [--repeat 3] [--reference-beams 8] [--device cuda]

Floors (on a 2-core CPU): static >= 2 rotations/s, motion-compensated >= 0.5.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import time
from pathlib import Path

import numpy as np
from _run import best_of, header

from holodata.radar import BeamformParams, beam_indices, beamform, static_reflection
from holodata.radar.chirp import ChirpConfig
from holodata.radar.simulate import RigEffects, point_at, simulate_rotation

ROOT = Path(__file__).resolve().parents[1]


def _reference():
    """The direct-sum reference (``tests/_radar_reference.py``, which lives with the tests), loaded from
    its file: no sys.path edit, so no module of the tests folder shadows an installed one."""
    spec = importlib.util.spec_from_file_location("_radar_reference", ROOT / "tests" / "_radar_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_ref = _reference()
beamform_direct, beamform_direct_near = _ref.beamform_direct, _ref.beamform_direct_near

VELOCITY = (0.35, 0.12)   # m/s: a walking-pace robot


def rotation_data(chirp: ChirpConfig, n_syn_half: int, seed: int = 0):
    """One rotation (and the neighbouring chirps a moving platform's beams need) of five scatterers."""
    rng = np.random.default_rng(seed)
    pts = np.stack([point_at(r, a, e) for r, a, e in
                    zip(rng.uniform(1.0, 8.0, 5), rng.uniform(-np.pi, np.pi, 5), rng.uniform(-0.5, 0.5, 5))])
    leak = (0.05 * np.exp(-np.arange(chirp.n_samples) / 4.0))[None, :].repeat(chirp.n_virtual, 0)
    return simulate_rotation(pts, chirp=chirp, velocity=VELOCITY, pad=n_syn_half,
                             effects=RigEffects(noise_std=1e-3, leakage=leak, rng=seed))


def timed(fn, repeat: int) -> float:
    """Best wall time of ``repeat`` calls after one that warms caches (kernel spectra, FFT plans)."""
    fn()
    return best_of(fn, repeat)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed calls per case (best is reported)")
    ap.add_argument("--reference-beams", type=int, default=8,
                    help="beams the direct-sum reference forms (its time is scaled to all 512 columns)")
    ap.add_argument("--device", default="cpu", help="also time the torch path on this device (e.g. cuda)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    a = ap.parse_args(argv)
    header()

    chirp = ChirpConfig()
    params = BeamformParams()
    N = chirp.chirps_per_rotation
    h = (params.syn_count(N) - 1) // 2
    print(f"simulating one rotation: {N} chirps x {chirp.n_virtual} antennas x {chirp.n_samples} samples ...",
          flush=True)
    rot, before, after = rotation_data(chirp, h)
    refl = static_reflection(rot)
    out: dict = {"size": f"{N}x{chirp.n_virtual}x{chirp.n_samples} -> {params.n_range or chirp.n_samples}x"
                         f"{params.grid.H}x{params.grid.W}"}
    near = BeamformParams(focus="near")
    moving = {"velocity": VELOCITY, "neighbours": (before, after)}
    cases = {"static": (params, {}), "motion": (params, moving),
             "static-near": (near, {}), "motion-near": (near, moving)}
    beams = beam_indices(N, params.grid.W)
    pick = beams[np.linspace(0, beams.size - 1, a.reference_beams).round().astype(int)]
    for name, (prm, kw) in cases.items():
        fast = timed(lambda kw=kw, prm=prm: beamform(rot, chirp, prm, static_refl=refl, **kw), a.repeat)
        t0 = time.perf_counter()
        ref_fn = beamform_direct_near if prm.focus == "near" else beamform_direct
        ref_fn(rot, chirp, prm, static_refl=refl, beams=pick, **kw)
        ref = (time.perf_counter() - t0) * beams.size / pick.size
        out[name] = {"seconds": fast, "rotations_per_s": 1.0 / fast, "direct_sum_seconds_per_rotation": ref,
                     "direct_sum_rotations_per_s": 1.0 / ref, "speedup_vs_direct_sum": ref / fast}
        line = (f"{name:11s} holodata {1 / fast:7.2f} rotations/s ({fast:6.3f} s)   direct sums {1 / ref:8.4f} "
                f"rotations/s ({ref:7.1f} s, from {pick.size} beams)   ratio {ref / fast:7.1f}x")
        if a.device != "cpu" and prm.focus == "far":
            try:
                dev = timed(lambda kw=kw: beamform(rot, chirp, params, static_refl=refl, device=a.device, **kw),
                            a.repeat)
            except Exception as err:  # noqa: BLE001 - no torch / no GPU: say so, keep the CPU numbers
                line += f"   {a.device}: unavailable ({' '.join(str(err).split())[:80]})"
            else:
                out[name][f"{a.device}_rotations_per_s"] = 1.0 / dev
                line += f"   {a.device} {1 / dev:7.2f} rotations/s ({fast / dev:5.1f}x the CPU)"
        print(line, flush=True)
    floors = {"static": 2.0, "motion": 0.5, "static-near": 2.0, "motion-near": 0.5}
    for name, floor in floors.items():
        ok = out[name]["rotations_per_s"] >= floor
        print(f"floor {name}: >= {floor} rotations/s: {'met' if ok else 'MISSED'}")
    # near vs far interleaved, call by call: on a shared machine the load changes between the cases
    # above, so their ratio is measured here with both sides under the same load
    for kind, kw in (("static", {}), ("motion", moving)):
        best = {"far": float("inf"), "near": float("inf")}
        for _ in range(a.repeat):
            for focus, prm in (("far", params), ("near", near)):
                t0 = time.perf_counter()
                beamform(rot, chirp, prm, static_refl=refl, **kw)
                best[focus] = min(best[focus], time.perf_counter() - t0)
        out[f"{kind}_near_over_far"] = best["near"] / best["far"]
        print(f"{kind}: near / far time, interleaved: {best['near'] / best['far']:.2f} "
              f"({best['near']:.3f} s / {best['far']:.3f} s)")
    if a.json:
        print(json.dumps(out, indent=1, default=float))
    return out


if __name__ == "__main__":
    main()
