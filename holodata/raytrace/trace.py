"""Multi-bounce specular ray tracing (DESIGN §2).

``R_b`` is the accumulated travel distance from the beam origin to the b-th bounce point;
``d_b = d_{b-1} - 2 (d_{b-1}·n) n`` with ``n`` the unit geometric (per-triangle) normal flipped
to face the incoming ray. The next ray starts at the hit point offset by ``SELF_HIT_OFFSET_M``
along the new direction; a hit that still lands on the plane of the point it left (float32
noise at grazing angles) is recast from just past it, so thin geometry (>= 0.1 mm) is never
skipped. Distances are refined in float64 against the hit triangle's plane, so all backends
agree to float64 precision when they report the same triangle.

A static scene is built once (:class:`RayScene`); a dynamic mesh (the human of a frame) is
given per call, cast separately and merged by nearest hit, so the static BVH is never rebuilt.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..conventions import DEFAULT_MAX_BOUNCES, DEFAULT_MAX_RANGE_M, LOS_TOLERANCE_M
from .backends import DEFAULT_BACKEND, make_backend
from .labels import class_table, combine_label, face_normals, geometric_classes

SELF_HIT_OFFSET_M = 1e-4
_MAX_RECASTS = 4


@dataclass
class CastResult:
    """First hits: ``t`` (N,) float32 m (inf = none), ``normal`` (N,3) float32 unit geometric normal
    facing the ray (0 = none), ``face`` (N,) int64 triangle index in the mesh that was hit (-1 = none),
    ``hit_dynamic`` (N,) bool (True = the dynamic mesh was hit)."""

    t: np.ndarray
    normal: np.ndarray
    face: np.ndarray
    hit_dynamic: np.ndarray


@dataclass
class TraceResult:
    """Per ray and bounce (B = max_bounces): ``range`` (N,B) float32 accumulated travel distance m
    (NaN = none), ``normal`` (N,B,3) float32 unit normal facing the incoming ray, ``point`` (N,B,3)
    float32 hit point (same frame as the origins), ``face`` (N,B) int64 (-1 = none; index into the
    dynamic mesh where ``hit_dynamic``), ``hit_dynamic`` (N,B) bool, ``label`` (N,B) uint8
    (conventions.Label), ``semantic`` (N,B) uint8 class id (0 = none; table in RayScene.class_names)."""

    range: np.ndarray
    normal: np.ndarray
    point: np.ndarray
    face: np.ndarray
    hit_dynamic: np.ndarray
    label: np.ndarray
    semantic: np.ndarray

    def as_dict(self) -> dict:
        return asdict(self)


class _Geometry:
    """One mesh with its backend, float64 vertices and unit face normals."""

    def __init__(self, vertices, faces, backend: str, nthreads: int):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError("face index out of range")
        self.normals = face_normals(self.vertices, self.faces)
        self.v0 = self.vertices[self.faces[:, 0]] if len(self.faces) else np.zeros((0, 3))
        self.backend = make_backend(backend, self.vertices, self.faces, nthreads) if len(self.faces) else None


class RayScene:
    """Static triangle scene built once. ``vertices`` (V,3) m, ``faces`` (F,3) int;
    ``face_class`` (F,) uint8 per-face semantic class (else geometric classes are derived);
    ``class_names`` {id: name} for ``face_class``. ``class_names`` / ``human_class`` attributes give
    the table used in ``TraceResult.semantic``. Set ``cast_log = []`` to record every backend cast
    as ``(which, origins float32, directions float32)`` (benchmarks)."""

    def __init__(self, vertices, faces, backend: str = DEFAULT_BACKEND, face_class=None,
                 class_names: dict | None = None, nthreads: int = 0):
        self.backend_name = backend
        self.nthreads = nthreads
        self.static = _Geometry(vertices, faces, backend, nthreads)
        if self.static.backend is None:
            raise ValueError("static scene mesh has no triangles")
        if face_class is not None:
            face_class = np.asarray(face_class, dtype=np.uint8).reshape(-1)
            if len(face_class) != len(self.static.faces):
                raise ValueError(f"face_class has {len(face_class)} entries for {len(self.static.faces)} faces")
            self.face_semantic = face_class
            self.class_source = "face_class"
        else:
            self.face_semantic = geometric_classes(self.static.vertices, self.static.faces, self.static.normals)
            self.class_source = "geometric"
        self.class_names, self.human_class = class_table(face_class, class_names)
        self.cast_log: list | None = None

    # ------------------------------------------------------------------ casting
    def _dynamic(self, dynamic) -> _Geometry | None:
        if dynamic is None:
            return None
        if isinstance(dynamic, _Geometry):
            return dynamic
        hv, hf = dynamic
        g = _Geometry(hv, hf, self.backend_name, self.nthreads)
        return g if g.backend is not None else None

    def _raw(self, geom: _Geometry, which: str, o: np.ndarray, d: np.ndarray):
        o32 = o.astype(np.float32)
        d32 = d.astype(np.float32)
        if self.cast_log is not None:
            self.cast_log.append((which, o32, d32))
        return geom.backend.cast(o32, d32)

    def _first_hit(self, o: np.ndarray, d: np.ndarray, dyn: _Geometry | None, offset: float):
        """Nearest hit from ``o`` (float64 (n,3)) along unit ``d`` skipping the first ``offset`` m.

        Returns t (n,) float64 measured from ``o`` (inf none), face (n,) int64, is_dyn (n,) bool,
        normal (n,3) float64 (unoriented)."""
        n = len(o)
        t = np.full(n, np.inf)
        face = np.full(n, -1, dtype=np.int64)
        is_dyn = np.zeros(n, dtype=bool)
        normal = np.zeros((n, 3))
        todo = np.arange(n)
        start = np.full(n, float(offset))
        for attempt in range(_MAX_RECASTS + 1):
            if len(todo) == 0:
                break
            oo, dd, ss = o[todo], d[todo], start[todo]
            oc = oo + ss[:, None] * dd if offset > 0 else oo
            ts, fs = self._raw(self.static, "static", oc, dd)
            tt = ts.astype(np.float64)
            ff = fs
            dy = np.zeros(len(todo), dtype=bool)
            if dyn is not None:
                td, fd = self._raw(dyn, "dynamic", oc, dd)
                dy = td < ts
                tt = np.where(dy, td, tt)
                ff = np.where(dy, fd, ff)
            hit = ff >= 0
            tt = tt + ss
            nn = np.zeros((len(todo), 3))
            v0 = np.zeros((len(todo), 3))
            hs = hit & ~dy
            nn[hs] = self.static.normals[ff[hs]]
            v0[hs] = self.static.v0[ff[hs]]
            if dyn is not None:
                hd = hit & dy
                nn[hd] = dyn.normals[ff[hd]]
                v0[hd] = dyn.v0[ff[hd]]
            # refine the distance in float64 against the hit triangle's plane
            nd = np.einsum("ij,ij->i", nn, dd)
            num = np.einsum("ij,ij->i", nn, v0 - oo)
            ok = hit & (np.abs(nd) > 1e-9)
            tref = np.divide(num, nd, out=tt.copy(), where=ok)
            with np.errstate(invalid="ignore"):
                good = ok & (np.abs(tref - tt) < 1e-3)
            tt = np.where(good, tref, tt)
            spurious = hit & (tt < 0.5 * offset) if offset > 0 else np.zeros(len(todo), bool)
            keep = ~spurious
            sel = todo[keep]
            t[sel] = np.where(hit[keep], tt[keep], np.inf)
            face[sel] = ff[keep]
            is_dyn[sel] = dy[keep] & hit[keep]
            normal[sel] = nn[keep]
            # recast spurious self-hits from just past the reported (cast) hit
            tcast = (ts if dyn is None else np.minimum(ts, td)).astype(np.float64)
            start[todo[spurious]] = ss[spurious] + np.maximum(tcast[spurious], 0) + offset
            todo = todo[spurious]
        return t, face, is_dyn, normal

    def cast(self, origins, directions, dynamic=None) -> CastResult:
        """One first-hit cast per ray (no offset): ``origins`` (N,3) m, ``directions`` (N,3) (normalised
        here); ``dynamic`` = (vertices, faces) of a per-call mesh, or None."""
        o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        d = _unit(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
        t, face, is_dyn, n = self._first_hit(o, d, self._dynamic(dynamic), 0.0)
        s = np.einsum("ij,ij->i", n, d)
        n = np.where(s[:, None] > 0, -n, n)
        return CastResult(t.astype(np.float32), n.astype(np.float32), face, is_dyn)

    # ------------------------------------------------------------------ tracing
    def trace(self, origins, directions, max_bounces: int = DEFAULT_MAX_BOUNCES,
              max_range: float = DEFAULT_MAX_RANGE_M, dynamic=None, labels: bool = True) -> TraceResult:
        """Trace ``origins`` (N,3) m along ``directions`` (N,3) with up to ``max_bounces`` specular
        bounces; returns a :class:`TraceResult`. ``dynamic`` = (vertices, faces) considered at every
        bounce and in the LOS checks. ``labels=False`` skips the LOS casts (labels then assume LOS)."""
        O = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        d = _unit(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
        if len(O) != len(d):
            raise ValueError(f"{len(O)} origins for {len(d)} directions")
        N, B = len(O), int(max_bounces)
        dyn = self._dynamic(dynamic)
        rng = np.full((N, B), np.nan, dtype=np.float32)
        normal = np.full((N, B, 3), np.nan, dtype=np.float32)
        point = np.full((N, B, 3), np.nan, dtype=np.float32)
        face = np.full((N, B), -1, dtype=np.int64)
        hdyn = np.zeros((N, B), dtype=bool)
        pts64 = [None] * B
        idx = np.arange(N)
        o = O
        acc = np.zeros(N)
        for b in range(B):
            if len(idx) == 0:
                break
            t, f, isd, n = self._first_hit(o, d, dyn, 0.0 if b == 0 else SELF_HIT_OFFSET_M)
            total = acc + t
            ok = (f >= 0) & (total <= max_range)
            idx, o, d, t, f, isd, n, acc = idx[ok], o[ok], d[ok], t[ok], f[ok], isd[ok], n[ok], total[ok]
            p = o + t[:, None] * d
            s = np.einsum("ij,ij->i", n, d)
            n = np.where(s[:, None] > 0, -n, n)
            rng[idx, b] = acc
            point[idx, b] = p
            normal[idx, b] = n
            face[idx, b] = f
            hdyn[idx, b] = isd
            pts64[b] = (idx, p)
            d = _unit(d + 2.0 * np.abs(s)[:, None] * n)  # d - 2(d.n)n with n facing the ray: d.n = -|s|
            o = p
        hit = face >= 0
        los = np.ones((N, B), dtype=bool)
        if labels and B > 1:
            parts = [(b, pts64[b]) for b in range(1, B) if pts64[b] is not None and len(pts64[b][0])]
            if parts:
                ii = np.concatenate([p[1][0] for p in parts])
                bb = np.concatenate([np.full(len(p[1][0]), p[0]) for p in parts])
                P = np.concatenate([p[1][1] for p in parts])
                los[ii, bb] = self._visible(O[ii], P, dyn)
        semantic = np.zeros((N, B), dtype=np.uint8)
        st = hit & ~hdyn
        semantic[st] = self.face_semantic[face[st]]
        semantic[hit & hdyn] = self.human_class
        label = combine_label(hit, hdyn, los)
        return TraceResult(rng, normal, point, face, hdyn, label, semantic)

    def _visible(self, O: np.ndarray, P: np.ndarray, dyn) -> np.ndarray:
        """(n,) bool: P visible from O along the straight segment (LOS_TOLERANCE_M tolerance)."""
        v = P - O
        L = np.linalg.norm(v, axis=1)
        near = L <= LOS_TOLERANCE_M
        dirs = v / np.where(near, 1.0, L)[:, None]
        dirs[near] = (1.0, 0.0, 0.0)
        t, _, _, _ = self._first_hit(O, dirs, dyn, 0.0)
        return near | (t >= L - LOS_TOLERANCE_M)


def _unit(d: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def trace(vertices, faces, origins, directions, max_bounces: int = DEFAULT_MAX_BOUNCES,
          max_range: float = DEFAULT_MAX_RANGE_M, backend: str = DEFAULT_BACKEND, dynamic=None,
          face_class=None) -> dict:
    """One-shot multi-bounce trace (DESIGN §6). Returns a dict: ``range`` (N,B) float32 accumulated
    travel distance m (NaN none), ``normal`` (N,B,3), ``point`` (N,B,3), ``face`` (N,B) int64 (-1 none),
    plus ``hit_dynamic``, ``label``, ``semantic`` (see :class:`TraceResult`)."""
    scene = RayScene(vertices, faces, backend=backend, face_class=face_class)
    return scene.trace(origins, directions, max_bounces=max_bounces, max_range=max_range, dynamic=dynamic).as_dict()
