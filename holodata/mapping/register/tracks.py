"""The person's track over the frames, smoothed as far as its own noise allows (:func:`track_smooth`,
:func:`smooth_window`): on a far, coarse camera each frame's solid is placed to several cm, independently
from frame to frame, while a walking person's centre moves smoothly (docs/design/register.md); the
track checks (:func:`track_jumps`, :func:`track_velocity`) and the person's motion from it
(:func:`track_prediction`, :func:`velocity_shift`, :func:`radial_speed`, :func:`side_back`)."""
from __future__ import annotations

import numpy as np

from .config import RegisterConfig

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


# ------------------------------------------------------------------------------------ checks and motion
def track_jumps(centroids: np.ndarray, t_ns: np.ndarray, jump_m: float = RegisterConfig.track_jump_m,
                speed_mps: float = RegisterConfig.walk_speed_mps) -> np.ndarray:
    """(T,) bool: frames whose centroid (``centroids`` (T,3), NaN = none) a person on the track cannot
    have walked to: farther (plan) than ``jump_m`` (m) + ``speed_mps`` (m/s) × the time between them
    (``t_ns`` (T,)) from where the track is before and after.

    The frames with a centroid split into runs at each such step between consecutive ones. A run is
    flagged when the track passes around it: the runs either side of it reach each other, and one of
    them is at least as long; a single frame at either end of the track, cut from the rest, is
    flagged too. A single wrong frame is a run of one; so is a run of frames on another object (a
    still box the background kept, larger than the far person while it is there: held-out
    hidden-depth16-64 seed 6, docs/design/register.md), which a test of each frame against its own neighbours — the other
    frames of that run — let through. A run cut on one side only (far stereo noise moving one frame
    over the limit) stays. The defaults are :class:`RegisterConfig`'s ``track_jump_m`` and
    ``walk_speed_mps`` (what register passes)."""
    c = np.asarray(centroids, float)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1))
    out = np.zeros(len(c), bool)
    if len(ok) < 2:
        return out

    def reach(a: int, b: int) -> bool:
        return bool(np.linalg.norm(c[a, :2] - c[b, :2]) <= jump_m + speed_mps * abs(t[a] - t[b]))

    cut = np.flatnonzero([not reach(a, b) for a, b in zip(ok[:-1], ok[1:])]) + 1
    runs = np.split(ok, cut)
    for i, r in enumerate(runs):
        if 0 < i < len(runs) - 1:
            p, n = runs[i - 1], runs[i + 1]
            out[r] = len(r) <= max(len(p), len(n)) and reach(p[-1], n[0])
        elif len(runs) > 1:
            out[r] = len(r) == 1
    return out


def track_prediction(centroids: np.ndarray, t_ns: np.ndarray, max_gap_s: float = 2.0) -> np.ndarray:
    """(T,3) where each frame's centroid is expected from its neighbours: the nearest frame with a
    centroid on each side (within ``max_gap_s``), linearly interpolated in time (``t_ns`` (T,)), or
    the one side's centroid when only one exists; NaN when none. ``centroids`` (T,3), NaN = none."""
    c = np.asarray(centroids, float)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    ok = np.flatnonzero(np.isfinite(c).all(1))
    out = np.full_like(c, np.nan)
    for k in range(len(c)):
        before = ok[(ok < k) & (t[k] - t[ok] <= max_gap_s)]
        after = ok[(ok > k) & (t[ok] - t[k] <= max_gap_s)]
        a = before[-1] if len(before) else None
        b = after[0] if len(after) else None
        if a is not None and b is not None and t[b] > t[a]:
            out[k] = c[a] + (c[b] - c[a]) * (t[k] - t[a]) / (t[b] - t[a])
        elif a is not None or b is not None:
            out[k] = c[a if a is not None else b]
    return out


