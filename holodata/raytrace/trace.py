"""Multi-bounce specular ray tracing (docs/format.md §2).

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

import threading
from dataclasses import asdict, dataclass

import numpy as np

from ..conventions import DEFAULT_MAX_BOUNCES, DEFAULT_MAX_RANGE_M, LOS_TOLERANCE_M
from . import _kernels
from .backends import DEFAULT_BACKEND, make_backend
from .labels import class_table, combine_label, face_normals, geometric_classes

SELF_HIT_OFFSET_M = 1e-4
_MAX_RECASTS = 4
BOX_MARGIN_M = 0.01  # the dynamic mesh's bounding box is grown by this before culling rays against it


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
    """One mesh with its backend, float64 vertices, unit face normals (float64 (F,3) and float32
    (3,F)) and plane offsets ``c = n·v0`` (float32 (F,))."""

    def __init__(self, vertices, faces, backend: str, nthreads: int):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError("face index out of range")
        self.normals = face_normals(self.vertices, self.faces)
        self.v0 = self.vertices[self.faces[:, 0]] if len(self.faces) else np.zeros((0, 3))
        self.n32 = np.ascontiguousarray(self.normals.T, dtype=np.float32)
        self.c32 = np.einsum("ij,ij->i", self.normals, self.v0).astype(np.float32)
        # float32 box of the vertices grown by BOX_MARGIN_M (culling, see _meets_box); per column, as numpy
        # reduces an (n,3) array along axis 0 slower (docs/design/raytrace.md, "Bounding box per column")
        v = self.vertices
        self.box = np.array([[v[:, k].min() - BOX_MARGIN_M for k in range(3)], [v[:, k].max() + BOX_MARGIN_M for k in range(3)]],
                            dtype=np.float32) if len(v) else None
        nrm = self.normals
        keep = np.flatnonzero((nrm[:, 0] != 0) | (nrm[:, 1] != 0) | (nrm[:, 2] != 0))  # zero-area faces are never hit
        if len(keep) == 0:
            self.backend = None
        elif len(keep) == len(self.faces):
            self.backend = make_backend(backend, self.vertices, self.faces, nthreads)
        else:
            self.backend = _FaceMapped(make_backend(backend, self.vertices, self.faces[keep], nthreads), keep)


class _FaceMapped:
    """A backend built on a subset of the faces, reporting the original face indices."""

    def __init__(self, inner, face_ids: np.ndarray):
        self.inner, self.face_ids = inner, face_ids

    def cast6(self, rays):
        t, f = self.inner.cast6(rays)
        hit = np.isfinite(t)
        return t, np.where(hit, self.face_ids[np.where(hit, f, 0).astype(np.int64)], 0)

    def occluded6(self, rays):
        return self.inner.occluded6(rays)


class _NumpyBounces:
    """The numpy trace's state (:meth:`RayScene._trace_numpy`): per bounce and ray the outputs, bounce
    major and structure of arrays (``rng`` (B,N), ``point``/``normal`` (B,3,N), ``face`` (B,N),
    ``hdyn`` (B,N)), the live rays' state ``S`` (12,n) float32 — rows 0-2 origin, 3-5 direction, 6-8
    normal, 9 t, 10 n·d, 11 accumulated distance —, their indices ``idx`` (None: all rays, in order)
    and each bounce's (indices, hit points) in ``visited`` for the LOS checks."""

    def __init__(self, O: np.ndarray, d: np.ndarray, B: int):
        N = O.shape[1]
        self.rng = np.full((B, N), np.nan, dtype=np.float32)
        self.point = np.full((B, 3, N), np.nan, dtype=np.float32)  # structure of arrays; (N,B,3) views returned
        self.normal = np.full((B, 3, N), np.nan, dtype=np.float32)
        self.face = np.full((B, N), -1, dtype=np.int64)
        self.hdyn = np.zeros((B, N), dtype=bool)
        self.visited: list = [None] * B
        self.S = np.empty((12, N), dtype=np.float32)
        self.S[0:3], self.S[3:6], self.S[11] = O, d, 0.0
        self.idx: np.ndarray | None = None

    def advance(self, b: int, t, f, isd, hit, max_range) -> None:
        """Bounce ``b``'s hits (t, face, is_dyn or None, hit) of the live rays: the rays that hit within
        ``max_range`` in all stay live; their range, point, normal (facing the ray), face and is_dyn
        recorded; each reflected about its normal from its hit point."""
        S = self.S
        S[9] = t
        S[11] += t
        ok = hit & (S[11] <= max_range)
        if not ok.all():
            keep = np.flatnonzero(ok)
            self.idx = keep if self.idx is None else self.idx[keep]
            S = self.S = S.take(keep, axis=1)
            f = f[keep]
            isd = None if isd is None else isd[keep]
        o, d, nx, t, nd = S[0:3], S[3:6], S[6:9], S[9], S[10]
        sel = slice(None) if self.idx is None else self.idx
        p = o + t * d
        nx *= np.where(nd > 0, np.float32(-1), np.float32(1))
        self.rng[b, sel] = S[11]
        self.point[b][:, sel] = p
        self.normal[b][:, sel] = nx
        self.face[b, sel] = f
        if isd is not None:
            self.hdyn[b, sel] = isd
        self.visited[b] = (sel, p)
        d += (2 * np.abs(nd)) * nx  # d - 2(d.n)n with n facing the ray (d.n = -|nd|)
        d /= np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        o[...] = p

    def los_parts(self, labels: bool, N: int) -> list:
        """[(b, ray indices, (3, n) hit points)] of bounces 2..B for :meth:`RayScene._los` (none without ``labels``)."""
        B = len(self.visited)
        parts: list = []
        if labels and B > 1:
            parts = [(b, self.visited[b]) for b in range(1, B) if self.visited[b] is not None]
            parts = [(b, np.arange(N) if isinstance(s, slice) else s, p) for b, (s, p) in parts]
            parts = [q for q in parts if len(q[1])]
        return parts


