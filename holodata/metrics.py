"""The reference paper's metrics (docs/format.md §5), pure numpy/scipy — no torch.

Range images: mean / median / 90th-percentile absolute error (cm) and PSNR (dB, peak = max range)
over pixels where the ground truth is finite. Point clouds (metres): Chamfer distance as the SUM of
the two directed mean nearest-neighbour distances, modified Hausdorff distance (MHD) as their MAX,
precision / recall / F-score at a distance threshold τ (default 10 cm). Human detection: predicted
centroids matched one-to-one to ground-truth centres within 50 cm. Breakdown helpers group
per-scene results by corner shape, width band and attenuation band.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from holodata.conventions import DEFAULT_MAX_RANGE_M

DEFAULT_TAU_M = 0.10
HUMAN_MATCH_M = 0.50
HUMAN_CLUSTER_M = 0.30   # human points closer than this are one person (single linkage)
HUMAN_MIN_POINTS = 5     # a person is a cluster of at least this many human points
DEFAULT_TAUS_M = (0.02, 0.05, 0.10, 0.15, 0.20, 0.30, 0.50)


# ---------------------------------------------------------------------------------------------
# range images
def range_errors(pred, gt) -> np.ndarray:
    """Absolute range errors (metres, 1-D float64) over the pixels where ``gt`` is finite.

    ``pred``/``gt``: same shape, metres, NaN = no return. A missing prediction where the ground
    truth has a return counts as a prediction of 0 m (the paper's range images use 0 for "none"),
    so a model cannot improve its score by staying silent.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"pred shape {pred.shape} != gt shape {gt.shape}")
    m = np.isfinite(gt)
    p = pred[m]
    return np.abs(np.where(np.isfinite(p), p, 0.0) - gt[m])


def range_metrics_from_errors(err: np.ndarray, max_range: float = DEFAULT_MAX_RANGE_M, n_pred_finite: int | None = None) -> dict:
    """Summary of absolute errors ``err`` (metres): mean_cm, median_cm, p90_cm, psnr_db, n.

    PSNR = 10·log10(max_range² / MSE) with errors clipped at ``max_range``. No pixels → NaN values.
    """
    err = np.asarray(err, dtype=np.float64).ravel()
    n = int(err.size)
    if n == 0:
        return {"mean_cm": float("nan"), "median_cm": float("nan"), "p90_cm": float("nan"),
                "psnr_db": float("nan"), "n": 0}
    e = np.minimum(err, max_range)
    mse = float(np.mean(e * e))
    psnr = float("inf") if mse == 0.0 else float(10.0 * np.log10(max_range**2 / mse))
    out = {"mean_cm": float(err.mean() * 100.0), "median_cm": float(np.median(err) * 100.0),
           "p90_cm": float(np.percentile(err, 90) * 100.0), "psnr_db": psnr, "n": n}
    if n_pred_finite is not None:
        out["coverage"] = float(n_pred_finite) / n
    return out


def range_image_metrics(pred, gt, max_range: float = DEFAULT_MAX_RANGE_M) -> dict:
    """Range-image metrics over pixels where ``gt`` is finite (any shape; metres, NaN = none).

    Returns dict mean_cm, median_cm, p90_cm (absolute error, centimetres), psnr_db (peak =
    ``max_range``), n (pixels scored) and coverage (fraction of them with a finite prediction).
    All-NaN ground truth gives NaN metrics and n = 0.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    err = range_errors(pred, gt)
    n_fin = int(np.isfinite(pred[np.isfinite(gt)]).sum())
    return range_metrics_from_errors(err, max_range, n_pred_finite=n_fin)


# ---------------------------------------------------------------------------------------------
# point clouds
def _as_points(P) -> np.ndarray:
    P = np.asarray(P, dtype=np.float64)
    if P.size == 0:
        return P.reshape(0, 3)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"point cloud must be (N, 3), got {P.shape}")
    return P[np.all(np.isfinite(P), axis=1)]


def nn_distances(P, G, workers: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Directed nearest-neighbour distances (metres): (d_PG (N,), d_GP (M,)).

    ``d_PG[i] = min_g |P_i − g|``; an empty other cloud gives +inf distances. Non-finite rows are dropped.
    """
    P, G = _as_points(P), _as_points(G)
    if len(G):
        d_pg = cKDTree(G).query(P, k=1, workers=workers)[0] if len(P) else np.zeros(0)
    else:
        d_pg = np.full(len(P), np.inf)
    if len(P):
        d_gp = cKDTree(P).query(G, k=1, workers=workers)[0] if len(G) else np.zeros(0)
    else:
        d_gp = np.full(len(G), np.inf)
    return np.asarray(d_pg, dtype=np.float64), np.asarray(d_gp, dtype=np.float64)


