"""Ray-casting backends behind one registry: first-hit casts against one static triangle mesh.

A backend is built once per mesh (``make_backend(name, vertices, faces)``) and answers
``cast6(rays) -> (t, face)`` for ``rays`` (N,6) float32 ``[ox oy oz dx dy dz]`` (unit directions):
``t`` (N,) float32 hit distance (inf = no hit), ``face`` (N,) integer triangle index (undefined
where ``t`` is inf); ``cast(origins, directions)`` is the same with ``face`` int64, -1 = no hit;
``occluded6(rays)`` (N,) bool: any hit with ray parameter in (0, 1), i.e. along a segment whose
length is the (unnormalised) direction's length (shadow-ray / line-of-sight queries). Normals, exact
distances and bounces are computed by :mod:`holodata.raytrace.trace` from the face index, so
every backend yields the same geometry.
"""
from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Callable

import numpy as np

BACKENDS: dict[str, Callable] = {}
DEFAULT_BACKEND = "open3d"
_OPEN3D_CAST = [False]   # open3d has cast in this process: its thread pool runs, a fork would lose it


def open3d_has_cast() -> bool:
    """open3d cast rays in this process (its first cast starts the thread pool Embree runs on, which a
    forked child would not have, with its locks in whatever state the fork found them); a process
    that has not cast may fork a tracing process (:class:`holodata.raytrace.pool.Helper`)."""
    return _OPEN3D_CAST[0]


def register_backend(name: str):
    def deco(cls):
        BACKENDS[name] = cls
        return cls

    return deco


def available_backends() -> list[str]:
    """Names of the registered backends whose library imports."""
    out = []
    for name, cls in BACKENDS.items():
        try:
            cls.check()
            out.append(name)
        except ImportError:
            pass
    return out


def make_backend(name: str, vertices: np.ndarray, faces: np.ndarray, nthreads: int = 0):
    if name not in BACKENDS:
        raise ValueError(f"unknown ray-tracing backend {name!r} (choose from {', '.join(BACKENDS)})")
    return BACKENDS[name](vertices, faces, nthreads=nthreads)


def _default_threads(nthreads: int) -> int:
    return nthreads if nthreads > 0 else (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0)


def open3d_module():
    """open3d's compiled module (``core``, ``t.geometry``): ``open3d`` when imported already, else
    its extension ``open3d.pybind`` loaded on its own — ``import open3d`` also imports its
    visualisation and ML packages (dash, plotly), which costs a tracing process more start-up time
    than loading the extension; a later ``import open3d`` reuses the loaded extension. Falls back
    to ``import open3d`` when the extension is not where the wheel puts it."""
    for name in ("open3d", "open3d.pybind"):
        if name in sys.modules and hasattr(sys.modules[name], "t"):
            return sys.modules[name]
    spec = importlib.util.find_spec("open3d")
    if spec is None:
        raise ImportError("open3d is not installed")
    try:
        folder = (spec.submodule_search_locations or [])[0]
        so = next(f for f in sorted(os.listdir(folder)) if f.startswith("pybind.") and f.endswith(".so"))
        ext = importlib.util.spec_from_file_location("open3d.pybind", os.path.join(folder, so))
        mod = importlib.util.module_from_spec(ext)
        ext.loader.exec_module(mod)
        sys.modules["open3d.pybind"] = mod
        return mod
    except (IndexError, StopIteration, OSError, ImportError, AttributeError):
        import open3d

        return open3d


@register_backend("open3d")
class Open3DBackend:
    """open3d ``t.geometry.RaycastingScene`` (Embree 3/4 underneath)."""

    name = "open3d"

    @staticmethod
    def check() -> None:
        open3d_module()

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, nthreads: int = 0):
        o3d = open3d_module()
        self._o3d = o3d
        self.nthreads = _default_threads(nthreads)
        self.scene = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        self.scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
        )

    def cast6(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _OPEN3D_CAST[0] = True
        ans = self.scene.cast_rays(self._o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, dtype=np.float32)),
                                   nthreads=self.nthreads)
        return ans["t_hit"].numpy(), ans["primitive_ids"].numpy()

    def occluded6(self, rays: np.ndarray) -> np.ndarray:
        """(N,) bool: anything hit with ray parameter in (0, 1) (directions carry the segment length)."""
        _OPEN3D_CAST[0] = True
        ans = self.scene.test_occlusions(self._o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, dtype=np.float32)),
                                         tnear=0.0, tfar=1.0, nthreads=self.nthreads)
        return ans.numpy().astype(bool)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _cast_via6(self, origins, directions)


@register_backend("embreex")
class EmbreexBackend:
    """embreex ``EmbreeScene`` (Embree 2 via Cython)."""

    name = "embreex"

    @staticmethod
    def check() -> None:
        import embreex.rtcore_scene  # noqa: F401

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, nthreads: int = 0):
        from embreex import mesh_construction, rtcore_scene

        self.scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(
            self.scene, np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.int32)
        )

    def cast6(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ans = self.scene.run(
            np.ascontiguousarray(rays[:, :3], dtype=np.float32),
            np.ascontiguousarray(rays[:, 3:], dtype=np.float32),
            output=1,
        )
        face = ans["primID"]
        return np.where(face >= 0, ans["tfar"], np.float32(np.inf)).astype(np.float32), face

    def occluded6(self, rays: np.ndarray) -> np.ndarray:
        ans = self.scene.run(
            np.ascontiguousarray(rays[:, :3], dtype=np.float32),
            np.ascontiguousarray(rays[:, 3:], dtype=np.float32),
            dists=np.ones(len(rays), dtype=np.float32),
            query="OCCLUDED",
        )
        return np.asarray(ans) >= 0

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _cast_via6(self, origins, directions)


def _cast_via6(backend, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rays = np.empty((len(origins), 6), dtype=np.float32)
    rays[:, :3] = origins
    rays[:, 3:] = directions
    t, face = backend.cast6(rays)
    return t, np.where(np.isfinite(t), face.astype(np.int64), -1)
