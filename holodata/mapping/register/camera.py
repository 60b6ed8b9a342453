"""The depth camera's frames: :class:`CameraFrames`, the static depth (:func:`static_depth`),
the per-frame candidate returns of a moving or standing person (:func:`frame_candidates`)
and what the camera sees through (:func:`camera_seen_through`) or sees swept by a walk along its
line of sight (:func:`camera_swept`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...conventions import transform_points
from ...dataset.layout import CALIB_T_WORLD_CAMERA, CAMERA_POINTS, CAMERA_POINTS_WORLD
from ...errors import InputError
from ...progress import track
from .config import RegisterConfig

# median absolute deviation → standard deviation for normal noise
MAD_TO_SIGMA = 1.4826
# nearer than this to the camera no depth is trusted (behind or at the lens: no pixel, no stereo)
MIN_DEPTH_M = 0.1
# a pixel's background window is at least this wide (3 σ of the stereo model can be sub-centimetre
# near the camera, finer than the depth quantisation)
MIN_WINDOW_M = 0.02
# the background samples' inlier band (3 robust σ) is at least this wide
MIN_INLIER_BAND_M = 0.005
# depth noise σ where the data says nothing (no spread): 1 cm; and the stereo model's floor
UNKNOWN_SIGMA_M = 0.01
MIN_MODEL_SIGMA_M = 1e-3
# the stereo model σ = a·z² needs this many pixels with a spread to fit a
MIN_MODEL_PIXELS = 100


# ------------------------------------------------------------------------------------ camera frames
@dataclass
class CameraFrames:
    """A scene's camera clouds on the depth image grid: ``K`` (3,3), ``shape`` (h, w)."""

    scene: object
    K: np.ndarray
    shape: tuple

    @classmethod
    def open(cls, scene, url: str = "") -> CameraFrames:
        where = f"{url}: scene {scene.id!r}"
        if CAMERA_POINTS not in set(scene.arrays()):
            raise InputError(f"{where} has no camera (camera/points): a LiDAR-only scene, e.g. a mapping pass, has "
                             f"nothing to register")
        intr = ((scene.attrs.get("sensors") or {}).get("camera") or {}).get("intrinsics")
        if not intr or "K" not in intr:
            raise InputError(f"{where}: camera has no intrinsics (sensors.camera.intrinsics); register needs a "
                             f"depth camera whose pixels can be recovered")
        return cls(scene, np.asarray(intr["K"], float), (int(intr["height"]), int(intr["width"])))

    def points(self, k: int) -> np.ndarray:
        """(N,3) float64 finite camera-frame points of frame ``k`` in front of the camera (z > 0)."""
        return _camera_points(self.scene, k)

    def counts(self) -> np.ndarray:
        """(T,) int64 points stored per frame (from the ragged offsets; nothing else is read)."""
        return np.diff(np.asarray(self.scene[CAMERA_POINTS].offsets[...], np.int64))

    def depth(self, k: int) -> np.ndarray:
        """(h,w) float32 depth image of frame ``k`` (NaN = none): each point in front of the camera (z > 0)
        at its nearest pixel, in float32 as stored (the camera points of a depth image are its pixels'
        rays, so the same pixels as in float64, and faster: ``docs/design/register.md``); non-finite points
        go nowhere."""
        p = np.asarray(self.scene.ragged(CAMERA_POINTS, k))
        h, w = self.shape
        D = np.full(h * w, np.nan, np.float32)
        if len(p):
            p = p.astype(np.float32, copy=False)
            f32 = np.float32
            with np.errstate(invalid="ignore", divide="ignore"):
                z = p[:, 2]
                iz = f32(1.0) / z
                u = p[:, 0] * iz
                u *= f32(self.K[0, 0])
                u += f32(self.K[0, 2])
                v = p[:, 1] * iz
                v *= f32(self.K[1, 1])
                v += f32(self.K[1, 2])
                np.rint(u, out=u)
                np.rint(v, out=v)
                ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)    # NaN/inf compare False
                pix = v.astype(np.intp)    # flat pixel index: one index array to scatter with, not two
                pix *= w
                pix += u.astype(np.intp)
            if ok.all():                   # (the usual frame: no gathered copies)
                D[pix] = z
            else:
                D[pix[ok]] = z[ok]
        return D.reshape(h, w)

    def rays(self) -> np.ndarray:
        """(h,w,3) camera-frame rays with z = 1."""
        h, w = self.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        return np.stack([(u - self.K[0, 2]) / self.K[0, 0], (v - self.K[1, 2]) / self.K[1, 1], np.ones((h, w))], -1)