def _prf(d_pg: np.ndarray, d_gp: np.ndarray, tau: float) -> tuple[float, float, float]:
    """Precision, recall, F at ``tau``. Empty prediction: precision 0; empty GT: recall 1 (vacuous);
    both empty: all 1."""
    if d_pg.size == 0 and d_gp.size == 0:
        return 1.0, 1.0, 1.0
    prec = float(np.mean(d_pg < tau)) if d_pg.size else 0.0
    rec = float(np.mean(d_gp < tau)) if d_gp.size else 1.0
    f = 0.0 if prec + rec == 0 else 2.0 * prec * rec / (prec + rec)
    return prec, rec, f


def point_cloud_metrics(P, G, tau: float = DEFAULT_TAU_M, cd_mode: str = "sum", squared: bool = False,
                        max_dist: float | None = None, workers: int = -1) -> dict:
    """Compare predicted cloud ``P`` (N,3) with ground truth ``G`` (M,3), metres.

    Default (docs/format.md §5): ``cd = mean_p min_g |p−g| + mean_g min_p |g−p|``, ``mhd = max`` of the two
    directed means, precision = fraction of P within ``tau`` of G, recall = fraction of G within
    ``tau`` of P, f_score their harmonic mean. Options for other tools' conventions:
    ``cd_mode="mean"`` averages the two terms instead of summing; ``squared=True`` uses squared
    distances in CD/MHD; ``max_dist`` clips each distance (outlier cut-off). The precision/recall
    use unclipped, unsquared distances. Empty P or G → cd = mhd = inf (both empty → 0).
    """
    if cd_mode not in ("sum", "mean"):
        raise ValueError(f"cd_mode must be 'sum' or 'mean', got {cd_mode!r}")
    d_pg, d_gp = nn_distances(P, G, workers=workers)
    return _cloud_summary(d_pg, d_gp, tau, cd_mode, squared, max_dist)


def _cloud_summary(d_pg, d_gp, tau, cd_mode="sum", squared=False, max_dist=None) -> dict:
    prec, rec, f = _prf(d_pg, d_gp, tau)
    if d_pg.size == 0 and d_gp.size == 0:
        a = b = 0.0
    elif d_pg.size == 0 or d_gp.size == 0:
        a = b = float("inf")
    else:
        x, y = d_pg, d_gp
        if max_dist is not None:
            x, y = np.minimum(x, max_dist), np.minimum(y, max_dist)
        if squared:
            x, y = x * x, y * y
        a, b = float(x.mean()), float(y.mean())
    cd = a + b if cd_mode == "sum" else 0.5 * (a + b)
    return {"cd": cd, "mhd": max(a, b), "precision": prec, "recall": rec, "f_score": f,
            "tau": float(tau), "n_pred": int(d_pg.size), "n_gt": int(d_gp.size)}


def prf_curve(P, G, taus: Sequence[float] = DEFAULT_TAUS_M, workers: int = -1) -> dict:
    """Precision / recall / F-score over thresholds ``taus`` (metres), one KD-tree pass.

    Returns dict tau, precision, recall, f_score: lists of len(taus).
    """
    d_pg, d_gp = nn_distances(P, G, workers=workers)
    return prf_curve_from_distances(d_pg, d_gp, taus)


def prf_curve_from_distances(d_pg, d_gp, taus: Sequence[float] = DEFAULT_TAUS_M) -> dict:
    rows = [_prf(np.asarray(d_pg), np.asarray(d_gp), t) for t in taus]
    return {"tau": [float(t) for t in taus], "precision": [r[0] for r in rows],
            "recall": [r[1] for r in rows], "f_score": [r[2] for r in rows]}


def mean_cloud_metrics(rows: Iterable[Mapping]) -> dict:
    """Average per-frame point-cloud metric dicts (finite values only); n_frames counts the rows."""
    rows = list(rows)
    out: dict = {"n_frames": len(rows)}
    for key in ("cd", "mhd", "precision", "recall", "f_score"):
        v = np.array([r[key] for r in rows], dtype=np.float64)
        v = v[np.isfinite(v)]
        out[key] = float(v.mean()) if v.size else float("nan")
    return out


