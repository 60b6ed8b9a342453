"""Unit quaternions for pose files and pose interpolation: matrix ↔ quaternion and spherical linear
interpolation (SLERP, Shoemake 1985, "Animating rotation with quaternion curves", SIGGRAPH).

Quaternions are ``(x, y, z, w)`` (the TUM and ROS order; scipy's ``as_quat`` too), rotation matrices
``(..., 3, 3)`` float64. Plain numpy, no I/O: the trajectory module and every stage that reads poses
import it, and scipy's ``scipy.spatial.transform`` costs a process ~0.17 s of imports (``scipy.spatial``
and ``scipy.sparse``), a tenth of the whole start-up of ``holodata raytrace-gt``
(benchmarks/results/raytrace.md).
"""
from __future__ import annotations

import numpy as np


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices → (..., 4) unit quaternions (x, y, z, w). Shepperd's method
    (1978): the largest of 1 + trace and 1 + 2 R_ii − trace sets the component computed from the
    diagonal, so no division loses precision; the same choice as scipy's ``from_matrix`` (so the sign
    of each quaternion is too). A matrix a little off orthogonal (float rounding) gives the quaternion
    of its nearest rotation to first order."""
    R = np.asarray(R, np.float64)
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    decision = np.concatenate([np.diagonal(m, axis1=1, axis2=2), tr[:, None]], axis=1)
    choice = np.argmax(decision, axis=1)
    q = np.empty((len(m), 4))
    w = choice == 3
    q[w, 0] = m[w, 2, 1] - m[w, 1, 2]
    q[w, 1] = m[w, 0, 2] - m[w, 2, 0]
    q[w, 2] = m[w, 1, 0] - m[w, 0, 1]
    q[w, 3] = 1 + tr[w]
    for i in range(3):
        s = choice == i
        j, k = (i + 1) % 3, (i + 2) % 3
        q[s, i] = 1 - tr[s] + 2 * m[s, i, i]
        q[s, j] = m[s, j, i] + m[s, i, j]
        q[s, k] = m[s, k, i] + m[s, i, k]
        q[s, 3] = m[s, k, j] - m[s, j, k]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(R.shape[:-2] + (4,))


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w; normalised here) → (..., 3, 3) rotation matrices."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of (..., 4) quaternions (x, y, z, w): the rotation b, then a."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def slerp(times: np.ndarray, quats: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rotations at ``t`` (M,) interpolated between keyframes ``quats`` (N, 4) at strictly increasing
    ``times`` (N,), N ≥ 2; ``t`` inside [times[0], times[-1]]. On each interval the rotation turns
    at a constant rate about one axis along the shorter way from one keyframe to the next:
    ``q_i ⊗ exp(α · log(q_i⁻¹ ⊗ q_{i+1}))``, α the fraction of the interval (as scipy's ``Slerp``).
    Returns (M, 4) unit quaternions (x, y, z, w)."""
    times = np.asarray(times, np.float64)
    q = np.asarray(quats, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    t = np.asarray(t, np.float64)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    alpha = (t - times[i]) / (times[i + 1] - times[i])
    rel = quat_multiply(q[i] * [-1, -1, -1, 1], q[i + 1])           # q_i⁻¹ ⊗ q_{i+1}
    rel *= np.where(rel[:, 3:] < 0, -1.0, 1.0)                       # the shorter way (w ≥ 0)
    s = np.linalg.norm(rel[:, :3], axis=1)
    half = np.arctan2(s, rel[:, 3]) * alpha                          # half the angle turned by t
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(s > 1e-12, np.sin(half) / s, alpha)          # (small angles: sin(αθ/2)/sin(θ/2) → α)
    step = np.concatenate([rel[:, :3] * scale[:, None], np.cos(half)[:, None]], axis=1)
    out = quat_multiply(q[i], step)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


__all__ = ["quat_from_matrix", "matrix_from_quat", "quat_multiply", "slerp"]