def static_depth(cam: CameraFrames, frames: list[int], quiet: bool = True, far_quantile: float = 0.8,
                 images: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Static depth picture from ``frames``: per pixel the mean of the *background* samples (NaN where
    fewer than half the frames have a return), their robust spread σ (1.4826 · MAD, m) and how many
    were averaged. A moving person is only ever in front of the static scene, so the background
    samples are those within 3 σ (stereo model, :func:`depth_noise_model`) of the pixel's
    ``far_quantile`` sample, then within 3 robust sigmas of their median. The plain median failed
    when a person walks along the camera's line of sight and covers the same pixels in most frames
    (the person became static scene and a wall fragment was taken instead: ``docs/design/register.md``,
    static depth). A pixel has no static depth (NaN: its returns are candidates in
    every frame) where fewer than half the frames have a return, or where fewer than half the returns
    are background samples and the nearest other sample lies within the window of them (a continuum of
    depths: something moving along the line of sight that covers the pixel in every frame, not a wall
    seen behind a person). Frames whose depth image holds no return are left out; None when none holds
    one. ``images``: a dict that receives {frame: depth image} of ``frames``."""
    if not frames:
        return None
    images = {} if images is None else images
    for k in track(frames, len(frames), "camera background", quiet):
        images[k] = cam.depth(k)
    stack = np.stack([images[k] for k in frames])
    keep = np.isfinite(stack).any(axis=(1, 2))
    return static_depth_of(stack[keep], far_quantile) if keep.any() else None


def static_depth_of(stack: np.ndarray, far_quantile: float = 0.8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`static_depth` of a stack of depth images (F,h,w) float32 m, NaN = no return.

    Everything here is a per-pixel statistic of the frames' samples, so it is read off one sorted
    copy of the stack: a pixel's background samples (within the window of its far sample) are a run
    of its sorted samples, and so are the samples short of that window. One float64 buffer holds the
    deviations; the fresh memory of a temporary per step (~1 GB for 60 frames of 376x672) cost more
    than the arithmetic. Same values as the plain formulation (test)."""
    import warnings

    F = len(stack)
    s = np.sort(stack, axis=0)                       # NaN (and inf) sort last
    n = np.isfinite(stack).sum(0)
    dev = np.empty(stack.shape, np.float64)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        med, far = (_sorted_quantile(s, n, q) for q in (0.5, far_quantile))   # (np.nanmedian, np.nanquantile)
        np.abs(np.subtract(stack, med[None], out=dev), out=dev)
        dev.sort(axis=0)
        mad = MAD_TO_SIGMA * _sorted_quantile(dev, n, 0.5)
        window = np.maximum(3 * depth_noise_model(far, mad), MIN_WINDOW_M)
        # the background samples, within the window of the far one: sorted samples [start, start + m)
        np.subtract(s, far[None], out=dev)
        start = (dev < -window[None]).sum(0)
        inside = np.abs(dev, out=dev) <= window[None]
        m = inside.sum(0)
        med = _sorted_quantile(s, m, 0.5, start)
        np.abs(np.subtract(s, med[None], out=dev), out=dev)
        dev[np.logical_not(inside, out=inside)] = np.nan
        dev.sort(axis=0)
        mad = MAD_TO_SIGMA * _sorted_quantile(dev, m, 0.5)
        # the nearest sample short of the background window: a background seen in a minority of the
        # frames must stand apart from what was in front of it (a wall behind a person); far samples
        # that continue the nearer ones are the far end of something moving along the line of sight
        short = (s < (far - window)[None]).sum(0)
        below = np.where(short > 0, np.take_along_axis(s, np.maximum(short - 1, 0)[None], 0)[0], -np.inf)
        apart = (far - window) - below >= window
        inl = np.abs(np.subtract(stack, med[None], out=dev), out=dev) <= np.maximum(3 * mad, MIN_INLIER_BAND_M)[None]
        cnt = inl.sum(0)
        # background are only the inliers within the window of the far sample as well: 3 robust sigmas of
        # samples that fill the window evenly (the far end of a walk along the line of sight) reach beyond
        # it, and counted half the walk as background (docs/design/register.md, "A person lingering").
        # The mean stays that of the inliers, a band symmetric about their median (the window is not)
        cnt_bg = (inl & (np.abs(np.subtract(stack, far[None], out=dev), out=dev) <= window[None])).sum(0)
        s.fill(0.0)                                   # (s as the buffer of the inliers' sum: no NaN in it)
        np.copyto(s, stack, where=inl)
        mean = np.where(cnt > 0, s.sum(axis=0) / np.maximum(cnt, 1), np.nan)
    # no static depth where fewer than half the frames have a return, nor where fewer than half the
    # returns are background and these do not stand apart (a person walking along the line of sight
    # covers such pixels in every frame: their "static" depth was the person at the far end of the walk;
    # docs/design/register.md, static depth)
    mean = np.where((n * 2 >= F) & ((cnt_bg * 2 >= n) | apart), mean, np.nan).astype(np.float32)
    return mean, mad.astype(np.float32), cnt.astype(np.int32)


def _sorted_quantile(s: np.ndarray, n: np.ndarray, q: float, start: np.ndarray | int = 0) -> np.ndarray:
    """Quantile ``q`` (linear interpolation, as ``np.nanquantile``) of each pixel's ``n`` (H,W) values
    ``s[start:start + n]`` of a stack ``s`` (F,H,W) sorted along axis 0; NaN where n is 0."""
    top = np.maximum(n - 1, 0)
    pos = q * top
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, top)
    last = len(s) - 1
    v_lo = np.take_along_axis(s, np.minimum(start + lo, last)[None], 0)[0]
    v_hi = np.take_along_axis(s, np.minimum(start + hi, last)[None], 0)[0]
    return np.where(n > 0, v_lo + (pos - lo) * (v_hi - v_lo), np.nan)


