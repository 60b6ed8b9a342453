"""The person's track over the frames, smoothed as far as its own noise allows (:func:`track_smooth`,
:func:`smooth_window`): on a far, coarse camera each frame's solid is placed to several cm, independently
from frame to frame, while a walking person's centre moves smoothly (docs/design/register.md)."""
from __future__ import annotations

import numpy as np


# the bias of a local linear fit (tricube kernel, half-width W) at a walk's instant turn (the
# centroid v·|t|): v · W · ∫u(1-u³)³du / ∫(1-u³)³du over (0, 1)
TURN_BIAS = 0.318


def track_noise(centroids: np.ndarray, t_ns: np.ndarray, max_gap_s: float = 0.5) -> float:
    """The noise (m, the norm over x, y, z) of a frame's centroid in the track ``centroids`` (T,3)
    (NaN: none; ``t_ns`` (T,)): each detection's offset from the line through its neighbours (within
    ``max_gap_s``), divided by its standard deviation in units of the noise (sqrt(1 + a² + b²),
    a, b the interpolation weights), 1.4826 × MAD per axis (a walk's acceleration is a few cm
    over 0.1 s; its turns are outliers to the MAD). NaN with fewer than 5 such triples."""
    c = np.asarray(centroids, float)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1))
    if len(ok) < 7:
        return float("nan")
    a, m, b = ok[:-2], ok[1:-1], ok[2:]
    keep = (t[b] - t[a] <= 2 * max_gap_s) & (t[m] - t[a] > 0) & (t[b] - t[m] > 0)
    a, m, b = a[keep], m[keep], b[keep]
    if len(m) < 5:
        return float("nan")
    f = ((t[m] - t[a]) / (t[b] - t[a]))[:, None]
    r = (c[m] - (1 - f) * c[a] - f * c[b]) / np.sqrt(1 + f ** 2 + (1 - f) ** 2)
    mad = np.median(np.abs(r - np.median(r, 0)), 0)
    return float(np.linalg.norm(1.4826 * mad))


def track_speed(centroids: np.ndarray, t_ns: np.ndarray, base_s: float = 1.0) -> float:
    """The walking speed (m/s, plan) of the track ``centroids`` (T,3) (NaN: none; ``t_ns`` (T,)): the
    median over detections of the plan distance to the first detection at least ``base_s`` later
    (within 2 ``base_s``) over the time between (over a second a frame's noise adds little). NaN
    without such pairs."""
    c = np.asarray(centroids, float)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1))
    j = np.searchsorted(t[ok], t[ok] + base_s)
    sel = j < len(ok)
    i, j = ok[sel], ok[j[sel]]
    dt = t[j] - t[i]
    keep = dt <= 2 * base_s
    if not keep.any():
        return float("nan")
    return float(np.median(np.linalg.norm(c[j[keep], :2] - c[i[keep], :2], axis=1) / dt[keep]))


def smooth_window(centroids: np.ndarray, t_ns: np.ndarray) -> float:
    """Half-width (s) of :func:`track_smooth`'s kernel for the track ``centroids`` (T,3), ``t_ns``
    (T,): as wide as keeps the bias at an instant turn (:data:`TURN_BIAS` · speed · W) within a frame's
    own noise (:func:`track_noise`, :func:`track_speed`): wide on a far coarse camera (noise 10 cm,
    0.7 m/s: 0.45 s), nothing on a near one (3 cm at 1 m/s: 0.09 s, about a frame). 0 when either
    cannot be measured."""
    sigma, v = track_noise(centroids, t_ns), track_speed(centroids, t_ns)
    if not (np.isfinite(sigma) and np.isfinite(v)) or v <= 0:
        return 0.0
    return float(sigma / (TURN_BIAS * v))


def track_smooth(centroids: np.ndarray, weights: np.ndarray, t_ns: np.ndarray, window_s: float | None = None) -> np.ndarray:
    """(T,3) the centroid track ``centroids`` (T,3) (NaN: no detection) smoothed in time (``t_ns`` (T,)):
    at each detection, a local linear fit over the detections within ``window_s`` s (None:
    :func:`smooth_window`, from the track's own noise and speed) (tricube kernel in
    time × ``weights`` (T,), e.g. the frame's returns: the noise of a frame's centroid falls as 1/√n),
    then once more with each detection's weight scaled by the bisquare of its residual over 6 MADs of
    all residuals (robust LOWESS, Cleveland 1979: a frame whose far-noise centroid is 30 cm off moves
    its neighbours little). A detection with fewer than 3 others in its window keeps its centroid.

    Why: on a far, coarse camera a person is 20-60 returns (robot-cloud-32: 160 columns, 8-9 m,
    11 cm pixels, stereo σ 0.2-0.3 m) and each frame's solid is placed to σ/√n along the view and a
    pixel in height — errors of 7-9 cm that are independent from frame to frame, while a walking
    person's centre moves smoothly (docs/design/register.md)."""
    c = np.asarray(centroids, float)
    out = c.copy()
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1) & (np.asarray(weights, float) > 0))
    if window_s is None:
        window_s = smooth_window(c, t_ns)
    if len(ok) < 4 or window_s <= 0:
        return out
    tk, ck, wk = t[ok], c[ok], np.asarray(weights, float)[ok]
    robust = np.ones(len(ok))
    for _ in range(2):
        fit = ck.copy()
        for j in range(len(ok)):
            u = np.abs(tk - tk[j]) / window_s
            near = u < 1.0
            if near.sum() < 4:
                continue
            w = (1 - u[near] ** 3) ** 3 * wk[near] * robust[near]
            if w.sum() <= 0:
                continue
            dt = tk[near] - tk[j]
            A = np.stack([np.ones(len(dt)), dt], 1) * np.sqrt(w)[:, None]
            coef, *_ = np.linalg.lstsq(A, ck[near] * np.sqrt(w)[:, None], rcond=None)
            fit[j] = coef[0]
        res = np.linalg.norm(ck - fit, axis=1)
        s = 6.0 * np.median(res)
        robust = (1 - np.clip(res / max(s, 1e-9), 0.0, 1.0) ** 2) ** 2 if s > 0 else np.ones(len(ok))
    out[ok] = fit
    return out