# ---------------------------------------------------------------------------------------------
# humans
def single_linkage(points: np.ndarray, radius: float) -> tuple[int, np.ndarray]:
    """Single-linkage clusters of points (N,3): two points closer than ``radius`` m are in one cluster.
    Returns (number of clusters K, (N,) cluster index per point)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    n = len(points)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    k, lab = connected_components(adj, directed=False)
    return int(k), lab


def human_centroids(points, radius: float = HUMAN_CLUSTER_M, min_points: int = HUMAN_MIN_POINTS) -> np.ndarray:
    """Cluster human points (N,3) (:func:`single_linkage`, ``radius`` metres) → (K,3) centroids of the
    clusters with at least ``min_points`` points."""
    X = _as_points(points)
    if len(X) < max(min_points, 1):
        return np.zeros((0, 3))
    k, lab = single_linkage(X, radius)
    counts = np.bincount(lab, minlength=k)
    keep = np.flatnonzero(counts >= min_points)
    sums = np.zeros((k, 3))
    np.add.at(sums, lab, X)
    return sums[keep] / counts[keep, None]


def strongest_clusters(points, weights, k: int, min_sum: float, radius: float = HUMAN_CLUSTER_M,
                       min_points: int = HUMAN_MIN_POINTS) -> np.ndarray:
    """(<= k, 3) centres (means) of the ``k`` clusters of ``points`` (N,3) (:func:`single_linkage`,
    ``radius`` m; at least ``min_points`` points) with the largest summed ``weights`` (N,), strongest
    first (ties: the cluster met first), each kept only when its sum reaches ``min_sum``: the person
    (or persons) a per-point score singles out. Points with a non-finite coordinate are left out."""
    X = np.asarray(points, np.float64).reshape(-1, 3)
    w = np.asarray(weights, np.float64).reshape(-1)
    ok = np.isfinite(X).all(1)
    X, w = X[ok], w[ok]
    if len(X) < max(min_points, 1):
        return np.zeros((0, 3))
    n, lab = single_linkage(X, radius)
    size = np.bincount(lab, minlength=n)
    score = np.where(size >= min_points, np.bincount(lab, weights=w, minlength=n), -np.inf)
    best = [c for c in np.argsort(-score, kind="stable")[:k] if score[c] >= min_sum]
    return np.array([X[lab == c].mean(0) for c in best]).reshape(-1, 3)


def match_centres(pred, gt, max_dist: float = HUMAN_MATCH_M) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one matching (Hungarian, Euclidean) of predicted centroids (K,3) to GT centres (L,3);
    pairs farther than ``max_dist`` are not matches. Returns (pred_idx, gt_idx, distances)."""
    pred, gt = _as_points(pred), _as_points(gt)
    if len(pred) == 0 or len(gt) == 0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0)
    D = np.linalg.norm(pred[:, None, :] - gt[None, :, :], axis=-1)
    r, c = linear_sum_assignment(np.where(max_dist >= D, D, 1e6))
    ok = D[r, c] <= max_dist
    return r[ok], c[ok], D[r[ok], c[ok]]


def human_detection_metrics(pred_centroids: Sequence, gt_centres: Sequence, max_dist: float = HUMAN_MATCH_M) -> dict:
    """Detection over frames: ``pred_centroids[t]`` (K_t,3), ``gt_centres[t]`` (L_t,3) metres (NaN
    rows = absent). Returns precision, recall, f_score, loc_mean_cm, loc_median_cm, tp, n_pred, n_gt.
    No GT centres at all → recall and F are NaN (undefined), precision 0 if anything was claimed
    else NaN; so a split without humans never reports a perfect detector."""
    if len(pred_centroids) != len(gt_centres):
        raise ValueError("pred_centroids and gt_centres need one entry per frame")
    tp, n_pred, n_gt, dists = 0, 0, 0, []
    for p, g in zip(pred_centroids, gt_centres):
        p, g = _as_points(np.reshape(p, (-1, 3))), _as_points(np.reshape(g, (-1, 3)))
        _, _, d = match_centres(p, g, max_dist)
        tp += len(d)
        n_pred += len(p)
        n_gt += len(g)
        dists.append(d)
    d = np.concatenate(dists) if dists else np.zeros(0)
    nan = float("nan")
    prec = tp / n_pred if n_pred else (nan if n_gt == 0 else 0.0)
    rec = tp / n_gt if n_gt else nan
    f = nan if not (np.isfinite(prec) and np.isfinite(rec)) else (0.0 if prec + rec == 0 else 2 * prec * rec / (prec + rec))
    return {"precision": float(prec), "recall": float(rec), "f_score": float(f),
            "loc_mean_cm": float(d.mean() * 100) if d.size else float("nan"),
            "loc_median_cm": float(np.median(d) * 100) if d.size else float("nan"),
            "tp": int(tp), "n_pred": int(n_pred), "n_gt": int(n_gt), "match_m": float(max_dist)}