@dataclass
class ForegroundTest:
    """Which camera returns may be a person (:func:`frame_candidates`): those nearer than ``front``
    (h,w) m (the static depth less its noise margin) or on pixels marked ``always`` (h,w) bool, moved
    to the map through ``T`` (4,4) T_world_camera along the pixel ``rays`` (h,w,3), and not explained
    by a map point (``map_tree``, a cKDTree of the map points)."""

    T: np.ndarray
    rays: np.ndarray
    front: np.ndarray
    always: np.ndarray
    map_tree: object


def frame_candidates(cam: CameraFrames, frames, test: ForegroundTest, cfg: RegisterConfig, images: dict | None = None,
                     quiet: bool = True, label: str = "human candidates") -> list:
    """Per frame k of ``frames``: the returns that may be a person, (qw (N,3) float64 map frame, vv, uu
    (N,) int64 pixel rows / columns, dv (N,) float32 optical depths m): returns within
    ``cfg.max_range_m`` that pass ``test`` (:class:`ForegroundTest`: nearer than its ``front`` or on
    its ``always`` pixels), moved to the map through its ``T`` along its ``rays``, and farther than
    ``cfg.map_explain_m`` from every map point (its ``map_tree``). ``images``: depth images already
    made, by frame (taken out of the dict as used)."""
    T, rays, front, always, map_tree = test.T, test.rays, test.front, test.always, test.map_tree
    out = []
    bound = np.nextafter(cfg.map_explain_m, np.inf)    # far points end their search early
    for k in track(frames, len(frames), label, quiet):
        D = images.pop(k, None) if images else None
        if D is None:
            D = cam.depth(k)
        with np.errstate(invalid="ignore"):
            fg = np.isfinite(D) & (always | (front > D)) & (cfg.max_range_m >= D)
        vv, uu = np.nonzero(fg)
        dv = D[vv, uu]
        qw = transform_points(T, rays[vv, uu] * dv[:, None])
        if len(qw):
            far = map_tree.query(qw, k=1, distance_upper_bound=bound, workers=1)[0] > cfg.map_explain_m
            qw, vv, uu, dv = qw[far], vv[far], uu[far], dv[far]
        out.append((qw, vv, uu, dv))
    return out


