"""A scene's LiDAR scans: loaded whole (:func:`load_scans`) or streamed on a thread while odometry
runs (:func:`stream_scans`), and the data's own maximum range."""
from __future__ import annotations

import threading
import time

import numpy as np

from ...dataset.layout import LIDAR_POINT_TIME_NS, LIDAR_POINTS, LIDAR_RANGE, LIDAR_TIMESTAMP_NS, TIME_TIMESTAMP_NS
from ...errors import DatasetError
from ...progress import track
from .config import Scans

# kiss-icp's max range from the data: this percentile of the first scans' ranges (stray far returns
# aside) × RANGE_MARGIN, at least MIN_MAX_RANGE_M (a scan in a cupboard)
RANGE_PERCENTILE = 99.5
RANGE_MARGIN = 1.1
MIN_MAX_RANGE_M = 2.0


class _ScanSource:
    """The LiDAR arrays of a scene (module doc, 1.): ``stamps`` (T,) int64 scan stamps, ``has_t`` (per-point
    times present), ``grid`` (H, W) of ``lidar/range`` or None. Raises DatasetError without lidar/points."""

    def __init__(self, scene):
        names = set(scene.arrays())
        if LIDAR_POINTS not in names:
            raise DatasetError(f"{scene.ds.url}: scene {scene.id!r} has no lidar/points (slam needs LiDAR scans)")
        if LIDAR_TIMESTAMP_NS in names:
            self.stamps = np.asarray(scene[LIDAR_TIMESTAMP_NS][...], np.int64)
        elif TIME_TIMESTAMP_NS in names:
            self.stamps = np.asarray(scene[TIME_TIMESTAMP_NS][...], np.int64)
        else:
            raise DatasetError(f"{scene.ds.url}: scene {scene.id!r} has neither lidar/timestamp_ns nor time/timestamp_ns")
        self.scene = scene
        self.has_t = LIDAR_POINT_TIME_NS in names
        self.rng = scene[LIDAR_RANGE] if LIDAR_RANGE in names and len(scene[LIDAR_RANGE].shape) == 3 else None
        self.grid = tuple(int(x) for x in self.rng.shape[1:]) if self.rng is not None else None

    def candidates(self) -> np.ndarray:
        """Frames with a stamp that is set and differs from the previous one: the scans, unless one has
        fewer than 100 returns."""
        out, last = [], None
        for f, s in enumerate(self.stamps.tolist()):
            if s != 0 and s != last:
                out.append(f)
                last = s
        return np.asarray(out, np.int64)

    def read(self, quiet: bool = True, stop=None):
        """Yield (frame, stamp, points (N,3) float32, times (N,) float32 s or None, pixels (N,) int32 or
        None) of each scan in frame order (frames without a new stamp or with < 100 returns skipped);
        ``stop()`` True ends it early."""
        scene, stamps, T = self.scene, self.stamps, self.scene.n_frames
        pr = scene[LIDAR_POINTS]
        tr = scene[LIDAR_POINT_TIME_NS] if self.has_t else None
        rng = self.rng
        last = None
        rblock = None  # (first frame, end frame, (n,H,W) ranges): lidar/range read a shard at a time
        for f in track(range(T), total=T, description=f"slam {scene.id}: read scans", quiet=quiet):
            if stop is not None and stop():
                return
            s = int(stamps[f])
            if s == 0 or s == last:
                continue
            p = pr[f]   # sequential reads: one zarr read per shard (dataset.reader.Ragged)
            if p.dtype not in (np.float32, np.float64):
                p = p.astype(np.float64)
            good = _returns(p)  # organised clouds: (0,0,0) = no return
            n_good = int(np.count_nonzero(good))
            if n_good < 100:
                continue
            every = n_good == len(p)  # unorganised clouds (synth, most drivers): no copy by a mask
            pts = (p if every else p[good]).astype(np.float32, copy=False)  # float32: 400 scans x 65k points < 0.5 GB
            pix = None
            if rng is not None:
                if rblock is None or not rblock[0] <= f < rblock[1]:
                    step = int((getattr(rng, "shards", None) or rng.chunks)[0])
                    end = min((f // step + 1) * step, T)
                    rblock = (f, end, np.asarray(rng[f:end], np.float32))
                fin = np.flatnonzero(np.isfinite(rblock[2][f - rblock[0]]).reshape(-1))
                pix = (fin if every else fin[good]).astype(np.int32) if len(fin) == len(p) else None
            tm = None
            if tr is not None:
                t = np.asarray(tr[f], np.int64).reshape(-1)
                tm = (((t if every else t[good]) * 1e-9).astype(np.float32) if len(t) == len(p)
                      else np.zeros(n_good, np.float32))
            last = s
            yield f, s, pts, tm, pix


def load_scans(scene, quiet: bool = True) -> Scans:
    """Read the LiDAR scans of a dataset scene (see module doc). Raises DatasetError without any."""
    src = _ScanSource(scene)
    rows = list(src.read(quiet))
    if not rows:
        raise DatasetError(f"{scene.ds.url}: scene {scene.id!r} has no usable LiDAR scan (all empty)")
    rows.sort(key=lambda r: r[1])   # stable: by stamp
    return Scans(np.asarray([r[0] for r in rows], np.int64), np.asarray([r[1] for r in rows], np.int64),
                 [r[2] for r in rows], [r[3] for r in rows] if src.has_t else None, src.grid,
                 [r[4] for r in rows] if src.rng is not None else None)


class _StreamBroken(Exception):
    """A streamed scan list does not hold: a frame chosen by its stamp had < 100 returns (read again whole)."""


class _ScanFeed:
    """Fills a :class:`Scans` (frames and stamps known, arrays empty) from a daemon thread, scan by scan;
    :meth:`wait` blocks until scan i is there and re-raises the reader's error."""

    def __init__(self, scans: Scans, src: _ScanSource):
        self.scans, self.src = scans, src
        self.cond = threading.Condition()
        self.count, self.error, self.stopped = 0, None, False
        self.read_s = self.wait_s = 0.0
        self.thread = threading.Thread(target=self._run, name="holodata-slam-read", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        t0 = time.perf_counter()
        sc = self.scans
        try:
            # quiet: one progress display at a time (the refinement's)
            for k, (f, _, pts, tm, pix) in enumerate(self.src.read(True, stop=lambda: self.stopped)):
                if k >= len(sc.frames) or f != sc.frames[k]:
                    raise _StreamBroken(f"frame {f}")
                sc.points.append(pts)
                if sc.times is not None:
                    sc.times.append(tm)
                if sc.pixels is not None:
                    sc.pixels.append(pix)
                with self.cond:
                    self.count = k + 1
                    self.cond.notify_all()
            if self.count < len(sc.frames) and not self.stopped:
                raise _StreamBroken("fewer scans")
        except BaseException as e:  # noqa: BLE001 - handed to the consumer by wait()
            with self.cond:
                self.error = e
                self.cond.notify_all()
        self.read_s = time.perf_counter() - t0

    def wait(self, i: int) -> None:
        t0 = time.perf_counter()
        with self.cond:
            while self.count <= i and self.error is None:
                self.cond.wait()
        self.wait_s += time.perf_counter() - t0
        if self.count <= i:
            raise self.error

    def close(self) -> None:
        """Stop reading (after an error of the consumer) and wait for the thread."""
        self.stopped = True
        self.thread.join()


def stream_scans(scene) -> tuple[Scans, _ScanFeed] | None:
    """The scans of :func:`load_scans`, read by a background thread while the caller already works on the
    first ones (call ``feed.wait(i)`` before using scan i, ``feed.close()`` at the end). None when the
    scans' stamps are not increasing in frame order (then :func:`load_scans` sorts them). A frame that
    turns out to have < 100 returns makes ``wait`` raise :class:`_StreamBroken`: read with
    :func:`load_scans` then."""
    src = _ScanSource(scene)
    frames = src.candidates()
    if len(frames) == 0 or np.any(np.diff(src.stamps[frames]) <= 0):
        return None
    scans = Scans(frames, src.stamps[frames].copy(), [], [] if src.has_t else None, src.grid,
                  [] if src.rng is not None else None)
    return scans, _ScanFeed(scans, src)


def _returns(p: np.ndarray) -> np.ndarray:
    """(N,) bool: rows of (N,3) float ``p`` that are LiDAR returns — finite and not (0,0,0), the
    organised clouds' "no return" — from one squared norm per row (``isfinite(p).all(1) &
    (abs(p).sum(1) > 0)`` in one pass instead of four; a coordinate beyond ~1e19 m, whose square
    overflows float32, also counts as no return)."""
    r2 = np.einsum("ij,ij->i", p, p)
    return np.isfinite(r2) & (r2 > 0)


def data_max_range(scans: Scans, n: int = 10) -> float:
    """Max range for kiss-icp from the data: 99.5th percentile of the first ``n`` scans' ranges ×1.1."""
    r = np.concatenate([np.linalg.norm(p, axis=1) for p in scans.points[:n]])
    return float(max(MIN_MAX_RANGE_M, np.percentile(r, RANGE_PERCENTILE) * RANGE_MARGIN))


def _import_in_background(modules) -> threading.Thread:
    """Start importing ``modules`` in a daemon thread and return it (join it before use). kiss-icp and
    open3d are slow to import (open3d's visualization module pulls in dash and plotly;
    docs/design/performance.md), mostly Python; it runs while the scans are read, whose zarr decoding
    leaves the GIL free at times. An import error is left for the real import to raise."""
    import importlib

    def run():
        for m in modules:
            try:
                importlib.import_module(m)
            except Exception:  # noqa: BLE001 - raised again, with context, by the import that needs it
                return

    th = threading.Thread(target=run, name="holodata-slam-imports", daemon=True)
    th.start()
    return th