# ---------------------------------------------------------------------------------------------
# breakdowns
WIDTH_BANDS = ("narrow", "medium", "wide")
ATTENUATION_BANDS = ("low", "medium", "high")


def width_band(width_m: float | None) -> str | None:
    """narrow < 1.5 m ≤ medium ≤ 3 m < wide; None when unknown."""
    if width_m is None or not np.isfinite(width_m):
        return None
    return "narrow" if width_m < 1.5 else ("medium" if width_m <= 3.0 else "wide")


def attenuation_band(drop_db: float | None) -> str | None:
    """LOS-to-NLOS power drop: low < 10 dB ≤ medium ≤ 20 dB < high; None when unknown."""
    if drop_db is None or not np.isfinite(drop_db):
        return None
    return "low" if drop_db < 10 else ("medium" if drop_db <= 20 else "high")


def scene_attenuation_db(attrs: Mapping) -> float | None:
    """The scene's LOS-to-NLOS power drop (dB) from its attributes, if recorded."""
    for src in (attrs, attrs.get("stats") or {}):
        for key in ("attenuation_db", "los_nlos_human_drop_db", "los_nlos_drop_db"):
            v = src.get(key) if isinstance(src, Mapping) else None
            if v is not None:
                try:
                    return float(v)
                except (TypeError, ValueError):
                    pass
    return None


def estimate_attenuation_db(heatmap, gt_range, gt_label, dr: float) -> float | None:
    """LOS-to-NLOS power drop (dB) measured on the heatmap, as the paper does: mean power at the
    range bins of LOS bounce-1 returns vs at the NLOS human returns (falls back to all NLOS returns).

    heatmap (T,N_r,H,W) linear amplitude; gt_range (T,B,H,W) m; gt_label (T,B,H,W) uint8.
    """
    hm = np.asarray(heatmap, dtype=np.float64)
    R = np.asarray(gt_range, dtype=np.float64)
    L = np.asarray(gt_label)
    n = hm.shape[1]

    def power(mask, r):
        t, b, i, j = np.nonzero(mask)
        k = np.clip(np.floor(r[t, b, i, j] / dr).astype(int), 0, n - 1)
        return float(np.mean(hm[t, k, i, j] ** 2)) if len(k) else None

    los = power((L == 1) & np.isfinite(R) & (np.arange(R.shape[1])[None, :, None, None] == 0), R)
    nlos = power((L == 4) & np.isfinite(R), R) or power((L == 2) & np.isfinite(R), R)
    if not los or not nlos:
        return None
    return float(10 * np.log10(los / nlos))


def scene_bands(attrs: Mapping, attenuation_db: float | None = None) -> dict:
    """{"shape": corner type, "width": band, "attenuation": band} of one scene (None = unknown)."""
    att = attenuation_db if attenuation_db is not None else scene_attenuation_db(attrs)
    w = attrs.get("width_m")
    return {"shape": attrs.get("corner_type"), "width": width_band(None if w is None else float(w)),
            "attenuation": attenuation_band(att)}


def breakdown(per_scene: Sequence[Mapping], keys: Sequence[str] = ("cd", "mhd", "f_score")) -> dict:
    """Group per-scene results by band. ``per_scene`` rows: {"bands": scene_bands(...), "n_frames": n,
    key: value, ...}. Returns {group: {band: {key: frame-weighted mean, "n_scenes", "n_frames"}}}."""
    out: dict = {"shape": {}, "width": {}, "attenuation": {}}
    for group in out:
        buckets: dict = {}
        for row in per_scene:
            band = (row.get("bands") or {}).get(group)
            if band is not None:
                buckets.setdefault(str(band), []).append(row)
        for band, rows in sorted(buckets.items()):
            wts = np.array([max(int(r.get("n_frames", 1)), 1) for r in rows], float)
            cell: dict[str, float] = {"n_scenes": len(rows), "n_frames": int(wts.sum())}
            for k in keys:
                v = np.array([r.get(k, np.nan) for r in rows], float)
                ok = np.isfinite(v)
                cell[k] = float(np.average(v[ok], weights=wts[ok])) if ok.any() else float("nan")
            out[group][band] = cell
    return out
