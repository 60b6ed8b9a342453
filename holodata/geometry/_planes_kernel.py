"""Per-pixel iteratively reweighted plane normals of a point image, compiled with numba.

What :func:`holodata.geometry.planes.window_plane_normals` computes, pixel by pixel instead of image
by image: each pixel's window neighbours (rows ``y−rows … y+rows``, those outside the image left
out; columns ``x−cols … x+cols`` modulo the width, a full rotation), taken relative to the pixel's
own point, non-finite ones left out; then ``iterations`` times the weights
``w = exp(−½ (d/σ)²)`` of their distances ``d`` to the current plane (through ``c``, normal ``n``),
the weighted moments summed in the numpy version's order (row offset outer, column offset inner),
the covariance's eigenvector of the smallest eigenvalue (closed form, a cyclic Jacobi solver where
the two smallest eigenvalues are close: no LAPACK call and no allocation per pixel), signed like the
current normal; a pixel whose weights sum to under 4 keeps its normal (and its plane point returns
to the pixel), one whose point or normal is not finite keeps its ``n0``. Why: the numpy version
builds a dozen full-size temporaries per window offset and iteration and a batched ``eigh``, a fifth
or more of ``holodata evaluate`` at the paper's grid.
Arrays in, arrays out: no I/O. numba compiles it on first use and caches the machine code next to
this file; it releases the GIL (callers may run it in threads) and runs serially.
"""
from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def smallest_eigenvector(a, v):  # pragma: no cover - compiled
    """Eigen-decomposition of a symmetric a (3,3) by cyclic Jacobi rotations (Numerical Recipes'
    ``jacobi``, an off-diagonal entry negligible next to both its diagonal entries zeroed from the
    first sweep on): a is overwritten (its diagonal ends as the eigenvalues), v (3,3) receives the
    orthonormal eigenvectors as columns. Returns the column index of the smallest eigenvalue."""
    for i in range(3):
        for j in range(3):
            v[i, j] = 1.0 if i == j else 0.0
    for _sweep in range(64):
        if a[0, 1] == 0.0 and a[0, 2] == 0.0 and a[1, 2] == 0.0:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                g = 100.0 * abs(apq)
                app = a[p, p]
                aqq = a[q, q]
                if abs(app) + g == abs(app) and abs(aqq) + g == abs(aqq):
                    a[p, q] = 0.0      # negligible next to both diagonal entries
                    a[q, p] = 0.0
                    continue
                h = aqq - app
                if abs(h) + g == abs(h):
                    t = apq / h
                else:
                    theta = 0.5 * h / apq
                    t = 1.0 / (abs(theta) + math.sqrt(1.0 + theta * theta))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = t * c
                tau = s / (1.0 + c)
                h = t * apq
                a[p, p] = app - h
                a[q, q] = aqq + h
                a[p, q] = 0.0
                a[q, p] = 0.0
                r = 3 - p - q          # the third index
                arp = a[r, p]
                arq = a[r, q]
                a[r, p] = arp - s * (arq + tau * arp)
                a[p, r] = a[r, p]
                a[r, q] = arq + s * (arp - tau * arq)
                a[q, r] = a[r, q]
                for k in range(3):
                    vkp = v[k, p]
                    vkq = v[k, q]
                    v[k, p] = vkp - s * (vkq + tau * vkp)
                    v[k, q] = vkq + s * (vkp - tau * vkq)
    k = 0
    if a[1, 1] < a[k, k]:
        k = 1
    if a[2, 2] < a[k, k]:
        k = 2
    return k


@numba.njit(cache=True, nogil=True)
def smallest_eigenvector3(a00, a10, a11, a20, a21, a22, a, v):  # pragma: no cover - compiled
    """Unit eigenvector (x, y, z) of the smallest eigenvalue of the symmetric 3×3 matrix with lower
    triangle a00, a10, a11, a20, a21, a22: the eigenvalues in closed form (Smith's trigonometric
    solution of the characteristic cubic; the smallest is accurate to rounding unless the two
    smallest are close), the vector as the longest cross product of two rows of ``A − λ₁I``, the
    directions orthogonal to it. Where the two smallest eigenvalues are within 1 % of the matrix's
    scale (a nearly collinear window; there a closed-form λ₁'s error grows with the gap's inverse
    squared) or the eigenvalues coincide, the Jacobi solver (:func:`smallest_eigenvector`, scratch
    a and v (3,3)) decides."""
    q = (a00 + a11 + a22) / 3.0
    b00 = a00 - q
    b11 = a11 - q
    b22 = a22 - q
    p2 = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a10 * a10 + a20 * a20 + a21 * a21)) / 6.0
    if p2 > 0.0:
        p = math.sqrt(p2)
        det = b00 * (b11 * b22 - a21 * a21) - a10 * (a10 * b22 - a21 * a20) + a20 * (a10 * a21 - b11 * a20)
        r = min(max(det / (2.0 * p2 * p), -1.0), 1.0)
        phi = math.acos(r) / 3.0
        l3 = q + 2.0 * p * math.cos(phi)
        l1 = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
        l2 = 3.0 * q - l1 - l3
        if l2 - l1 > 1e-2 * (abs(q) + p):
            m00 = a00 - l1
            m11 = a11 - l1
            m22 = a22 - l1
            # rows (m00, a10, a20), (a10, m11, a21), (a20, a21, m22): their cross products
            x01 = a10 * a21 - a20 * m11
            y01 = a20 * a10 - m00 * a21
            z01 = m00 * m11 - a10 * a10
            x02 = a10 * m22 - a20 * a21
            y02 = a20 * a20 - m00 * m22
            z02 = m00 * a21 - a10 * a20
            x12 = m11 * m22 - a21 * a21
            y12 = a21 * a20 - a10 * m22
            z12 = a10 * a21 - m11 * a20
            n01 = x01 * x01 + y01 * y01 + z01 * z01
            n02 = x02 * x02 + y02 * y02 + z02 * z02
            n12 = x12 * x12 + y12 * y12 + z12 * z12
            if n01 >= n02 and n01 >= n12:
                s = 1.0 / math.sqrt(n01)
                return x01 * s, y01 * s, z01 * s
            if n02 >= n12:
                s = 1.0 / math.sqrt(n02)
                return x02 * s, y02 * s, z02 * s
            s = 1.0 / math.sqrt(n12)
            return x12 * s, y12 * s, z12 * s
    a[0, 0] = a00
    a[1, 0] = a10
    a[1, 1] = a11
    a[2, 0] = a20
    a[2, 1] = a21
    a[2, 2] = a22
    a[0, 1] = a10
    a[0, 2] = a20
    a[1, 2] = a21
    j = smallest_eigenvector(a, v)
    return v[0, j], v[1, j], v[2, j]


