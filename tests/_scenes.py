"""Meshes shared by the ray-tracing, ground-truth and scale-out tests: an axis-aligned box, quads, and
the L corridor with a box-shaped person around its corner (not a test module)."""
from __future__ import annotations

import numpy as np

from holodata.meshio import merge_meshes


def box(lo, hi):
    """Closed axis-aligned box as 12 triangles (winding irrelevant: normals are flipped per ray)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def quad(p0, p1, p2, p3):
    return np.array([p0, p1, p2, p3], float), np.array([[0, 1, 2], [0, 2, 3]])


def merge(*meshes):
    return merge_meshes(meshes)


def l_corridor():
    """Corridor A: x in [0,10], y in [0,2]; corridor B: x in [8,10], y in [0,10]; z in [-1, 1.5]."""
    poly = np.array([[0, 0], [10, 0], [10, 10], [8, 10], [8, 2], [0, 2]], float)
    walls = [quad([*poly[i], -1], [*poly[(i + 1) % 6], -1], [*poly[(i + 1) % 6], 1.5], [*poly[i], 1.5])
             for i in range(6)]
    walls += [quad([0, 0, -1], [10, 0, -1], [10, 10, -1], [0, 10, -1]),
              quad([0, 0, 1.5], [10, 0, 1.5], [10, 10, 1.5], [0, 10, 1.5])]
    return merge(*walls)


HUMAN = box([8.2, 3.2, -1.0], [8.6, 3.6, 0.8])
