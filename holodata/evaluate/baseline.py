"""The non-learned baseline: the three strongest range peaks per beam of the radar heatmap."""
from __future__ import annotations

import numpy as np

from holodata.conventions import RangeBins


def strongest_peaks(heatmap, range_bins: RangeBins, k: int = 3, min_snr_db: float = 6.0,
                    min_range_m: float = 0.25) -> np.ndarray:
    """(…,N_r,H,W) linear amplitude → (…,k,H,W) ranges (m), ascending per beam, NaN = none.

    Peaks are local maxima along range whose amplitude exceeds the beam's median by ``min_snr_db``,
    beyond ``min_range_m`` (the first bins hold the radar's near-field leakage, not a return);
    the ``k`` strongest are kept and refined by a parabola through log amplitudes.
    """
    a = np.asarray(heatmap, dtype=np.float32)
    ax = a.ndim - 3
    n = a.shape[ax]
    la = np.log10(np.maximum(a, 1e-12))
    pad = np.full_like(la.take([0], axis=ax), -np.inf)
    left = np.concatenate([pad, la.take(range(n - 1), axis=ax)], axis=ax)
    right = np.concatenate([la.take(range(1, n), axis=ax), pad], axis=ax)
    floor = np.median(la, axis=ax, keepdims=True)
    near = RangeBins(n, range_bins.dr).centres() < min_range_m   # (the heatmap's own bin count)
    near = near.reshape((n,) + (1,) * (a.ndim - ax - 1))
    peak = (la >= left) & (la > right) & (la > floor + min_snr_db / 20.0) & ~near
    score = np.where(peak, la, -np.inf)
    top = np.argsort(-score, axis=ax).take(range(min(k, n)), axis=ax)  # (…,k,H,W)
    s = np.take_along_axis(score, top, axis=ax)
    l0 = np.take_along_axis(la, top, axis=ax)
    lm = np.take_along_axis(left, top, axis=ax)
    lp = np.take_along_axis(right, top, axis=ax)
    den = lm - 2 * l0 + lp
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where(np.isfinite(den) & (den < 0), 0.5 * (lm - lp) / den, 0.0)
    r = (top + 0.5 + np.clip(off, -0.5, 0.5)) * range_bins.dr
    r = np.where(np.isfinite(s), r, np.nan).astype(np.float32)
    r = np.sort(r, axis=ax)  # NaN sorts last
    if r.shape[ax] < k:
        extra = list(r.shape)
        extra[ax] = k - r.shape[ax]
        r = np.concatenate([r, np.full(extra, np.nan, np.float32)], axis=ax)
    return r
