"""Benchmark: `holodata.geometry.planes.window_plane_normals`, numpy version vs the compiled kernel.

Builds a (3, 64, 512, 3) point image (three bounces' images at the paper's grid) from synthetic
corner-like range images: a box room with walls a few metres off (different for each bounce), 2 cm
range noise, NaN where a beam has no return (a doorway of open space and random dropouts); the
start normals are the finite-difference ones (``normals_from_range(method="difference")``, what
``normals_from_range`` feeds it). Times the numpy reference (``_window_plane_normals_numpy``) and
the kernel, best of ``--repeat``, after a warm-up call of each (numba compiles or loads its cache),
checks they agree and prints both times and the ratio.

    .venv/bin/python benchmarks/planes.py [--repeat 3] [--batch 3] [--grid 64x512]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from _run import best_of, header

from holodata.conventions import Grid
from holodata.geometry.planes import _window_plane_normals_numpy, window_plane_normals
from holodata.geometry.unmirror import normals_from_range


def room_ranges(grid: Grid, walls, noise: float, rng) -> np.ndarray:
    """(H,W) range image of a box room about the origin, walls ``[(axis, position), …]``, with
    Gaussian range noise, NaN through a doorway in the first wall (open space: nothing within
    range) and on 2 % random dropouts."""
    d = grid.directions()
    t = np.full(d.shape[:2], np.inf)
    first = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, pos in walls:
            ti = np.where(d[..., axis] * pos > 0, pos / d[..., axis], np.inf)
            first = ti if first is None else first
            t = np.minimum(t, ti)
        p = t[..., None] * d
        door = (t == first) & (np.abs(p[..., 1] - 0.3) < 0.5) & (p[..., 2] < 1.2)
    t[door] = np.inf
    R = t + rng.normal(0, noise, t.shape)
    R[~np.isfinite(t) | (rng.random(t.shape) < 0.02)] = np.nan
    return R


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--batch", type=int, default=3, help="images (bounces)")
    ap.add_argument("--grid", default="64x512", help="HxW")
    args = ap.parse_args()
    header()
    H, W = (int(v) for v in args.grid.split("x"))
    grid = Grid(H, W)
    rng = np.random.default_rng(0)
    R = np.stack([room_ranges(grid, [(0, 3.0 + b), (0, -2.5), (1, 2.0 + 0.5 * b), (1, -1.8), (2, 2.2), (2, -1.0)],
                              0.02, rng) for b in range(args.batch)])
    d = grid.directions()
    P = R[..., None] * d
    n0 = normals_from_range(R, grid, method="difference")
    print(f"point image {P.shape}, {np.isnan(R).mean():.1%} no return, "
          f"{np.isfinite(n0).all(-1).mean():.1%} with a start normal")

    t0 = time.perf_counter()
    out = window_plane_normals(P, n0)                        # warm-up: numba compiles / loads its cache
    print(f"kernel warm-up (compile or cache load): {time.perf_counter() - t0:.2f} s")
    ref = _window_plane_normals_numpy(P, n0)
    assert np.array_equal(np.isnan(out), np.isnan(ref))
    print(f"max |kernel - numpy| = {np.nanmax(np.abs(out - ref)):.2e}")

    t_np = best_of(lambda: _window_plane_normals_numpy(P, n0), args.repeat)
    t_nb = best_of(lambda: window_plane_normals(P, n0), args.repeat)
    print(f"numpy  {t_np * 1e3:8.1f} ms   (best of {args.repeat})")
    print(f"kernel {t_nb * 1e3:8.1f} ms   (best of {args.repeat})")
    print(f"ratio  {t_np / t_nb:8.1f} x")


if __name__ == "__main__":
    main()