@numba.njit(cache=True, nogil=True)
def plane_normals(P, n0, rows, cols, sigma, iterations, out):  # pragma: no cover - compiled
    """out (N,H,W,3) = the reweighted window plane normals of the point images P (N,H,W,3) started
    from n0 (N,H,W,3) (module docstring; the numpy reference is
    :func:`holodata.geometry.planes._window_plane_normals_numpy`)."""
    N, H, W = P.shape[0], P.shape[1], P.shape[2]
    K = max(0, 2 * rows + 1) * max(0, 2 * cols + 1)
    nb = np.empty((max(K, 1), 3))       # the pixel's finite neighbours, relative to its point
    a = np.empty((3, 3))
    v = np.empty((3, 3))
    for b in range(N):
        for y in range(H):
            for x in range(W):
                nx = n0[b, y, x, 0]
                ny = n0[b, y, x, 1]
                nz = n0[b, y, x, 2]
                out[b, y, x, 0] = nx
                out[b, y, x, 1] = ny
                out[b, y, x, 2] = nz
                px = P[b, y, x, 0]
                py = P[b, y, x, 1]
                pz = P[b, y, x, 2]
                if not (np.isfinite(nx) and np.isfinite(ny) and np.isfinite(nz)
                        and np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
                    continue           # keeps n0: no neighbour counts, or never "ok"
                k = 0
                for dy in range(-rows, rows + 1):
                    yy = y + dy
                    if yy < 0 or yy >= H:
                        continue
                    for dx in range(-cols, cols + 1):
                        xx = x + dx
                        if xx < 0 or xx >= W:
                            xx %= W
                        qx = P[b, yy, xx, 0]
                        qy = P[b, yy, xx, 1]
                        qz = P[b, yy, xx, 2]
                        if np.isfinite(qx) and np.isfinite(qy) and np.isfinite(qz):
                            nb[k, 0] = qx - px
                            nb[k, 1] = qy - py
                            nb[k, 2] = qz - pz
                            k += 1
                cx = 0.0
                cy = 0.0
                cz = 0.0
                for _ in range(iterations):
                    s0 = 0.0
                    s1x = 0.0
                    s1y = 0.0
                    s1z = 0.0
                    sxx = 0.0
                    syx = 0.0
                    syy = 0.0
                    szx = 0.0
                    szy = 0.0
                    szz = 0.0
                    for i in range(k):
                        qx = nb[i, 0]
                        qy = nb[i, 1]
                        qz = nb[i, 2]
                        d = (qx - cx) * nx + (qy - cy) * ny + (qz - cz) * nz
                        t = d / sigma
                        w = math.exp(-0.5 * (t * t))
                        wx = w * qx
                        wy = w * qy
                        wz = w * qz
                        s0 += w
                        s1x += wx
                        s1y += wy
                        s1z += wz
                        sxx += wx * qx     # the lower triangle, (w q_i) q_j as numpy forms it
                        syx += wy * qx
                        syy += wy * qy
                        szx += wz * qx
                        szy += wz * qy
                        szz += wz * qz
                    if not s0 >= 4.0:
                        cx = 0.0
                        cy = 0.0
                        cz = 0.0
                        continue
                    mx = s1x / s0
                    my = s1y / s0
                    mz = s1z / s0
                    ex, ey, ez = smallest_eigenvector3(sxx / s0 - mx * mx, syx / s0 - my * mx, syy / s0 - my * my,
                                                       szx / s0 - mz * mx, szy / s0 - mz * my, szz / s0 - mz * mz,
                                                       a, v)
                    if ex * nx + ey * ny + ez * nz < 0.0:
                        ex = -ex
                        ey = -ey
                        ez = -ez
                    nx = ex
                    ny = ey
                    nz = ez
                    cx = mx
                    cy = my
                    cz = mz
                out[b, y, x, 0] = nx
                out[b, y, x, 1] = ny
                out[b, y, x, 2] = nz
