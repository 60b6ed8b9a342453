"""The tracer's per-bounce array work (:meth:`holodata.raytrace.RayScene.trace_soa`), compiled with numba.

Each kernel is one pass over the rays doing what ~10-40 numpy array operations did (their cost:
docs/design/raytrace.md, "Compiled per-bounce pass"), with the same float32 operations in the same
order, so the results are identical to the bit to the numpy reference path (``RayScene.compiled =
False``; tests/raytrace/test_raytrace.py compares both on random scenes and rays):

- no ``fastmath`` (no reassociation, no fused multiply-add: LLVM contracts only under fastmath),
  ``error_model="numpy"`` (x/0 gives inf/NaN as in numpy instead of raising);
- every constant enters as a float32 scalar, as numpy 2 treats Python floats next to float32 arrays
  (NEP 50), and sums keep numpy's left-to-right order ``(a + b) + c``.

Arrays in, arrays out: no I/O. numba compiles on first use and caches the machine code next to
this file (``cache=True``), as :mod:`holodata.radar._motion_kernel` does.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def make_rays(S, off, first, R):  # pragma: no cover - compiled
    """Rays (n,6) float32 into ``R`` from the state ``S`` (12,n): origin rows 0-2 (moved ``off``
    along the direction unless ``first``), direction rows 3-5."""
    n = S.shape[1]
    for i in range(n):
        dx, dy, dz = S[3, i], S[4, i], S[5, i]
        if first:
            R[i, 0], R[i, 1], R[i, 2] = S[0, i], S[1, i], S[2, i]
        else:
            R[i, 0] = S[0, i] + off * dx
            R[i, 1] = S[1, i] + off * dy
            R[i, 2] = S[2, i] + off * dz
        R[i, 3], R[i, 4], R[i, 5] = dx, dy, dz


@numba.njit(cache=True, nogil=True, error_model="numpy")
def meets_box(R, tmax, box):  # pragma: no cover - compiled
    """:func:`holodata.raytrace.trace._meets_box` on rays ``R`` (n,6) float32 (origin, direction);
    ``tmax`` (n,) or (1,) float32. Returns the int64 indices of the rays kept."""
    n = R.shape[0]
    out = np.empty(n, np.int64)
    m = 0
    one = np.float32(1)
    for i in range(n):
        enter = np.float32(-np.inf)
        leave = np.float32(np.inf)
        for k in range(3):
            inv = one / R[i, 3 + k]
            a = (box[0, k] - R[i, k]) * inv
            b = (box[1, k] - R[i, k]) * inv
            # np.fmin / np.fmax: a NaN operand is ignored (both NaN: NaN)
            lo = b if np.isnan(a) else (a if np.isnan(b) else min(a, b))
            hi = b if np.isnan(a) else (a if np.isnan(b) else max(a, b))
            if k == 0:
                enter, leave = lo, hi
            else:
                enter = lo if np.isnan(enter) else (enter if np.isnan(lo) else max(enter, lo))
                leave = hi if np.isnan(leave) else (leave if np.isnan(hi) else min(leave, hi))
        tm = tmax[i] if tmax.shape[0] > 1 else tmax[0]
        if enter <= leave and leave >= 0 and enter <= tm:
            out[m] = i
            m += 1
    return out[:m]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def refine(S, t, f, isd, st_n32, st_c32, dy_n32, dy_c32, off, first, hit, tout):  # pragma: no cover - compiled
    """Normals (S rows 6-8, unoriented), n.d (row 10) and the hit distance refined against the hit
    triangle's plane (``tout``), ``hit`` = finite t. Returns the number of spurious (grazing
    self-) hits closer than off/2 (only when not ``first``), which the caller recasts."""
    n = S.shape[1]
    thr = np.float32(1e-3)
    half = off * np.float32(0.5)
    nspur = 0
    for i in range(n):
        ti = t[i]
        h = np.isfinite(ti)
        hit[i] = h
        if isd[i]:
            fi = f[i]
            nx, ny, nz, c = dy_n32[0, fi], dy_n32[1, fi], dy_n32[2, fi], dy_c32[fi]
        else:
            fz = f[i] if h else 0
            nx, ny, nz, c = st_n32[0, fz], st_n32[1, fz], st_n32[2, fz], st_c32[fz]
        S[6, i], S[7, i], S[8, i] = nx, ny, nz
        nd = nx * S[3, i] + ny * S[4, i] + nz * S[5, i]
        S[10, i] = nd
        no = nx * S[0, i] + ny * S[1, i] + nz * S[2, i]
        if not first:
            ti = ti + off
        tref = (c - no) / nd
        if abs(tref - ti) < thr:
            ti = tref
        tout[i] = ti
        if not first and h and ti < half:
            nspur += 1
    return nspur


@numba.njit(cache=True, nogil=True, error_model="numpy")
def advance(S, t, hit, f, isd, max_range, idx, b, rng, point, normal, face, hdyn):  # pragma: no cover - compiled
    """One bounce's bookkeeping: accumulate the distance, keep the rays that hit within
    ``max_range``, write their range, point, oriented normal, face and hit_dynamic into row ``b`` of
    the (B,N) / (B,N,3) outputs at ``idx``, reflect their directions and move their origins to the
    hit points. Returns (new state (12,m), new idx (m,), points (3,m))."""
    n = S.shape[1]
    m = 0
    keep = np.empty(n, np.int64)
    for i in range(n):
        acc = S[11, i] + t[i]
        S[9, i] = t[i]
        S[11, i] = acc
        if hit[i] and acc <= max_range:
            keep[m] = i
            m += 1
    S2 = np.empty((12, m), np.float32)
    idx2 = np.empty(m, np.int64)
    P = np.empty((3, m), np.float32)
    m1 = np.float32(-1)
    p1 = np.float32(1)
    two = np.float32(2)
    for j in range(m):
        i = keep[j]
        g = idx[i]
        idx2[j] = g
        ti = S[9, i]
        nd = S[10, i]
        sgn = m1 if nd > 0 else p1
        dx, dy, dz = S[3, i], S[4, i], S[5, i]
        px = S[0, i] + ti * dx
        py = S[1, i] + ti * dy
        pz = S[2, i] + ti * dz
        nx, ny, nz = S[6, i] * sgn, S[7, i] * sgn, S[8, i] * sgn
        rng[b, g] = S[11, i]
        point[b, g, 0], point[b, g, 1], point[b, g, 2] = px, py, pz
        normal[b, g, 0], normal[b, g, 1], normal[b, g, 2] = nx, ny, nz
        face[b, g] = f[i]
        hdyn[b, g] = isd[i]
        P[0, j], P[1, j], P[2, j] = px, py, pz
        k = two * abs(nd)
        dx = dx + k * nx
        dy = dy + k * ny
        dz = dz + k * nz
        L = np.sqrt(dx * dx + dy * dy + dz * dz)
        S2[0, j], S2[1, j], S2[2, j] = px, py, pz
        S2[3, j], S2[4, j], S2[5, j] = dx / L, dy / L, dz / L
        S2[11, j] = S[11, i]  # rows 6-10 are rewritten (refine, the next advance) before they are read
    return S2, idx2, P


@numba.njit(cache=True, nogil=True, error_model="numpy")
def los_rays(O, idx, P, tol, R):  # pragma: no cover - compiled
    """LOS segments into ``R`` (n,6) float32 from origins ``O[:, idx]`` ((3,N) float32, ``idx`` (n,)
    int64) and points ``P`` (3,n) float32: origin, and ``P - O`` scaled to its length minus ``tol`` (0
    when the length <= ``tol``). Returns ``near`` (n,) bool (length <= ``tol``)."""
    n = P.shape[1]
    near = np.empty(n, np.bool_)
    zero = np.float32(0)
    for i in range(n):
        k = idx[i]
        ox, oy, oz = O[0, k], O[1, k], O[2, k]
        vx = P[0, i] - ox
        vy = P[1, i] - oy
        vz = P[2, i] - oz
        L = np.sqrt(vx * vx + vy * vy + vz * vz)
        nr = tol >= L
        near[i] = nr
        s = zero if nr else (L - tol) / L
        R[i, 0], R[i, 1], R[i, 2] = ox, oy, oz
        R[i, 3], R[i, 4], R[i, 5] = vx * s, vy * s, vz * s
    return near


@numba.njit(cache=True, nogil=True, error_model="numpy")
def labels(face, hdyn, los, face_semantic, human_class, semantic, label):  # pragma: no cover - compiled
    """semantic and label (conventions.Label, :func:`holodata.raytrace.labels.combine_label`) of
    (B,N) faces (-1 none), hit_dynamic and LOS flags."""
    B, N = face.shape
    for b in range(B):
        for i in range(N):
            f = face[b, i]
            if f < 0:
                semantic[b, i] = 0
                label[b, i] = 0
            elif hdyn[b, i]:
                semantic[b, i] = human_class
                label[b, i] = 3 if los[b, i] else 4
            else:
                semantic[b, i] = face_semantic[f]
                label[b, i] = 1 if los[b, i] else 2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def merge_hits(ts, fs, sub, td, fd):  # pragma: no cover - compiled
    """Nearest of the static hits ``ts``, ``fs`` (n,) and the dynamic hits ``td``, ``fd`` of the rays
    ``sub`` (m,): t (n,) float32, face (n,) int64, is_dyn (n,) bool — ``np.minimum`` / ``np.where``
    of RayScene._cast6 (the dynamic mesh wins only when strictly closer)."""
    n = ts.shape[0]
    t = ts.copy()
    f = np.empty(n, np.int64)
    isd = np.zeros(n, np.bool_)
    for i in range(n):
        f[i] = fs[i]
    for j in range(sub.shape[0]):
        i = sub[j]
        if td[j] < ts[i]:
            t[i] = td[j]
            f[i] = fd[j]
            isd[i] = True
    return t, f, isd


@numba.njit(cache=True, nogil=True)
def to_half(x, out):  # pragma: no cover - compiled
    """``x`` (n,) float32 rounded to IEEE binary16 bit patterns into ``out`` (n,) uint16 (a float16
    array's ``.view(np.uint16)``): ``x.astype(np.float16)`` to the bit — round to nearest, ties to
    even; overflow to inf; subnormal halves; a NaN keeps its top payload bits — in one pass
    (cheaper than numpy's cast of a frame's normals). Checked against numpy on every
    float32 bit pattern (cost and check: docs/design/raytrace.md) and on a sample in tests/raytrace/test_kernels.py."""
    u = x.view(np.uint32)
    for i in range(u.shape[0]):
        b = np.int64(u[i])
        sgn = (b >> 16) & 0x8000
        e = (b >> 23) & 0xFF
        m = b & 0x7FFFFF
        if e == 0xFF:
            h = 0x7C00 if m == 0 else max(0x7C00 + (m >> 13), 0x7C01)  # numpy keeps a NaN a NaN, quiet or not
        elif e > 127 + 15:
            h = 0x7C00
        elif e >= 127 - 14:  # a normal half; a carry out of the significand rounds up the exponent
            h = ((e - 127 + 15) << 10) | (m >> 13)
            rem = m & 0x1FFF
            if rem > 0x1000 or (rem == 0x1000 and (h & 1)):
                h += 1
        else:  # a subnormal half (or zero): units of 2**-24
            shift = 126 - e
            if shift > 24:
                h = 0
            else:
                M = m | 0x800000
                h = M >> shift
                rem = M & ((1 << shift) - 1)
                half = 1 << (shift - 1)
                if rem > half or (rem == half and (h & 1)):
                    h += 1
        out[i] = sgn | h


@numba.njit(cache=True, nogil=True, error_model="numpy")
def column_dirs(R, dirs, out):  # pragma: no cover - compiled
    """Per-column beam directions into ``out`` (3,H,W) float32: ``R`` (W,3,3) float64 column
    rotations, ``dirs`` (H,W,3) float64 radar-frame directions; the float64 sum
    ``(R_i0 d_0 + R_i2 d_2) + R_i1 d_1`` of :func:`holodata.raytrace.frames.column_rays_soa`, rounded
    to float32 once."""
    H, W = dirs.shape[0], dirs.shape[1]
    for i in range(3):
        for h in range(H):
            for w in range(W):
                out[i, h, w] = np.float32((R[w, i, 0] * dirs[h, w, 0] + R[w, i, 2] * dirs[h, w, 2])
                                          + R[w, i, 1] * dirs[h, w, 1])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def face_normals(v, f, out):  # pragma: no cover - compiled
    """Unit geometric normals into ``out`` (F,3) float64 of faces ``f`` (F,3) int64 (in range) over
    vertices ``v`` (V,3) float64: :func:`holodata.raytrace.labels.face_normals`'s ``np.cross`` of the
    edges, divided by ``np.linalg.norm`` (``(x² + y²) + z²``, numpy's order for this reduction), zero
    for degenerate faces — to the bit."""
    for j in range(f.shape[0]):
        a, b, c = f[j, 0], f[j, 1], f[j, 2]
        e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        L = np.sqrt((nx * nx + ny * ny) + nz * nz)
        if L > 0:
            out[j, 0], out[j, 1], out[j, 2] = nx / L, ny / L, nz / L
        else:
            out[j, 0], out[j, 1], out[j, 2] = 0.0, 0.0, 0.0
