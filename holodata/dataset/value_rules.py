"""Value rules of ``holodata validate`` (docs/format.md §2/§3): what a decoded shard of a frame array
must hold, checked on every shard :mod:`holodata.dataset.validate` reads once.

- gt/range: finite >= 0 or NaN (NaN: no return on that beam); R1 < R2 < R3 where finite, and no return
  after a missing one (bounces are ordered along the ray).
- gt/label: in 0..4 (:class:`holodata.conventions.Label`), and 0 exactly where gt/range is NaN (a label
  names the surface a range hit: one without the other is a tracing or writing bug).
- gt/normal: unit length (±1e-3; ±2e-3 when stored as float16) where gt/range is finite.
- time/timestamp_ns: int64, strictly increasing across the scene (frames are ordered in time).
- pose/*: rigid (orthonormal rotation, last row 0 0 0 1) and NaN-free.
- radar/heatmap: finite >= 0 (stored as linear amplitude); :func:`frames_not_finite_nonneg` is also
  what ingest uses to drop damaged radar messages before they reach a dataset.

gt/label and gt/normal are checked against the same frames of gt/range: from the shard walk when it
decoded them (``decoded``), else read through zarr. Problems go to the caller's report (``rep.add``).
"""
from __future__ import annotations

import numpy as np

from ..conventions import Label, is_rigid
from .layout import GT_LABEL, GT_NORMAL, GT_RANGE, POSE_PREFIX, RADAR_HEATMAP, TIME_TIMESTAMP_NS


def _frames_where(bad: np.ndarray) -> np.ndarray:
    """Indices (within the shard) of frames with any True in ``bad`` (frame axis first)."""
    return np.flatnonzero(bad.reshape(bad.shape[0], -1).any(axis=1))


def _report_frames(rep, sid, name, fr, bad, rule, msg_fn) -> None:
    for i in _frames_where(bad):
        rep.add(sid, name, fr.start + i, rule, msg_fn(i))


def _aligned(ds, sid, name, fr, decoded) -> np.ndarray | None:
    """``name`` over frames ``fr`` (from this shard walk, else read via zarr)."""
    if name in decoded:
        return decoded[name]
    try:
        return np.asarray(ds.scene(sid)[name][fr])
    except Exception:  # noqa: BLE001 - its own problems are reported when it is walked
        return None


_EXP_BITS = {2: (np.uint16, 0x7C00), 4: (np.uint32, 0x7F800000), 8: (np.uint64, 0x7FF0000000000000)}


def frames_not_finite_nonneg(a: np.ndarray) -> np.ndarray:
    """Frame indices where a float array holds NaN, inf or negative values. Fast path: as unsigned
    bits, a positive finite float is below the exponent mask, so one integer max per frame decides
    (float16 min/max in numpy is slow); flagged frames are re-checked exactly (-0.0 is fine)."""
    n = a.shape[0]
    ut, exp = _EXP_BITS[a.dtype.itemsize]
    cand = np.flatnonzero(a.view(ut).reshape(n, -1).max(axis=1) >= exp)
    out = []
    for i in cand:
        f = a[i]
        with np.errstate(invalid="ignore"):
            if not (np.isfinite(f).all() and (f >= 0).all()):
                out.append(i)
    return np.asarray(out, dtype=np.int64)