def _map_pixels(points: np.ndarray, T: np.ndarray, K: np.ndarray, shape: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where map ``points`` (N,3, world) fall in the image of the camera at ``T`` (4,4, T_world_camera;
    pinhole ``K``, image ``shape`` (h, w)): (indices (I,) of the points in the image and farther than
    ``MIN_DEPTH_M``, their flat pixel indices (I,), their optical depths (I,) m)."""
    h, w = shape
    q = transform_points(np.linalg.inv(T), np.asarray(points, np.float64))
    z = q[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.rint(K[0, 0] * q[:, 0] / z + K[0, 2])
        v = np.rint(K[1, 1] * q[:, 1] / z + K[1, 2])
    inside = np.flatnonzero((z > MIN_DEPTH_M) & (u >= 0) & (u < w) & (v >= 0) & (v < h))
    return inside, v[inside].astype(np.intp) * w + u[inside].astype(np.intp), z[inside]


def camera_seen_through(points: np.ndarray, T: np.ndarray, K: np.ndarray, shape: tuple, images,
                        margin: np.ndarray | float, min_fraction: float = 0.2) -> np.ndarray:
    """(N,) bool: map ``points`` (N,3, world) the camera at ``T`` (4,4, T_world_camera; pinhole ``K``,
    image ``shape`` (h, w)) sees *through* — in at least ``min_fraction`` of the depth ``images`` (an
    iterable of (h, w) float32 m, NaN = none) with a return at the point's pixel, that return lies
    more than ``margin`` (m, scalar or (h, w)) beyond the point. Free-space carving with the camera's
    rays: a LiDAR map keeps a person who walks along the LiDAR's line of sight (the scans that would
    see through the far end of the walk are the ones the person blocks), but from the camera's
    side those voxels are empty whenever the person is elsewhere; such map points must not explain
    the person's returns away."""
    h, w = shape
    inside, pix, zi = _map_pixels(points, T, K, shape)
    out = np.zeros(len(points), bool)
    if not len(inside):
        return out
    mg = np.broadcast_to(np.asarray(margin, np.float64), (h, w)).reshape(-1)[pix]
    through = np.zeros(len(inside), np.int32)
    seen = np.zeros(len(inside), np.int32)
    for D in images:
        d = D.reshape(-1)[pix]
        ok = np.isfinite(d)
        seen += ok
        through += ok & (d > zi + mg)
    out[inside] = (seen > 0) & (through >= np.maximum(1, min_fraction * seen))
    return out