class RayScene:
    """Static triangle scene built once. ``vertices`` (V,3) m, ``faces`` (F,3) int;
    ``face_class`` (F,) uint8 per-face semantic class (else geometric classes are derived);
    ``class_names`` {id: name} for ``face_class``. ``class_names`` / ``human_class`` attributes give
    the table used in ``TraceResult.semantic``. Set ``cast_log = []`` to record every backend cast
    as ``(which, rays (n,6) float32)`` with which = "static" | "dynamic" (``cast_rays``) or
    "static:occluded" | "dynamic:occluded" (``test_occlusions`` with tfar = 1) (benchmarks)."""

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
        self.cull_dynamic = True
        self.compiled = True  # per-bounce array work in numba kernels (_kernels.py); False: the numpy reference

    # ------------------------------------------------------------------ casting
    def prepare_dynamic(self, vertices, faces):
        """Build a dynamic mesh once for reuse across calls (pass the result as ``dynamic=``)."""
        return self._dynamic((vertices, faces))

    def _dynamic(self, dynamic) -> _Geometry | None:
        if dynamic is None:
            return None
        if isinstance(dynamic, _Geometry):
            return dynamic
        hv, hf = dynamic
        g = _Geometry(hv, hf, self.backend_name, self.nthreads)
        return g if g.backend is not None else None

    def _cast6(self, rays: np.ndarray, dyn: _Geometry | None, soa=None):
        """Nearest hit of static + dynamic for rays (n,6) float32: t float32 (inf none), face
        (integer, undefined where no hit), is_dyn bool (n,) or None without a dynamic mesh. ``soa``:
        the same origins and directions as contiguous (3,n) float32 rows, if at hand (faster culling)."""
        if self.cast_log is not None:
            self.cast_log.append(("static", rays.copy()))
        ts, fs = self.static.backend.cast6(rays)
        if dyn is None:
            return ts, fs, None
        if not self.cull_dynamic:
            sub = None
        elif self.compiled:
            sub = _kernels.meets_box(rays, ts, dyn.box)
        else:
            o3, d3 = soa if soa is not None else (rays[:, :3].T, rays[:, 3:].T)
            sub = _meets_box(o3, d3, ts, dyn.box)
        if sub is None:
            if self.cast_log is not None:
                self.cast_log.append(("dynamic", rays.copy()))
            td, fd = dyn.backend.cast6(rays)
        else:  # only rays whose segment [0, t_static] meets the dynamic mesh's box can hit it first
            part = rays[sub]
            if self.cast_log is not None:
                self.cast_log.append(("dynamic", part))
            if self.compiled:  # one pass: the same minimum and selection as below
                if not len(sub):
                    return ts, fs, np.zeros(len(rays), bool)
                return _kernels.merge_hits(ts, fs, sub, *dyn.backend.cast6(part))
            td = np.full(len(rays), np.inf, dtype=np.float32)
            fd = np.zeros(len(rays), dtype=np.int64)
            if len(sub):
                td[sub], fd[sub] = dyn.backend.cast6(part)
        isd = td < ts
        return np.minimum(ts, td), np.where(isd, fd.astype(np.int64), fs.astype(np.int64)), isd

    def _first_hit(self, o: np.ndarray, d: np.ndarray, dyn: _Geometry | None, offset: float):
        """Nearest hit from ``o`` (float64 (n,3)) along unit ``d`` skipping the first ``offset`` m;
        hits still on the plane of ``o`` (float32 noise) are recast from just past them.

        Returns t (n,) float64 measured from ``o`` (inf none), face (n,) int64 (-1 none), is_dyn (n,)
        bool, normal (n,3) float64 (unoriented)."""
        n = len(o)
        t = np.full(n, np.inf)
        face = np.full(n, -1, dtype=np.int64)
        is_dyn = np.zeros(n, dtype=bool)
        normal = np.zeros((n, 3))
        todo = np.arange(n)
        start = np.full(n, float(offset))
        for _ in range(_MAX_RECASTS + 1):
            if len(todo) == 0:
                break
            oo, dd, ss = o[todo], d[todo], start[todo]
            rays = np.empty((len(todo), 6), dtype=np.float32)
            rays[:, :3] = oo + ss[:, None] * dd
            rays[:, 3:] = dd
            tc, ff, dy = self._cast6(rays, dyn)
            dy = np.zeros(len(todo), bool) if dy is None else dy
            hit = np.isfinite(tc)
            ff = np.where(hit, ff.astype(np.int64), -1)
            tt = tc.astype(np.float64) + ss
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
            start[todo[spurious]] = ss[spurious] + np.maximum(tc[spurious], 0) + offset
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

    def fixed_rays(self, origins, directions) -> FixedRays:
        """The same rays cast again and again with a different dynamic mesh each time (a fixed camera
        watching a walking person): :class:`FixedRays`."""
        return FixedRays(self, origins, directions)

    # ------------------------------------------------------------------ tracing
    def trace(self, origins, directions, max_bounces: int = DEFAULT_MAX_BOUNCES,
              max_range: float = DEFAULT_MAX_RANGE_M, dynamic=None, labels: bool = True) -> TraceResult:
        """Trace ``origins`` (N,3) m along ``directions`` (N,3) with up to ``max_bounces`` specular
        bounces; returns a :class:`TraceResult` (arrays are (N,B,...) views of bounce-major storage:
        ``res.range.T`` is a contiguous (B,N) array, ``res.point.transpose(1,0,2)`` a contiguous (B,N,3) —
        (B,3,N) storage on the numpy path, ``compiled = False``). ``dynamic`` =
        (vertices, faces) considered at
        every bounce and in the LOS checks. ``labels=False`` skips the LOS casts (all LOS).

        Works in float32 structure-of-arrays (3,n) form: hit distances are refined against the hit
        triangle's plane, so rounding stays ~1e-6 m over the 10 m scale."""
        O = np.ascontiguousarray(np.asarray(origins, dtype=np.float32).reshape(-1, 3).T)
        d = np.ascontiguousarray(np.asarray(directions, dtype=np.float32).reshape(-1, 3).T)
        return self.trace_soa(O, d, max_bounces, max_range, dynamic, labels)

    def trace_soa(self, O: np.ndarray, d: np.ndarray, max_bounces: int = DEFAULT_MAX_BOUNCES,
                  max_range: float = DEFAULT_MAX_RANGE_M, dynamic=None, labels: bool = True) -> TraceResult:
        """:meth:`trace` for structure-of-arrays input: ``O``, ``d`` (3,N) float32 (``O`` may be
        (3,1) for one common origin)."""
        O = np.ascontiguousarray(O, dtype=np.float32)
        d = np.ascontiguousarray(d, dtype=np.float32)
        if O.shape[1] == 1:
            O = np.ascontiguousarray(np.broadcast_to(O, d.shape))
        if O.shape != d.shape:
            raise ValueError(f"{O.shape[1]} origins for {d.shape[1]} directions")
        B = int(max_bounces)
        d = d / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        dyn = self._dynamic(dynamic)
        if self.compiled:
            return self._trace_compiled(O, d, B, max_range, dyn, labels)
        return self._trace_numpy(O, d, B, max_range, dyn, labels)

    def _trace_numpy(self, O, d, B: int, max_range, dyn, labels: bool) -> TraceResult:
        """:meth:`trace_soa`'s bounce loop in numpy (``compiled = False``; the reference the numba
        kernels match to the bit): per bounce the nearest hits of the live rays (:meth:`_numpy_hits`),
        then the rays that hit within ``max_range`` recorded and reflected (:meth:`_NumpyBounces.advance`)."""
        N = O.shape[1]
        tr = _NumpyBounces(O, d, B)
        rays = self._workspace(N)
        for b in range(B):
            if tr.S.shape[1] == 0:
                break
            t, f, isd, hit = self._numpy_hits(tr.S, b, rays, dyn)
            tr.advance(b, t, f, isd, hit, max_range)
        hit = tr.face >= 0
        los = self._los(tr.los_parts(labels, N), O, dyn, B, N)
        semantic = np.zeros((B, N), dtype=np.uint8)
        sm = hit & ~tr.hdyn
        semantic[sm] = self.face_semantic[tr.face[sm]]
        semantic[hit & tr.hdyn] = self.human_class
        label = combine_label(hit, tr.hdyn, los)
        return TraceResult(tr.rng.T, tr.normal.transpose(2, 0, 1), tr.point.transpose(2, 0, 1), tr.face.T, tr.hdyn.T,
                           label.T, semantic.T)

    def _numpy_hits(self, S: np.ndarray, b: int, rays: np.ndarray, dyn):
        """Bounce ``b`` of the live rays of state ``S`` (rows as :class:`_NumpyBounces`): cast from their
        origins (offset along the direction after bounce 1), each hit's distance refined against its
        triangle's plane, grazing self-hits recast exactly; writes the hit normals (S[6:9]) and n·d
        (S[10]). Returns (t, face, is_dyn or None, hit)."""
        st = self.static
        n = S.shape[1]
        o, d, nx = S[0:3], S[3:6], S[6:9]
        off = np.float32(SELF_HIT_OFFSET_M)
        R = rays[:n]
        ro = o + off * d if b else o
        R[:, :3] = ro.T
        R[:, 3:] = d.T
        t, f, isd = self._cast6(R, dyn, (ro, d))
        hit = np.isfinite(t)
        fz = np.where(hit if isd is None else hit & ~isd, f, 0)  # static face ids only
        st.n32.take(fz, axis=1, out=nx)
        c = st.c32[fz]
        if isd is not None:
            k = np.flatnonzero(isd)
            if len(k):
                nx[:, k] = dyn.n32[:, f[k]]
                c[k] = dyn.c32[f[k]]
        nd = S[10]
        np.multiply(nx[0], d[0], out=nd)
        nd += nx[1] * d[1]
        nd += nx[2] * d[2]
        no = nx[0] * o[0] + nx[1] * o[1] + nx[2] * o[2]
        if b:
            t = t + off
        with np.errstate(invalid="ignore", divide="ignore"):
            tref = (c - no) / nd
            t = np.where(np.abs(tref - t) < 1e-3, tref, t)
        if b:
            spur = np.flatnonzero(hit & (t < 0.5 * off))
            if len(spur):  # rare: grazing float32 self-hits; recast those exactly
                isd = self._recast_spurious(S, spur, (t, f, hit, isd), dyn)
        return t, f, isd, hit

    def _recast_spurious(self, S: np.ndarray, spur: np.ndarray, hits: tuple, dyn):
        """Recast the rays ``spur`` of state ``S`` exactly (:meth:`_first_hit` in float64, past the
        self-hit offset) and write their results into ``hits`` = (t, face, hit, is_dyn or None) and
        S's normal and n·d rows, in place; the is_dyn array (made when there was none and a recast
        ray hit the dynamic mesh)."""
        t, f, hit, isd = hits
        o, d, nx, nd = S[0:3], S[3:6], S[6:9], S[10]
        ts, fs, ds, ns = self._first_hit(o[:, spur].T.astype(np.float64), d[:, spur].T.astype(np.float64), dyn,
                                         float(np.float32(SELF_HIT_OFFSET_M)))
        t[spur], f[spur], nx[:, spur] = ts, np.maximum(fs, 0), ns.T
        hit[spur] = fs >= 0
        nd[spur] = np.einsum("ij,ji->i", ns, d[:, spur])
        if isd is None and ds.any():
            isd = np.zeros(S.shape[1], bool)
        if isd is not None:
            isd[spur] = ds
        return isd

    def _trace_compiled(self, O, d, B: int, max_range, dyn, labels: bool) -> TraceResult:
        """:meth:`trace_soa`'s bounce loop with the array work in numba kernels (:mod:`._kernels`): the
        same float32 operations in the same order, so identical to the bit to the numpy path."""
        N, st = O.shape[1], self.static
        rng = np.full((B, N), np.nan, dtype=np.float32)
        point = np.full((B, N, 3), np.nan, dtype=np.float32)  # (B,N,3): the gt/* layout, no copy in frames.py
        normal = np.full((B, N, 3), np.nan, dtype=np.float32)
        face = np.full((B, N), -1, dtype=np.int64)
        hdyn = np.zeros((B, N), dtype=bool)
        visited: list = []
        S = np.empty((12, N), dtype=np.float32)  # rows as in trace_soa
        S[0:3], S[3:6], S[11] = O, d, 0.0
        idx = np.arange(N)
        rays = self._workspace(N)
        off = np.float32(SELF_HIT_OFFSET_M)
        mr = np.asarray(max_range, dtype=np.result_type(np.float32, max_range))[()]  # numpy 2's comparison dtype
        dn32, dc32 = (dyn.n32, dyn.c32) if dyn is not None else (st.n32, st.c32)
        for b in range(B):
            n = S.shape[1]
            if n == 0:
                break
            R = rays[:n]
            _kernels.make_rays(S, off, b == 0, R)
            t, f, isd = self._cast6(R, dyn)
            isd = np.zeros(n, bool) if isd is None else isd
            hit, tt = np.empty(n, bool), np.empty(n, np.float32)
            if _kernels.refine(S, t, f, isd, st.n32, st.c32, dn32, dc32, off, b == 0, hit, tt):
                # rare: grazing float32 self-hits; recast those exactly (as the numpy path)
                self._recast_spurious(S, np.flatnonzero(hit & (tt < 0.5 * off)), (tt, f, hit, isd), dyn)
            S, idx, P = _kernels.advance(S, tt, hit, f, isd, mr, idx, b, rng, point, normal, face, hdyn)
            visited.append((b, idx, P))
        los = self._los([q for q in visited[1:] if len(q[1])] if labels else [], O, dyn, B, N)
        semantic = np.empty((B, N), dtype=np.uint8)
        label = np.empty((B, N), dtype=np.uint8)
        _kernels.labels(face, hdyn, los, self.face_semantic, np.uint8(self.human_class), semantic, label)
        return TraceResult(rng.T, normal.transpose(1, 0, 2), point.transpose(1, 0, 2), face.T, hdyn.T,
                           label.T, semantic.T)

    def _workspace(self, n: int) -> np.ndarray:
        """Reused (n,6) float32 ray buffer (fresh large allocations cost page faults every call), one
        per thread: several threads may trace with one scene at once (:meth:`FrameTracer.run
        <holodata.raytrace.frames.FrameTracer.run>`); everything else a trace writes is its own."""
        ws = self.__dict__.setdefault("_ws", {})
        key = threading.get_ident()
        buf = ws.get(key)
        if buf is None or len(buf) < n:
            buf = ws[key] = np.empty((n, 6), dtype=np.float32)
        return buf[:n]

    def _los(self, parts: list, O: np.ndarray, dyn, B: int, N: int) -> np.ndarray:
        """(B, N) bool: bounce b of ray i is LOS (its hit point visible from the ray's origin) for the
        ``parts`` [(b, ray indices, (3, n) float32 hit points)] of bounces 2..B, checked in one batch;
        True elsewhere (bounce 1 is LOS by construction)."""
        los = np.ones((B, N), dtype=bool)
        if parts:
            ii = np.concatenate([q[1] for q in parts])
            P = np.concatenate([q[2] for q in parts], axis=1)
            vis = self._visible32(O, P, dyn, ii)
            pos = 0
            for b, i, _ in parts:
                los[b, i] = vis[pos:pos + len(i)]
                pos += len(i)
        return los

    def _visible32(self, O: np.ndarray, P: np.ndarray, dyn, idx=None) -> np.ndarray:
        """(n,) bool for (3,n) float32 origins and points: P visible from O, i.e. nothing (scene or
        dynamic mesh) on the segment closer than LOS_TOLERANCE_M before P. One any-hit (occlusion)
        query per mesh, the direction scaled to the segment length minus the tolerance. ``idx`` (n,)
        int64: the origins are ``O[:, idx]`` (gathered inside the compiled kernel, no copy)."""
        if self.compiled:
            rays = self._workspace(P.shape[1])
            idx = np.arange(P.shape[1]) if idx is None else idx
            near = _kernels.los_rays(np.ascontiguousarray(O), idx, np.ascontiguousarray(P), np.float32(LOS_TOLERANCE_M),
                                     rays)
        else:
            O = O if idx is None else O[:, idx]
            v = P - O
            L = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
            near = L <= LOS_TOLERANCE_M
            v *= np.where(near, np.float32(0), (L - np.float32(LOS_TOLERANCE_M)) / np.where(near, np.float32(1), L))
            rays = self._workspace(len(L))
            rays[:, :3] = O.T
            rays[:, 3:] = v.T
        if self.cast_log is not None:
            self.cast_log.append(("static:occluded", rays.copy()))
        blocked = self.static.backend.occluded6(rays)
        if dyn is not None:
            if not self.cull_dynamic:
                sub = None
            elif self.compiled:
                sub = _kernels.meets_box(rays, np.ones(1, np.float32), dyn.box)
            else:
                sub = _meets_box(O, v, np.float32(1), dyn.box)
            part = rays if sub is None else rays[sub]
            if self.cast_log is not None:
                self.cast_log.append(("dynamic:occluded", part.copy() if sub is None else part))
            if sub is None:
                blocked |= dyn.backend.occluded6(rays)
            elif len(sub):
                blocked[sub] |= dyn.backend.occluded6(part)
        return near | ~blocked

    def _visible(self, O: np.ndarray, P: np.ndarray, dyn) -> np.ndarray:
        """(n,) bool for (n,3) origins and points: P visible from O along the straight segment."""
        return self._visible32(np.asarray(O, np.float32).T, np.asarray(P, np.float32).T, self._dynamic(dyn))


