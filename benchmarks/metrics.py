"""point_cloud_metrics on 200k × 200k clouds vs the bare cKDTree work it wraps (same run).

Run: .venv/bin/python benchmarks/metrics.py [N]
Prints the time of holodata.metrics.point_cloud_metrics and of two cKDTree builds + queries
(workers=-1) and their ratio (≈ 1 means no overhead beyond the KD-trees).
"""
from __future__ import annotations

import argparse

import numpy as np
from _run import best_of, header
from scipy.spatial import cKDTree

from holodata.metrics import point_cloud_metrics, prf_curve


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("n", type=int, nargs="?", default=200_000, help="points per cloud (default 200000)")
    n = ap.parse_args(argv).n
    header()
    rng = np.random.default_rng(0)
    # surface-like clouds: points on the walls of a 6 m x 4 m room, GT and a noisy prediction
    def room(k):
        t = rng.uniform(0, 1, k)
        side = rng.integers(0, 4, k)
        x = np.where(side < 2, t * 6, np.where(side == 2, 0, 6))
        y = np.where(side < 2, np.where(side == 0, 0, 4), t * 4)
        return np.stack([x, y, rng.uniform(-1, 2, k)], 1)

    G = room(n)
    P = room(n) + rng.normal(scale=0.03, size=(n, 3))

    def bare():
        dp = cKDTree(G).query(P, k=1, workers=-1)[0]
        dg = cKDTree(P).query(G, k=1, workers=-1)[0]
        return dp.mean() + dg.mean()

    t_bare = best_of(bare, 5)
    t_ours = best_of(lambda: point_cloud_metrics(P, G, tau=0.10), 5)
    t_curve = best_of(lambda: prf_curve(P, G), 5)
    m = point_cloud_metrics(P, G)
    assert abs(m["cd"] - bare()) < 1e-9
    print(f"{n} x {n} points: point_cloud_metrics {t_ours * 1e3:.0f} ms, prf_curve {t_curve * 1e3:.0f} ms, "
          f"bare cKDTree build+query x2 {t_bare * 1e3:.0f} ms; ratio {t_ours / t_bare:.2f}")
    print(f"cd={m['cd'] * 100:.2f} cm mhd={m['mhd'] * 100:.2f} cm F@10cm={m['f_score']:.3f}")


if __name__ == "__main__":
    main()