def camera_swept(points: np.ndarray, T: np.ndarray, K: np.ndarray, shape: tuple, images,
                 static: np.ndarray) -> np.ndarray:
    """(N,) bool: map ``points`` (N,3, world) on pixels that something moving along the camera's line of
    sight covers in every frame (:func:`static_depth_of` leaves them without a ``static`` depth, (h, w)
    m, NaN, though at least half the depth ``images`` (a list of (h, w) float32 m, NaN = none, the frames
    of the static depth) have a return there), no farther than the pixel's farthest return. The camera
    (``T`` (4,4) T_world_camera, pinhole ``K``, image ``shape``) saw the returns there sweep through the
    depths up to the far end of the walk, so no static surface stands there; the LiDAR cannot see
    through the far end of a walk along its own line of sight either (the walker blocks those scans),
    so slam's map keeps the person there, and the camera cannot see through it
    (:func:`camera_seen_through`): the walker hides it in every frame. Such map points must not explain
    the person's returns away when they stand at that end."""
    out = np.zeros(len(points), bool)
    images = list(images)
    if not images:
        return out
    inside, pix, zi = _map_pixels(points, T, K, shape)
    open_ = ~np.isfinite(static.reshape(-1)[pix])
    inside, pix, zi = inside[open_], pix[open_], zi[open_]
    if not len(inside):
        return out
    samples = np.stack([D.reshape(-1)[pix] for D in images])         # (F, I)
    finite = np.isfinite(samples)
    cover = finite.sum(0) * 2 >= len(images)
    farthest = np.where(finite, samples, -np.inf).max(0)
    out[inside] = cover & (zi <= farthest)
    return out


def noise_coefficient(depth: np.ndarray, spread: np.ndarray) -> float | None:
    """``a`` (1/m) of the stereo noise model σ = a·z² (disparity noise): the median of spread/z² over the
    pixels with a ``depth`` (m) and a positive ``spread`` (m, one return's σ); None with fewer than
    ``MIN_MODEL_PIXELS`` such pixels."""
    z = np.asarray(depth, np.float64)
    s = np.asarray(spread, np.float64)
    ok = np.isfinite(z) & np.isfinite(s) & (z > MIN_DEPTH_M) & (s > 0)
    return float(np.median(s[ok] / z[ok] ** 2)) if ok.sum() >= MIN_MODEL_PIXELS else None


def depth_noise_model(depth: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Per-pixel depth noise σ (m) from the stereo model σ = a·z² (:func:`noise_coefficient`): smooth in
    z, unlike the per-pixel spread of a few frames (chance small spreads would get huge weights). Falls
    back to the spread where a is not known."""
    z = np.asarray(depth, np.float64)
    s = np.asarray(spread, np.float64)
    a = noise_coefficient(z, s)
    if a is None:
        return np.where(np.isfinite(s), s, UNKNOWN_SIGMA_M)
    return np.maximum(a * z ** 2, MIN_MODEL_SIGMA_M)


def _camera_points(scene, k: int) -> np.ndarray:
    """(N,3) float64 finite camera-frame points of frame ``k`` in front of the camera (z > 0)."""
    p = np.asarray(scene.ragged(CAMERA_POINTS, k), np.float64)
    return p[np.isfinite(p).all(1) & (p[:, 2] > 0)] if len(p) else p.reshape(0, 3)


def _camera_points_through(scene, T: np.ndarray, k: int) -> np.ndarray:
    """(N,3) float32: :func:`_camera_points` of frame ``k`` through ``T`` (4,4) T_world_camera."""
    return transform_points(T, _camera_points(scene, k)).astype(np.float32)


def camera_points_world(scene, k: int) -> np.ndarray:
    """(N,3) float32 camera points of frame ``k`` of a registered ``scene`` in the map frame (finite,
    in front of the camera): ``camera/points_world`` where register stored it, else the same values
    from ``camera/points`` through ``calib/T_world_camera``."""
    names = set(scene.arrays())
    if CAMERA_POINTS_WORLD in names:
        return np.asarray(scene.ragged(CAMERA_POINTS_WORLD, k))
    if CALIB_T_WORLD_CAMERA not in names:
        raise InputError(f"scene {scene.id!r} has no calib/T_world_camera (run holodata register first)")
    return _camera_points_through(scene, np.asarray(scene[CALIB_T_WORLD_CAMERA][...], np.float64), k)