def _meets_box(o: np.ndarray, d: np.ndarray, tmax, box: np.ndarray) -> np.ndarray:
    """Indices of the rays, origins ``o`` and directions ``d`` (3,n) float32 (rows may be strided views
    of an (n,6) ray array), whose segment ``o + s d``, s in [0, ``tmax``] (scalar or (n,), inf
    allowed), meets the axis-aligned ``box`` (2,3) float32 [lo, hi] (slab test).

    Conservative, so culling never changes a result: ``box`` is the mesh's box grown by
    BOX_MARGIN_M, which moves each slab's entry at least that far (|d| <= 1 m per unit s for the
    unit directions of casts; ``tmax`` = 1 segments of the LOS checks are shorter than the scene)
    ahead of float32 rounding (~1e-6 m at 10 m). A hit of the mesh lies in its box, so a ray left
    out would have missed the mesh or hit it beyond ``tmax``, where the static hit wins."""
    enter = leave = None
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for k in range(3):  # per axis on (n,) rows: numpy is slow on (n,3) arrays with their 3-long inner loops
            inv = np.float32(1) / d[k]  # d = 0: both slab ends -inf/+inf (origin inside) or same-signed
            a = (box[0, k] - o[k]) * inv
            b = (box[1, k] - o[k]) * inv
            # fmin/fmax ignore the NaN of 0 * inf (d = 0 with the origin on the grown box's face:
            # >= BOX_MARGIN_M from the mesh, so left out either way)
            lo, hi = np.fmin(a, b), np.fmax(a, b)
            enter = lo if enter is None else np.fmax(enter, lo, out=enter)
            leave = hi if leave is None else np.fmin(leave, hi, out=leave)
    return np.flatnonzero((enter <= leave) & (leave >= 0) & (enter <= tmax))