def track_velocity(centroids: np.ndarray, cam_ts: np.ndarray, max_speed: float = RegisterConfig.max_speed_mps) -> np.ndarray:
    """(T,3) plan velocity (m/s, z = 0) of the centroid track ``centroids`` (T,3) (NaN: no detection) by
    central differences over the frames with a detection and a camera stamp ``cam_ts`` (T,) ns (zero
    where it cannot be estimated: a single detection, neighbours more than 2 s apart, or faster than
    ``max_speed``, a wrong detection next door rather than a walking person)."""
    n = len(centroids)
    out = np.zeros((n, 3))
    ok = np.isfinite(centroids).all(1) & (cam_ts != 0)
    idx = np.flatnonzero(ok)
    if len(idx) < 2:
        return out
    t = cam_ts[idx].astype(np.float64) / 1e9
    c = centroids[idx]
    for j, k in enumerate(idx):
        a, b = max(j - 1, 0), min(j + 1, len(idx) - 1)
        if t[b] - t[a] <= 0 or t[b] - t[a] > 2.0:
            continue
        v = (c[b] - c[a]) / (t[b] - t[a])
        v[2] = 0.0
        if np.linalg.norm(v) > max_speed:
            continue
        out[k] = v
    return out


def velocity_shift(centroids: np.ndarray, cam_ts: np.ndarray, frame_ts: np.ndarray,
                   max_speed: float = RegisterConfig.max_speed_mps) -> np.ndarray:
    """(T,3) shifts = velocity (:func:`track_velocity`) · (frame time − camera time)."""
    v = track_velocity(centroids, cam_ts, max_speed)
    return v * ((np.asarray(frame_ts, np.int64) - np.asarray(cam_ts, np.int64)) / 1e9)[:, None]


def radial_speed(centroids: np.ndarray, cam_ts: np.ndarray, eye: np.ndarray,
                 max_speed: float = RegisterConfig.max_speed_mps) -> np.ndarray:
    """(T,) m/s: how fast the person walks along the camera's view in each frame — the larger of the
    one-sided plan speeds toward the previous and the next detection (within 2 s, at most ``max_speed``)
    along the plan direction from ``eye`` (3,) to the frame's centroid (``centroids`` (T,3), NaN: no
    detection; ``cam_ts`` (T,) ns, 0: none). One-sided: at a turn the central difference is near zero
    while the legs are still in stride. 0 without a neighbour."""
    c = np.asarray(centroids, float)
    out = np.zeros(len(c))
    idx = np.flatnonzero(np.isfinite(c).all(1) & (np.asarray(cam_ts) != 0))
    t = np.asarray(cam_ts, np.int64)[idx] / 1e9
    for j, k in enumerate(idx):
        u = c[k, :2] - np.asarray(eye, float)[:2]
        nu = np.linalg.norm(u)
        if nu < 1e-9:
            continue
        for m in (j - 1, j + 1):
            if 0 <= m < len(idx) and 0 < abs(t[m] - t[j]) <= 2.0:
                v = (c[idx[m], :2] - c[k, :2]) / (t[m] - t[j])
                if np.linalg.norm(v) <= max_speed:
                    out[k] = max(out[k], abs(float(v @ u)) / nu)
    return out


def track_heading_velocity(centroids: np.ndarray, t_ns: np.ndarray, half_window_s: float = 0.5,
                           max_speed: float = RegisterConfig.max_speed_mps) -> np.ndarray:
    """(T,2) plan velocity (m/s) of the centroid track ``centroids`` (T,3) (NaN: no detection) at stamps
    ``t_ns`` (T,) (0: none): the least-squares slope of the detections within ``half_window_s`` either
    side (at least three, spanning at least half of ``half_window_s``: one-sided at the track's ends),
    zero where there are fewer or it is faster than ``max_speed``. A slope over a second averages a
    far person's per-frame centroid noise that central differences over two frames (:func:`track_velocity`)
    would turn into a velocity: the direction is the person's heading, not the noise's."""
    c = np.asarray(centroids, float)
    out = np.zeros((len(c), 2))
    t_all = np.asarray(t_ns, np.int64)
    idx = np.flatnonzero(np.isfinite(c).all(1) & (t_all != 0))
    if len(idx) < 3:
        return out
    t = (t_all[idx] - t_all[idx[0]]) / 1e9
    xy = c[idx, :2]
    lo = np.searchsorted(t, t - half_window_s, "left")
    hi = np.searchsorted(t, t + half_window_s, "right")
    for j, k in enumerate(idx):
        tt, pp = t[lo[j]:hi[j]], xy[lo[j]:hi[j]]
        if len(tt) < 3 or tt[-1] - tt[0] < 0.5 * half_window_s:
            continue
        dt = tt - tt.mean()
        v = dt @ (pp - pp.mean(0)) / (dt @ dt)
        if np.linalg.norm(v) <= max_speed:
            out[k] = v
    return out


