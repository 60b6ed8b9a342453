"""Human (dynamic mesh) sources of raytrace-gt: ``source(k) -> (vertices, faces) | None``, world frame.

Sources: none; one mesh for all frames (``--human``, :class:`HumanFile`); a directory with one mesh
per frame *index* ``{k:06d}.ply`` (``.obj``/``.stl`` also accepted; k = 0-based row of the TUM
file, :class:`HumanDir`); in a dataset (:class:`HumanDataset`), ragged ``human/vertices`` +
``human/faces`` (per frame, world frame) or, failing that, the registered human cloud
``human/points`` (map frame, from ``register``) turned into small octahedra (3 cm).
``camera/points`` is never used: it is in the camera frame until registered.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..dataset.layout import HUMAN_FACES, HUMAN_POINTS, HUMAN_VERTICES
from ..errors import InputError
from ..geometry.voxels import first_per_voxel
from ..meshio import read_mesh

MESH_EXTS = (".ply", ".obj", ".stl")
HUMAN_SPLAT_RADIUS_M = 0.03


def points_to_mesh(points: np.ndarray, radius: float = HUMAN_SPLAT_RADIUS_M) -> tuple[np.ndarray, np.ndarray]:
    """A surface for a human point cloud: one octahedron of ``radius`` per (voxel-thinned) point."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    pts = pts[first_per_voxel(pts, radius)]
    ov = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * radius
    of = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    v = (pts[:, None, :] + ov[None]).reshape(-1, 3)
    f = (of[None] + 6 * np.arange(len(pts))[:, None, None]).reshape(-1, 3)
    return v, f.astype(np.int32)


class HumanSource:
    """Per-frame human mesh (world frame) or None: ``source(k) -> (vertices, faces) | None``."""

    kind = "none"

    def __call__(self, k: int):
        return None

    def describe(self) -> dict:
        return {"kind": self.kind}


class HumanFile(HumanSource):
    kind = "file"

    def __init__(self, path: str | Path):
        self.path = Path(path)
        m = read_mesh(self.path)
        self.mesh = (m.vertices, m.faces)

    def __call__(self, k: int):
        return self.mesh

    def describe(self) -> dict:
        return {"kind": self.kind, "path": str(self.path), "sha256": file_sha256(self.path)}


class HumanDir(HumanSource):
    """``DIR/{k:06d}.(ply|obj|stl)`` for every frame index k (checked up front)."""

    kind = "dir"

    def __init__(self, path: str | Path, n_frames: int):
        self.path = Path(path)
        if not self.path.is_dir():
            raise InputError(f"{self.path}: human directory does not exist")
        present = {p.stem: p for p in self.path.iterdir() if p.suffix.lower() in MESH_EXTS}
        self.files = []
        for k in range(n_frames):
            p = present.get(f"{k:06d}")
            if p is None:
                raise InputError(f"{self.path / f'{k:06d}.ply'}: human mesh for frame {k} is missing "
                                 f"(--human-dir needs one mesh per frame index, {n_frames} frames)")
            self.files.append(p)

    def __call__(self, k: int):
        m = read_mesh(self.files[k])
        return (m.vertices, m.faces)

    def describe(self) -> dict:
        return {"kind": self.kind, "path": str(self.path), "naming": "{frame_index:06d}.ply|obj|stl"}


class HumanDataset(HumanSource):
    """Ragged ``human/vertices`` + ``human/faces`` of a dataset scene, else ``human/points`` splats."""

    def __init__(self, url: str, scene_id: str, scene=None):
        self.url, self.scene_id = url, scene_id
        if scene is None:
            from ..dataset import open_dataset

            scene = open_dataset(url).scene(scene_id)
        self.scene = scene
        names = set(scene.arrays())
        if {HUMAN_VERTICES, HUMAN_FACES} <= names:
            self.kind = "dataset:human/vertices+faces"
        elif HUMAN_POINTS in names:
            self.kind = "dataset:human/points"
        else:
            self.kind = "none"

    def __getstate__(self):  # worker processes reopen the dataset read-only
        return {**self.__dict__, "scene": None}

    def __call__(self, k: int):
        if self.scene is None and self.kind != "none":
            from ..dataset import open_dataset

            self.scene = open_dataset(self.url).scene(self.scene_id)
        if self.kind == "dataset:human/vertices+faces":
            v = np.asarray(self.scene.ragged(HUMAN_VERTICES, k), dtype=np.float64)
            f = np.asarray(self.scene.ragged(HUMAN_FACES, k), dtype=np.int64)
            return (v, f) if len(f) else None
        if self.kind == "dataset:human/points":
            v, f = points_to_mesh(self.scene.ragged(HUMAN_POINTS, k))
            return (v, f) if len(f) else None
        return None


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def mesh_sha256(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha256(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    return h.hexdigest()


__all__ = ["MESH_EXTS", "HUMAN_SPLAT_RADIUS_M", "points_to_mesh", "HumanSource", "HumanFile", "HumanDir",
           "HumanDataset", "file_sha256", "mesh_sha256"]
