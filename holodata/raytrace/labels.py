"""Semantic classes per face: from the mesh's per-face class, or geometric (floor, ceiling, wall,
other) from the face normal and height. Id 0 means "no return"."""
from __future__ import annotations

import numpy as np

NONE_CLASS = 0
FLOOR, CEILING, WALL, OTHER, HUMAN = 1, 2, 3, 4, 5
GEOMETRIC_CLASS_NAMES = {0: "none", 1: "floor", 2: "ceiling", 3: "wall", 4: "other", 5: "human"}

HORIZONTAL_MIN_NZ = 0.866  # |n_z| >= cos 30 deg: floor or ceiling candidate
VERTICAL_MAX_NZ = 0.342    # |n_z| <= sin 20 deg: wall
HEIGHT_BAND_M = 0.3        # horizontal faces within this of the lowest/highest vertex


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,3) float64 unit geometric normals (right-hand winding); zero for degenerate faces. In one
    compiled pass (:func:`holodata.raytrace._kernels.face_normals`, identical to the bit to the numpy
    below and cheaper: docs/design/performance.md) when the face indices are in range."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if f.ndim == 2 and f.shape[1] == 3 and v.ndim == 2 and v.shape[1] == 3 and np.issubdtype(f.dtype, np.integer) \
            and (len(f) == 0 or (f.min() >= 0 and f.max() < len(v))):
        from . import _kernels

        out = np.empty((len(f), 3))
        _kernels.face_normals(v, np.ascontiguousarray(f, dtype=np.int64), out)
        return out
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def geometric_classes(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """(F,) uint8 geometric class per face: floor / ceiling for near-horizontal faces within
    HEIGHT_BAND_M of the mesh's lowest / highest vertex, wall for near-vertical faces, else other."""
    v = np.asarray(vertices, dtype=np.float64)
    n = face_normals(v, faces) if normals is None else normals
    zc = v[np.asarray(faces)].mean(axis=1)[:, 2]
    zmin, zmax = v[:, 2].min(), v[:, 2].max()
    anz = np.abs(n[:, 2])
    out = np.full(len(n), OTHER, dtype=np.uint8)
    horiz = anz >= HORIZONTAL_MIN_NZ
    out[anz <= VERTICAL_MAX_NZ] = WALL
    out[horiz & (zc <= zmin + HEIGHT_BAND_M)] = FLOOR
    out[horiz & (zc >= zmax - HEIGHT_BAND_M) & (zc > zmin + HEIGHT_BAND_M)] = CEILING
    return out


def class_table(face_class: np.ndarray | None, class_names: dict | None) -> tuple[dict, int]:
    """Class table {id: name} used for ``semantic`` and the id given to human (dynamic) hits."""
    if face_class is None:
        return dict(GEOMETRIC_CLASS_NAMES), HUMAN
    names = {int(k): str(v) for k, v in (class_names or {}).items()}
    for k in np.unique(face_class):
        names.setdefault(int(k), f"class_{int(k)}")
    names[NONE_CLASS] = names.get(NONE_CLASS, "none")
    human = next((k for k, v in names.items() if v.lower() in ("human", "person")), None)
    if human is None:
        human = max(names) + 1 if max(names) < 255 else 255
        names[human] = "human"
    return dict(sorted(names.items())), human


def combine_label(hit: np.ndarray, human: np.ndarray, los: np.ndarray) -> np.ndarray:
    """uint8 label (conventions.Label): 0 none, 1 LOS structure, 2 NLOS structure, 3 LOS human, 4 NLOS human."""
    lab = np.where(human, 3, 1) + np.where(los, 0, 1)
    return np.where(hit, lab, 0).astype(np.uint8)