def side_back(centroids: np.ndarray, t_ns: np.ndarray, eye: np.ndarray, ratio: float,
              heading_speed: float = RegisterConfig.heading_speed_mps,
              max_speed: float = RegisterConfig.max_speed_mps) -> np.ndarray:
    """(T,) how much deeper than its visible width's model a walking body is along the camera's view,
    as a fraction of that model's depth (:func:`body_columns`' ``back_frac``).

    A body's cross-section is about an ellipse ``ratio`` (breadth across the shoulders / depth, about
    2) times as wide across the person's heading as along it. :func:`body_columns` models the depth
    along the view from what the camera sees, the front: a torso capped at its depth, limbs as deep as
    wide. That is right for a person facing the camera or walking along its view; one walking across
    it shows their side, and the far arm, leg and shoulder are hidden behind the near ones. The ellipse
    with axes ``ratio`` · B (across the heading) and B (along it) is sqrt(``ratio``² sin²ψ + cos²ψ) · B
    deep along a view at angle ψ to the heading: the far end goes that, less 1, times the model's depth
    further back. ψ is between the plan direction from ``eye`` (3,) to each centroid (``centroids``
    (T,3), NaN: none; stamps ``t_ns`` (T,)) and the track's heading (:func:`track_heading_velocity`),
    weighted by min(1, speed / ``heading_speed``): a person standing still has no heading, and gets 0."""
    c = np.asarray(centroids, float)
    v = track_heading_velocity(c, t_ns, max_speed=max_speed)
    u = c[:, :2] - np.asarray(eye, float)[:2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        speed = np.linalg.norm(v, axis=1)
        cos = np.abs(np.sum(u * v, axis=1)) / speed
    sin2 = np.clip(1.0 - np.nan_to_num(cos, nan=1.0) ** 2, 0.0, 1.0)
    deeper = np.sqrt(ratio ** 2 * sin2 + (1.0 - sin2)) - 1.0
    return np.where(speed > 0, deeper * np.minimum(1.0, speed / heading_speed), 0.0)


def cut_prediction(centroids: np.ndarray, t_ns: np.ndarray, cut: np.ndarray,
                   half_window_s: float = RegisterConfig.cut_window_s) -> np.ndarray:
    """(T,3) where the person of each ``cut`` frame (T,) bool (partly hidden:
    :func:`~.humans.silhouette_cut`) is, from the whole frames' centroids around it: the least-squares
    line in time through the uncut detections within ``half_window_s`` either side (at least three,
    spanning at least a quarter of ``half_window_s``), evaluated at the frame's stamp — one-sided as the
    person walks into or out of sight behind a corner, where the cut frames are. NaN where there are
    fewer, for uncut frames, and where a frame has no detection. ``centroids`` (T,3), NaN = none;
    ``t_ns`` (T,) ns."""
    c = np.asarray(centroids, float)
    out = np.full_like(c, np.nan)
    t = np.asarray(t_ns, np.int64).astype(np.float64) / 1e9
    whole = np.isfinite(c).all(1) & ~np.asarray(cut, bool)
    for k in np.flatnonzero(np.asarray(cut, bool) & np.isfinite(c).all(1)):
        near = whole & (np.abs(t - t[k]) <= half_window_s)
        tt = t[near]
        if len(tt) < 3 or tt.max() - tt.min() < 0.25 * half_window_s:
            continue
        A = np.stack([np.ones(len(tt)), tt - t[k]], 1)
        coef, *_ = np.linalg.lstsq(A, c[near], rcond=None)
        out[k] = coef[0]
    return out
