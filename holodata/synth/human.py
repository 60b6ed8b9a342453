"""A walking human: a body-shaped closed mesh (head, torso, arms, legs) and its path.

Body frame: x forward, y left, z up, feet on z = 0. Limbs are closed octagonal prisms (capsule
stand-ins), the torso a box, the head a low-poly sphere; parts overlap but each is closed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .worlds import box_mesh

STEP_LENGTH_FRACTION = 0.41  # step length / body height (typical walking)


def _prism(p0, p1, radius: float, sides: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Closed prism of ``sides`` sides around the segment p0→p1 (capped): (2*sides+2, 3), faces."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    L = np.linalg.norm(axis)
    a = axis / L
    helper = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = radius * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
    verts = np.concatenate([p0 + ring, p1 + ring, [p0, p1]])
    c0, c1 = 2 * sides, 2 * sides + 1
    faces = []
    for k in range(sides):
        k2 = (k + 1) % sides
        faces += [[k, k2, sides + k2], [k, sides + k2, sides + k]]  # outward
        faces += [[c0, k2, k], [c1, sides + k, sides + k2]]
    return verts, np.asarray(faces)


def _sphere(center, radius: float, n_lat: int = 5, n_lon: int = 8) -> tuple[np.ndarray, np.ndarray]:
    lat = np.pi * (np.arange(1, n_lat) / n_lat) - np.pi / 2
    lon = 2 * np.pi * np.arange(n_lon) / n_lon
    ring = np.array([[np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), np.sin(b)] for b in lat for a in lon])
    verts = np.concatenate([ring, [[0, 0, -1.0], [0, 0, 1.0]]]) * radius + np.asarray(center, float)
    S, N = len(ring), n_lon
    faces = []
    for i in range(n_lat - 2):
        for k in range(N):
            a, b = i * N + k, i * N + (k + 1) % N
            c, d = a + N, b + N
            faces += [[a, b, d], [a, d, c]]
    for k in range(N):
        faces.append([S, (k + 1) % N, k])
        top = (n_lat - 2) * N
        faces.append([S + 1, top + k, top + (k + 1) % N])
    return verts, np.asarray(faces)


def human_mesh(height: float = 1.75, gait_phase: float = 0.0, swing: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame human mesh: vertices (V,3) float64 m, faces (F,3) int32.

    ``gait_phase`` (rad) drives leg/arm swing; ``swing`` 0 = standing still, 1 = full walking swing.
    """
    H = float(height)
    parts = []
    leg_amp = np.deg2rad(22.0) * swing
    arm_amp = np.deg2rad(18.0) * swing
    hip_z, sh_z = 0.52 * H, 0.81 * H
    for side, sgn in ((1.0, 1.0), (-1.0, -1.0)):
        # legs: swing in the x-z plane, left and right in antiphase
        a = leg_amp * np.sin(gait_phase) * sgn
        hip = np.array([0.0, side * 0.055 * H, hip_z])
        foot = hip + 0.50 * H * np.array([np.sin(a), 0.0, -np.cos(a)])
        foot[2] = max(foot[2], 0.02 * H)
        parts.append(_prism(hip, foot, 0.042 * H))
        # arms: counter-swing
        b = -arm_amp * np.sin(gait_phase) * sgn
        sh = np.array([0.0, side * 0.135 * H, sh_z])
        hand = sh + 0.40 * H * np.array([np.sin(b), side * 0.03, -np.cos(b)])
        parts.append(_prism(sh, hand, 0.027 * H))
    parts.append(box_mesh([0.0, 0.0, (hip_z - 0.03 * H + sh_z + 0.02 * H) / 2],
                          [0.12 * H, 0.23 * H, sh_z - hip_z + 0.05 * H]))
    parts.append(_prism([0, 0, sh_z], [0, 0, 0.88 * H], 0.03 * H))  # neck
    parts.append(_sphere([0.01 * H, 0.0, 0.935 * H], 0.058 * H))
    verts, faces, n = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int32)


@dataclass
class HumanWalk:
    """A human walking back and forth between plan points ``a`` and ``b`` (2,) m at ``speed`` m/s
    (0 = standing at ``a`` with a slight sway), starting at ``t0_s`` with ``phase0`` (0..1 of a lap)."""

    a: np.ndarray
    b: np.ndarray
    speed: float
    height: float
    phase0: float = 0.0

    def state(self, t_s: float) -> tuple[np.ndarray, float, float]:
        """Plan position (2,), heading (rad) and gait phase at time ``t_s`` (seconds from start)."""
        a, b = np.asarray(self.a, float), np.asarray(self.b, float)
        L = float(np.linalg.norm(b - a))
        if self.speed <= 0 or L < 1e-6:
            sway = 0.03 * np.sin(2 * np.pi * 0.3 * t_s)
            d = (b - a) / L if L > 1e-6 else np.array([1.0, 0.0])
            pos = a + sway * np.array([-d[1], d[0]])
            return pos, float(np.arctan2(-d[1], -d[0])), 0.0
        lap = 2 * L
        s = (self.phase0 * lap + self.speed * t_s) % lap
        d = (b - a) / L
        if s <= L:
            pos, head = a + d * s, np.arctan2(d[1], d[0])
        else:
            pos, head = b - d * (s - L), np.arctan2(-d[1], -d[0])
        gait = 2 * np.pi * (self.speed * t_s) / (2 * STEP_LENGTH_FRACTION * self.height)
        return pos, float(head), float(gait)

    def mesh_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """World-frame mesh at ``t_s``: vertices (V,3) float64, faces (F,3) int32."""
        pos, head, gait = self.state(t_s)
        v, f = human_mesh(self.height, gait, swing=1.0 if self.speed > 0 else 0.0)
        c, s = np.cos(head), np.sin(head)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        return v @ R.T + np.array([pos[0], pos[1], 0.0]), f

    def center_at(self, t_s: float) -> np.ndarray:
        """(3,) world point at the torso centre (≈ 0.6 height)."""
        pos, _, _ = self.state(t_s)
        return np.array([pos[0], pos[1], 0.6 * self.height])


def footprint_points(center_xy: np.ndarray, radius: float = 0.35, n: int = 12) -> np.ndarray:
    """(n,2) points on a circle around a plan position: a conservative plan-view body outline."""
    ang = 2 * np.pi * np.arange(n) / n
    return np.asarray(center_xy, float) + radius * np.column_stack([np.cos(ang), np.sin(ang)])