def _value_rules(ds, sid, name, a, fr, decoded, rep, state) -> None:
    n = a.shape[0] if a.ndim else 0
    if name == GT_RANGE:
        if a.dtype.kind != "f":
            return
        a2 = a.reshape(n, -1)
        with np.errstate(invalid="ignore"):
            badf = (np.fmin.reduce(a2, axis=1) < 0) | (np.fmax.reduce(a2, axis=1) == np.inf)
        for i in np.flatnonzero(badf):
            with np.errstate(invalid="ignore"):
                cnt = int(((a[i] < 0) | np.isinf(a[i])).sum())
            rep.add(sid, name, fr.start + i, "range", f"{cnt} ranges not finite >= 0 or NaN "
                                                      f"(min {np.nanmin(a[i]):.3g})")
        nan = np.isnan(a)
        decoded["gt/range:nan"] = nan
        if a.ndim == 4 and a.shape[1] > 1:
            with np.errstate(invalid="ignore"):
                order = ~(a[:, 1:] > a[:, :-1])
            order &= ~nan[:, 1:]
            if order.any():
                _report_frames(rep, sid, name, fr, order, "bounce_order",
                               lambda i: f"{int(order[i].sum())} beams break R1 < R2 < R3 (a later bounce "
                                         f"not beyond the previous one, or after a missing one)")
    elif name == GT_LABEL:
        if a.dtype.kind not in "ui":
            return
        a2 = a.reshape(n, -1)
        badf = a2.max(axis=1) > max(Label)
        if a.dtype.kind == "i":
            badf |= a2.min(axis=1) < 0
        for i in np.flatnonzero(badf):
            rep.add(sid, name, fr.start + i, "label",
                    f"{int(((a[i] > max(Label)) | (a[i] < 0)).sum())} labels outside 0..4")
        nan = _range_nan(ds, sid, fr, decoded)
        if nan is not None and nan.shape == a.shape:
            mism = np.not_equal(a == 0, nan)
            if mism.any():
                _report_frames(rep, sid, name, fr, mism, "label_range",
                               lambda i: f"{int(mism[i].sum())} beams where label is 0 but range is not NaN, "
                                         f"or label is set without a range")
    elif name == GT_NORMAL:
        nan = _range_nan(ds, sid, fr, decoded)
        if a.dtype.kind != "f" or nan is None or nan.shape != a.shape[:-1]:
            return
        tol = 1e-3 if a.dtype.itemsize >= 4 else 2e-3
        n32 = a.astype(np.float32, copy=False)
        norm2 = np.einsum("...k,...k->...", n32, n32)
        with np.errstate(invalid="ignore"):
            bad = ~((norm2 >= (1 - tol) ** 2) & (norm2 <= (1 + tol) ** 2))
        bad &= ~nan
        if bad.any():
            _report_frames(rep, sid, name, fr, bad, "normal_unit",
                           lambda i: f"{int(bad[i].sum())} normals not unit length (±{tol:g}) where range is finite")
    elif name == TIME_TIMESTAMP_NS:
        if a.dtype != np.int64:
            rep.add(sid, name, fr.start, "timestamps", f"dtype {a.dtype}, expected int64")
            return
        prev = state.get(("ts", sid))
        full = a if prev is None else np.concatenate([[prev], a])
        bad = np.flatnonzero(np.diff(full) <= 0)
        off = fr.start - (0 if prev is None else 1)
        for i in bad:
            rep.add(sid, name, off + i + 1, "timestamps", f"timestamp {full[i + 1]} not after the previous {full[i]}")
        if len(a):
            state[("ts", sid)] = a[-1]
    elif name.startswith(POSE_PREFIX):
        if a.ndim != 3 or a.shape[1:] != (4, 4):
            return
        ok = is_rigid(a)
        for i in np.flatnonzero(~ok):
            what = ("has NaN/inf" if not np.isfinite(a[i]).all()
                    else "is not rigid (rotation not orthonormal or last row not 0 0 0 1)")
            rep.add(sid, name, fr.start + i, "pose", f"pose {what}")
    elif name == RADAR_HEATMAP:
        if a.dtype.kind != "f" or a.dtype.itemsize not in _EXP_BITS:
            return
        for i in frames_not_finite_nonneg(a):
            rep.add(sid, name, fr.start + i, "heatmap", "heatmap has NaN/inf or negative amplitudes "
                                                        "(stored as linear amplitude >= 0)")


def _range_nan(ds, sid, fr, decoded) -> np.ndarray | None:
    if "gt/range:nan" in decoded:
        return decoded["gt/range:nan"]
    rng = _aligned(ds, sid, GT_RANGE, fr, decoded)
    return None if rng is None else np.isnan(rng)