class FixedRays:
    """Rays ``origins``, ``directions`` (N,3) cast against ``scene`` once per dynamic mesh:
    :meth:`cast` returns exactly ``scene.cast(origins, directions, dynamic)``, but the static mesh is
    cast once, here, and each call casts again only the rays whose segment up to their static hit
    meets the dynamic mesh's grown box, the test the full cast culls with (:func:`_meets_box`). Every
    other ray gets, in the full cast, its static result; a ray's result never depends on the other
    rays of its batch. A VGA depth camera at a fixed pose (``holodata.synth``) casts a few thousand
    rays a frame instead of 250 000."""

    def __init__(self, scene: RayScene, origins, directions):
        self.scene = scene
        self.origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        self.directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        self.static = scene.cast(self.origins, self.directions)
        d = _unit(self.directions)
        self._rays = np.empty((len(d), 6), dtype=np.float32)   # as :meth:`RayScene._first_hit` builds them
        self._rays[:, :3] = self.origins + 0.0 * d
        self._rays[:, 3:] = d
        # the full cast culls with the backend's float32 distance; the refined one kept here is within
        # 1 mm of it (RayScene._first_hit), so this bound keeps every ray that test keeps, and more
        self._tmax = self.static.t + np.float32(2e-3)

    def cast(self, dynamic=None) -> CastResult:
        """:meth:`RayScene.cast` of the rays with ``dynamic`` = (vertices, faces), a prepared mesh or None."""
        st, sc = self.static, self.scene
        dyn = sc._dynamic(dynamic)
        if dyn is not None and not sc.cull_dynamic:
            return sc.cast(self.origins, self.directions, dyn)
        out = CastResult(st.t.copy(), st.normal.copy(), st.face.copy(), st.hit_dynamic.copy())
        if dyn is None:
            return out
        sub = _kernels.meets_box(self._rays, self._tmax, dyn.box)
        if len(sub):
            part = sc.cast(self.origins[sub], self.directions[sub], dyn)
            out.t[sub], out.normal[sub], out.face[sub], out.hit_dynamic[sub] = (part.t, part.normal, part.face,
                                                                             part.hit_dynamic)
        return out


def _unit(d: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def trace(vertices, faces, origins, directions, max_bounces: int = DEFAULT_MAX_BOUNCES,
          max_range: float = DEFAULT_MAX_RANGE_M, dynamic=None, **scene_options) -> dict:
    """One-shot multi-bounce trace (docs/format.md §6): :meth:`RayScene.trace` on a scene built for this
    call, ``scene_options`` the rest of :class:`RayScene`'s arguments (``backend``, ``face_class``,
    ``class_names``, ``nthreads``). Returns a dict: ``range`` (N,B) float32 accumulated travel distance m
    (NaN none), ``normal`` (N,B,3), ``point`` (N,B,3), ``face`` (N,B) int64 (-1 none), plus
    ``hit_dynamic``, ``label``, ``semantic`` (see :class:`TraceResult`)."""
    scene = RayScene(vertices, faces, **scene_options)
    return scene.trace(origins, directions, max_bounces=max_bounces, max_range=max_range, dynamic=dynamic).as_dict()
