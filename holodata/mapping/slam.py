"""``holodata slam``: LiDAR poses per scan, radar poses through the extrinsic, and the static mesh.

Pipeline (all poses ``T_world_sensor``, 4×4 float64, REP-103):

1. **Scans** (:func:`load_scans`): ``lidar/points`` (sensor frame) per frame, the per-point time
   ``lidar/point_time_ns`` (relative to the scan stamp) when present, the scan stamp
   ``lidar/timestamp_ns`` (``time/timestamp_ns`` for LiDAR-framed scenes). Frames without a scan
   and frames repeating the previous scan are skipped (their poses are interpolated). ``holodata
   slam`` reads them in a thread while the refinement (3.) already works on the first ones
   (:func:`stream_scans`).
2. **Odometry** (:func:`kiss_odometry`): kiss-icp 1.3's Python API configured for indoor
   corridors: voxel ``SlamConfig.voxel`` (0.1–0.2 m), max range from the data (99.5th percentile
   of the ranges of the first scans, +10 %), min range ``min_range``, deskew with the per-point
   time. kiss-icp reports the pose at the *last* point time of a scan (its deskew reference).
3. **Refinement** (:func:`refine`): scan-to-map point-to-plane ICP in open3d (Tukey kernel,
   coarse-to-fine correspondence distances), initial guesses from kiss-icp's relative motion,
   own deskew (constant twist over the scan from the neighbouring refined poses, reference time
   = the scan stamp, so ``pose/T_world_lidar[k]`` is the pose at ``lidar/timestamp_ns[k]``), and
   optionally (``global_pass``) a second pass against the whole map with moving points removed by
   the voxel background model. Where TF's LiDAR poses are a ground robot's on a level floor
   (:func:`level_tf_poses`) or the seeds are (``seed_poses="tf"``), height, roll and pitch are
   theirs and the ICP sets the other three. kiss-icp and the refinement run in one pass (:class:`KissStream`):
   a scan taken at rest (one point-to-plane Gauss-Newton step from the last refined pose against
   the map below ``still_check_m`` / ``still_check_deg``) holds that pose and is fed to neither
   kiss-icp nor ICP, so a robot that stands for most of a long recording costs little; on organised
   scans the check reuses the map correspondences of the last scan that passed it, pixel by pixel
   (:class:`_SameBeam`: no downsampling, no nearest-neighbour search).
   Measured on ``holodata synth`` corners (``benchmarks/slam.py``, 40 radar cycles, 64×1024,
   T/L/cross/oblique): bare kiss-icp ATE 3–12 cm (it lags while the robot accelerates from
   rest), refined ATE 0.3–0.8 cm, also with two people walking in the corridor.
4. **World frame**: when TF connects the LiDAR to a world frame (ingest's ``tf/T_world_lidar``;
   else its TF radar poses ``pose/T_world_radar`` with ``source: tf`` through the extrinsics, or the
   source recording's TF), the first scan TF covers is anchored at its TF pose, so the map lives in
   TF's world frame (where static camera TF and odometry live; TF may start after the LiDAR);
   else the world is the base frame at the first scan (``extrinsics.lidar`` = T_base_lidar), else
   the first LiDAR pose is the identity. ``pose/T_world_lidar`` says which (``world_frame``,
   ``anchor``).
5. **Radar poses**: ``T_world_radar(t) = T_world_lidar(t) · T_base_lidar⁻¹ · T_base_radar`` with
   ``T_world_lidar(t)`` interpolated (SLERP) at each frame time ``time/timestamp_ns``.

Outputs (written with the dataset writer, whole arrays, atomically): ``pose/T_world_lidar``
(T,4,4), ``pose/T_world_radar`` (T,4,4) when there is a radar or a radar extrinsic (replacing the
odometry poses ingest took from TF), ``mesh/vertices`` + ``mesh/faces`` (:func:`static_mesh`, :mod:`.mesh`;
the background model of its scans is built in a forked process beside the point accumulation) and
``map/points``, the static point map the mesh was reconstructed from (``holodata register``'s
target), scene
attribute ``slam`` (config, counts, timings, health figures). A TUM trajectory and a PLY are
optional exports.
"""
from __future__ import annotations

import contextlib
import functools
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..conventions import rotation_angle_deg, transform_directions, transform_points
from ..errors import DatasetError, InputError
from ..progress import track
from ..trajectory import Trajectory, write_tum


SEED_POSES = ("kiss-icp", "tf")


@dataclass(frozen=True)
class SlamConfig:
    """SLAM settings (metres, seconds).

    ``voxel``: kiss-icp map voxel (indoor: 0.1–0.2); ``max_range``: None = from the data;
    ``min_range``: drop returns closer than this (robot body); ``deskew``: use per-point times;
    ``refine``: open3d scan-to-map refinement after kiss-icp (False = bare kiss-icp poses);
    ``source_voxel``: scan downsampling for refinement ICP; ``map_voxel``: refinement map
    resolution (a scan adds to it only when the sensor moved ``map_keyframe_m`` or turned
    ``map_keyframe_deg`` since the last scan that did); ``icp_distances``: coarse-to-fine max correspondence distances; ``tukey_k``:
    robust kernel width as a multiple of each stage's distance; ``min_fitness``: a refined scan
    pose whose share of source points with a map correspondence (finest stage) is below this keeps
    kiss-icp's relative motion instead (counted in the health figures); ``global_pass``: second
    refinement pass against the whole (background-filtered) map (measured on a synth L corner:
    ATE 0.45 → 0.35 cm, mesh F unchanged, about the cost of the first pass; off by default); ``background_voxel`` /
    ``background_min_fraction``: the voxel background model (moving points out of the map
    and mesh); ``mesh``: build and store the static mesh from at most ``mesh_max_scans`` scans
    (every scan that moved a keyframe distance plus scans evenly spread in time, so that people
    walking while the robot stands still are still seen moving); ``still_m`` / ``still_deg``:
    when kiss-icp says the sensor moved less than this since the last ICP-refined scan, and one
    point-to-plane Gauss-Newton step of the scan from that scan's pose against the map is below
    ``still_check_m`` / ``still_check_deg`` (kiss-icp alone lags when the robot starts from rest),
    the robot is at rest: the scan holds that refined pose without ICP; ``same_beam``: on organised
    scans (``lidar/range``) that check reuses, beam by beam, the map planes found for the last scan
    that passed it (:class:`_SameBeam`: at most ``same_beam_points`` beams, bounds ``same_beam_scale``
    × the check's, at least ``same_beam_share`` of the returns near their plane; else the full check
    runs); ``icp_converged_m``: ICP
    stages stop when the inlier RMSE changes less than this between iterations; kiss-icp runs on the
    scan downsampled to ``kiss_input_voxel`` (its own first voxelisation is at voxel/2) with ICP
    convergence ``kiss_convergence`` (norm of the pose update) and at most ``kiss_max_iterations``
    (the kiss-icp defaults 1e-4 / 500 cost 4x more time on a robot at rest for a worse ATE: it
    only seeds the refinement). Measured on a 400-cycle L corner (64x512, robot at rest after 10
    s; ``benchmarks/slam.py``): slam 84 s -> 35 s at the same load, refined ATE 0.24 -> 0.21 cm.
    ``seed_poses``: what seeds the refinement's relative motion: "kiss-icp" (default) or "tf" — the
    recording's odometry/TF poses (:func:`guess_poses`) where the scene has them for every scan
    (kiss-icp otherwise); a mapping pass throttled to a few scans per second (0.3-0.4 m apart) is
    seeded better and cheaper by its wheel odometry than by kiss-icp's constant-velocity model.
    """

    voxel: float = 0.15
    max_range: float | None = None
    min_range: float = 0.3
    deskew: bool = True
    refine: bool = True
    source_voxel: float = 0.12
    map_voxel: float = 0.06
    icp_distances: tuple[float, ...] = (0.3, 0.1)
    icp_iterations: int = 10
    fine_source_voxel: float = 0.1
    fine_map_voxel: float = 0.04
    fine_distances: tuple[float, ...] = (0.1, 0.05)
    tukey_k: float = 1.0
    global_pass: bool = False
    min_fitness: float = 0.3
    map_keyframe_m: float = 0.05
    map_keyframe_deg: float = 2.0
    mesh_max_scans: int = 120
    still_m: float = 0.01
    still_deg: float = 0.2
    still_check_m: float = 0.003
    still_check_deg: float = 0.06
    same_beam: bool = True
    same_beam_points: int = 8192
    same_beam_scale: float = 1.0
    same_beam_share: float = 0.9
    kiss_convergence: float = 1e-3
    kiss_max_iterations: int = 50
    kiss_input_voxel: float = 0.075
    icp_converged_m: float = 1e-5
    background_voxel: float = 0.15
    background_min_fraction: float = 0.6
    mesh: bool = True
    seed_poses: str = "kiss-icp"

    def __post_init__(self):
        if self.seed_poses not in SEED_POSES:
            raise InputError(f"unknown slam seed_poses {self.seed_poses!r} (choose from {', '.join(SEED_POSES)})")
        if not 0.02 <= self.voxel <= 2.0:
            raise InputError(f"slam voxel must be in [0.02, 2] m, got {self.voxel}")
        if self.max_range is not None and not self.max_range > self.min_range:
            raise InputError(f"slam max_range ({self.max_range}) must exceed min_range ({self.min_range})")
        if not self.icp_distances or min(self.icp_distances) <= 0:
            raise InputError("slam icp_distances must be positive")

    def to_attrs(self) -> dict:
        d = asdict(self)
        d["icp_distances"] = list(self.icp_distances)
        return d


@dataclass
class Scans:
    """LiDAR scans of one scene. ``frames`` (S,) frame index of each scan; ``stamp_ns`` (S,) scan
    stamps (int64 ns); ``points`` list of (Ni,3) float32 sensor-frame points; ``times`` list of
    (Ni,) float32 seconds relative to the stamp, or None when the scene has no per-point time."""

    frames: np.ndarray
    stamp_ns: np.ndarray
    points: list
    times: list | None
    # organised scans (``lidar/range`` (T,H,W) whose finite pixels in row-major order are the rows of
    # ``lidar/points``): ``grid`` (H, W) and per scan the flat pixel index (Ni,) int32 of each point
    # (None for a scan whose point count does not match); None without lidar/range
    grid: tuple | None = None
    pixels: list | None = None

    def __len__(self) -> int:
        return len(self.frames)


@dataclass
class SlamResult:
    """``scene``; ``timestamp_ns`` (S,) scan stamps; ``T_world_lidar`` (T,4,4) per frame;
    ``T_world_radar`` (T,4,4) or None; ``scan_poses`` (S,4,4) refined; ``kiss_poses`` (S,4,4) bare
    kiss-icp (its own reference time ``kiss_stamp_ns``); ``mesh`` (vertices, faces) or None;
    ``summary`` dict (counts, timings, health)."""

    scene: str
    timestamp_ns: np.ndarray
    scan_poses: np.ndarray
    kiss_poses: np.ndarray
    kiss_stamp_ns: np.ndarray
    T_world_lidar: np.ndarray
    T_world_radar: np.ndarray | None
    mesh: tuple | None = None
    summary: dict = field(default_factory=dict)
    map_points: np.ndarray | None = None

    def trajectory(self) -> Trajectory:
        """Refined LiDAR trajectory at the scan stamps."""
        return Trajectory(self.timestamp_ns.copy(), self.scan_poses.copy())

    def kiss_trajectory(self) -> Trajectory | None:
        """Bare kiss-icp trajectory (its own reference times), None for a result read back from a dataset."""
        if self.kiss_poses is None:
            return None
        return Trajectory(self.kiss_stamp_ns.copy(), self.kiss_poses.copy())


# ----------------------------------------------------------------------------------------------
# scans

class _ScanSource:
    """The LiDAR arrays of a scene (module doc, 1.): ``stamps`` (T,) int64 scan stamps, ``has_t`` (per-point
    times present), ``grid`` (H, W) of ``lidar/range`` or None. Raises DatasetError without lidar/points."""

    def __init__(self, scene):
        names = set(scene.arrays())
        if "lidar/points" not in names:
            raise DatasetError(f"{scene.ds.url}: scene {scene.id!r} has no lidar/points (slam needs LiDAR scans)")
        if "lidar/timestamp_ns" in names:
            self.stamps = np.asarray(scene["lidar/timestamp_ns"][...], np.int64)
        elif "time/timestamp_ns" in names:
            self.stamps = np.asarray(scene["time/timestamp_ns"][...], np.int64)
        else:
            raise DatasetError(f"{scene.ds.url}: scene {scene.id!r} has neither lidar/timestamp_ns nor time/timestamp_ns")
        self.scene = scene
        self.has_t = "lidar/point_time_ns" in names
        self.rng = scene["lidar/range"] if "lidar/range" in names and len(scene["lidar/range"].shape) == 3 else None
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
        pr = scene["lidar/points"]
        tr = scene["lidar/point_time_ns"] if self.has_t else None
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
    return float(max(2.0, np.percentile(r, 99.5) * 1.1))


# ----------------------------------------------------------------------------------------------
# kiss-icp

class KissStream:
    """kiss-icp 1.3 odometry fed scan by scan on demand (see :func:`kiss_odometry` for the settings):
    :meth:`pose` registers scan ``i``; :meth:`hold` skips it (robot at rest: kiss-icp is not fed, its
    pose repeats). ``poses`` (S,4,4) (first = identity, LiDAR frame) and ``ref`` (S,) reference stamps
    (scan stamp + the scan's last point time when deskewing, kiss-icp's reference) fill as it goes."""

    def __init__(self, scans: Scans, cfg: SlamConfig, max_range: float):
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        kc = KISSConfig()
        kc.data.max_range = float(max_range)
        kc.data.min_range = float(cfg.min_range)
        self.use_t = cfg.deskew and scans.times is not None
        kc.data.deskew = bool(self.use_t)
        kc.mapping.voxel_size = float(cfg.voxel)
        kc.mapping.max_points_per_voxel = 20
        kc.adaptive_threshold.initial_threshold = 0.5
        kc.adaptive_threshold.min_motion_th = 0.02
        kc.registration.convergence_criterion = float(cfg.kiss_convergence)
        kc.registration.max_num_iterations = int(cfg.kiss_max_iterations)
        self.odo = KissICP(config=kc)
        self.scans, self.cfg = scans, cfg
        self.poses = np.zeros((len(scans), 4, 4))
        self.ref = scans.stamp_ns.copy()
        self.fed = 0
        self.seconds = 0.0

    def pose(self, i: int) -> np.ndarray:
        t0 = time.perf_counter()
        sc, cfg = self.scans, self.cfg
        p = sc.points[i]
        sel = _downsample_index(p, cfg.kiss_input_voxel) if cfg.kiss_input_voxel > 0 else slice(None)
        p = np.ascontiguousarray(p[sel], np.float64)
        if self.use_t:
            t = np.ascontiguousarray(sc.times[i][sel], np.float64)
            self.odo.register_frame(p, t)
            if np.ptp(t) > 0:
                self.ref[i] = sc.stamp_ns[i] + int(round(float(t.max()) * 1e9))
        else:
            self.odo.register_frame(p, np.zeros(len(p)))
        self.poses[i] = self.odo.last_pose
        self.fed += 1
        self.seconds += time.perf_counter() - t0
        return self.poses[i]

    def hold(self, i: int) -> np.ndarray:
        self.poses[i] = self.poses[i - 1]
        self.ref[i] = self.ref[i - 1] + (self.scans.stamp_ns[i] - self.scans.stamp_ns[i - 1])
        return self.poses[i]


class _Fixed:
    """Given initial poses in the :class:`KissStream` interface (every scan "fed"). ``seed``: they are
    odometry (TF) poses at the scan stamps, whose motion about each scan also deskews it in
    :func:`refine` (a throttled scan rate makes the last refined step a poor guess of it in turns)."""

    def __init__(self, poses: np.ndarray, seed: bool = False):
        self.seed = seed
        self.poses = poses
        self.fed = len(poses)
        self.seconds = 0.0

    def pose(self, i: int) -> np.ndarray:
        return self.poses[i]

    hold = pose


def kiss_odometry(scans: Scans, cfg: SlamConfig, max_range: float, quiet: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Bare kiss-icp odometry on every scan: (S,4,4) poses (first = identity, lidar frame) and their
    reference stamps (S,) ns (scan stamp + the scan's last point time when deskewing, kiss-icp's
    reference). Indoor settings: voxel ``cfg.voxel``, max range from the data, the scan downsampled
    to ``cfg.kiss_input_voxel``, ICP convergence ``cfg.kiss_convergence``."""
    ks = KissStream(scans, cfg, max_range)
    for i in track(range(len(scans)), total=len(scans), description="slam: kiss-icp", quiet=quiet):
        ks.pose(i)
    return ks.poses, ks.ref


# ----------------------------------------------------------------------------------------------
# SE(3) helpers

def twist(Ta: np.ndarray, Tb: np.ndarray, dt: float) -> np.ndarray:
    """Body twist per second (6,) [ω, v] taking pose ``Ta`` to ``Tb`` in ``dt`` s (first order)."""
    if dt <= 0:
        return np.zeros(6)
    D = np.linalg.inv(Ta) @ Tb
    return np.r_[Rotation.from_matrix(D[:3, :3]).as_rotvec(), D[:3, 3]] / dt


def deskew(points: np.ndarray, times: np.ndarray | None, xi: np.ndarray) -> np.ndarray:
    """Points (N,3) taken at ``times`` (N,) s relative to the reference, sensor moving with body twist
    ``xi`` [ω, v] per second → the same points in the sensor frame at the reference time:
    ``R(t)·p + t·v``, ``R(t)`` the rotation by ``t·|ω|`` about ω/|ω| (Rodrigues, per point). Returns
    ``points`` unchanged when all times are equal or the twist turns less than 1e-12 rad and moves
    less than 1 nm over the scan (the rounding noise of the twist between two equal held poses)."""
    if times is None or len(points) == 0 or np.ptp(times) == 0:
        return points
    t = np.asarray(times, np.float64)
    span = float(np.abs(t).max())
    w = float(np.linalg.norm(xi[:3]))
    if w * span < 1e-12 and float(np.linalg.norm(xi[3:])) * span < 1e-9:
        return points
    p = np.asarray(points, np.float64)
    out = p + t[:, None] * xi[None, 3:]
    if w > 0:
        k = xi[:3] / w
        c, s = np.cos(t * w), np.sin(t * w)
        K = np.zeros((4, 4))
        K[:3, :3] = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]]  # K @ p = k × p
        # (transform_points: p @ K.T went to OpenBLAS threads, 10 ms for a 64k-point scan)
        out += transform_points(K, p) * s[:, None] + ((p @ k) * (1.0 - c))[:, None] * k[None, :] - p * (1.0 - c)[:, None]
    return out


# ----------------------------------------------------------------------------------------------
# refinement: scan-to-map point-to-plane ICP (open3d)

def _o3d_cloud(points, normals=None):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    return pc


def scan_normals(points: np.ndarray, radius: float = 0.3, max_nn: int = 20):
    """Downsampled sensor-frame points → (points, normals facing the sensor) via open3d."""
    import open3d as o3d

    pc = _o3d_cloud(points)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    return np.asarray(pc.points), np.asarray(pc.normals)


def _downsample_index(points: np.ndarray, voxel: float) -> np.ndarray:
    """Sorted indices of one point per occupied ``voxel`` (the first)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    from .background import _keys, voxel_index

    _, idx = np.unique(_keys(voxel_index(points, voxel)), return_index=True)
    return np.sort(idx)


def downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Voxel-grid downsampling (one point per occupied voxel: the first)."""
    return points[_downsample_index(points, voxel)] if len(points) else points


class VoxelMap:
    """Point-to-plane target map: one point (+ normal) per ``voxel``, first come first kept."""

    def __init__(self, voxel: float):
        self.voxel = voxel
        self.keys = np.zeros(0, np.int64)
        self.points = np.zeros((0, 3))
        self.normals = np.zeros((0, 3))

    def _k(self, p):
        from .background import _keys, voxel_index

        return _keys(voxel_index(p, self.voxel))

    def add(self, points: np.ndarray, normals: np.ndarray) -> None:
        k = self._k(points)
        k, idx = np.unique(k, return_index=True)
        new = ~np.isin(k, self.keys, assume_unique=True)
        if not new.any():
            return
        idx = idx[new]
        self.keys = np.concatenate([self.keys, k[new]])
        self.points = np.concatenate([self.points, points[idx]])
        self.normals = np.concatenate([self.normals, normals[idx]])
        o = np.argsort(self.keys)
        self.keys, self.points, self.normals = self.keys[o], self.points[o], self.normals[o]

    def crop(self, center: np.ndarray, radius: float):
        m = np.einsum("ij,ij->i", self.points - center, self.points - center) <= radius * radius
        return self.points[m], self.normals[m]


class _TargetCache:
    """The refinement map cropped around a position (``radius``), as an open3d cloud (ICP target) and a
    scipy KD-tree (rest check), rebuilt only when the map grew or the position moved > 1 m."""

    def __init__(self, radius: float):
        self.radius = radius
        self.key = None
        self.pts = self.nrm = None
        self._cloud = self._tree = None

    def _crop(self, vmap: VoxelMap, center: np.ndarray) -> None:
        if self.key is not None and self.key[0] == len(vmap.points) and np.linalg.norm(center - self.key[1]) < 1.0:
            return
        self.pts, self.nrm = vmap.crop(center, self.radius)
        self.key = (len(vmap.points), np.array(center, np.float64))
        self._cloud = self._tree = None

    def cloud(self, vmap: VoxelMap, center: np.ndarray):
        self._crop(vmap, center)
        if self._cloud is None:
            self._cloud = _o3d_cloud(self.pts, self.nrm)
        return self._cloud

    def tree(self, vmap: VoxelMap, center: np.ndarray):
        from scipy.spatial import cKDTree

        self._crop(vmap, center)
        if self._tree is None:
            self._tree = cKDTree(self.pts)
        return self._tree, self.pts, self.nrm


def _at_rest(src: np.ndarray, target, T: np.ndarray, cfg: SlamConfig) -> bool:
    """One point-to-plane Gauss-Newton step (Tukey weights, correspondences within the finest ICP
    distance) of ``src`` (sensor frame) at pose ``T`` against ``target`` (tree, points, normals): True
    when the step is below ``still_check_m`` and ``still_check_deg`` and enough points correspond."""
    tree, tp, tn = target
    d = float(min(cfg.icp_distances))
    p = transform_points(T, src)
    dist, j = tree.query(p, k=1, distance_upper_bound=d)  # single thread: a few thousand points
    ok = np.isfinite(dist)
    if ok.mean() < cfg.min_fitness or ok.sum() < 30:
        return False
    dx = _gn_step(p[ok], tp[j[ok]], tn[j[ok]], T[:3, 3], d * cfg.tukey_k)
    return dx is not None and _small(dx, cfg.still_check_m, cfg.still_check_deg)


def _gn_step(p: np.ndarray, q: np.ndarray, n: np.ndarray, centre: np.ndarray, k: float) -> np.ndarray | None:
    """One point-to-plane Gauss-Newton step (6,) [rotation vector (rad), translation (m)] moving points
    ``p`` (M,3) onto the planes through ``q`` (M,3) with unit normals ``n`` (M,3), rotation about
    ``centre`` (3,) (the sensor: the translation is its shift), Tukey weights of width ``k`` (m).
    None when the system is ill-conditioned (cond > 1e8)."""
    r = np.einsum("ij,ij->i", p - q, n)
    w = np.where(np.abs(r) < k, (1 - (r / k) ** 2) ** 2, 0.0)
    J = np.concatenate([np.cross(p - centre, n), n], axis=1)
    H = (J * w[:, None]).T @ J
    if np.linalg.cond(H) > 1e8:
        return None
    return -np.linalg.solve(H, (J * (w * r)[:, None]).sum(0))


def _small(dx: np.ndarray, m: float, deg: float) -> bool:
    return bool(np.linalg.norm(dx[3:]) < m and np.degrees(np.linalg.norm(dx[:3])) < deg)


class _SameBeam:
    """The map rest check (:func:`_at_rest`) with its correspondences cached per beam (organised scans,
    :attr:`Scans.pixels`).

    Built from a scan ``a`` that passed the map check at the held pose ``T``: for at most
    ``max_points`` of its returns (evenly spread in row-major order) the map point nearest to the
    return (within the finest ICP distance) and its normal, in the sensor frame at ``T``, are kept per
    pixel. While the robot stands, a pixel keeps seeing the same surface, so a later scan ``i`` needs
    no nearest-neighbour search and no downsampling: its return in the same pixel goes with that
    pixel's map plane, and one point-to-plane Gauss-Newton step (Tukey width as in the map check) is
    its motion from ``T``. Scan ``i`` is at rest when that step is below ``scale`` ×
    ``still_check_m`` / ``still_check_deg`` (the map check's bounds by default), at least
    ``min_fitness`` of the cached pixels have a return in scan ``i`` and at least ``min_share`` of
    those returns lie within half the finest ICP distance of their plane; anything else goes to the
    map check. The share guards against a motion beyond the Tukey width: along a corridor only the
    walls facing the motion see it, their residuals drop out of the kernel and the step alone would
    look small (the map check relies on the previous scans not having moved for that); at rest
    94-96 % of the returns lie that close (400-cycle L corner), so ``min_share`` 0.9 sends any
    motion seen by more than ~5 % of the beams to the map check. Measured there: 339 of 373 scans at
    rest decided this way, the step's size distribution as the map check's (median 1.4 vs 1.5 mm)."""

    def __init__(self, points: np.ndarray, pixels: np.ndarray, target, T: np.ndarray, cfg: SlamConfig,
                 n_pixels: int, max_points: int, scale: float, min_share: float):
        tree, tp, tn = target
        self.d = float(min(cfg.icp_distances))
        self.k = self.d * cfg.tukey_k
        self.min_share, self.min_fitness = min_share, cfg.min_fitness
        self.m, self.deg = scale * cfg.still_check_m, scale * cfg.still_check_deg
        pick = np.unique(np.linspace(0, len(points) - 1, min(len(points), max_points)).round().astype(np.int64))
        dist, j = tree.query(transform_points(T, points[pick]), k=1, distance_upper_bound=self.d)
        ok = np.isfinite(dist)
        j = j[ok]
        R, t = T[:3, :3], T[:3, 3]
        self.q = (tp[j] - t) @ R                 # the map point and normal found for the beam, sensor frame
        self.n = tn[j] @ R
        self.pix = pixels[pick[ok]]
        self.slot = np.full(n_pixels, -1, np.int32)   # scratch: pixel -> row of the scan under test

    def __len__(self) -> int:
        return len(self.q)

    def at_rest(self, points: np.ndarray, pixels: np.ndarray, keep: np.ndarray) -> bool:
        """Scan ``points`` (N,3) sensor frame, their ``pixels`` (N,), ``keep`` (N,) in the range limits."""
        if len(self.q) < 30:
            return False
        self.slot[pixels[keep]] = np.flatnonzero(keep)
        row = self.slot[self.pix]
        self.slot[pixels[keep]] = -1
        has = row >= 0
        if has.sum() < max(30, self.min_fitness * len(self.q)):
            return False
        p = np.asarray(points[row[has]], np.float64)
        q, n = self.q[has], self.n[has]
        near = np.abs(np.einsum("ij,ij->i", p - q, n)) < 0.5 * self.d
        if near.sum() < self.min_share * len(p):
            return False
        dx = _gn_step(p, q, n, np.zeros(3), self.k)
        return dx is not None and _small(dx, self.m, self.deg)


def icp(src_pts: np.ndarray, target, init: np.ndarray, cfg: SlamConfig, distances=None):
    """Coarse-to-fine point-to-plane ICP of ``src_pts`` (sensor frame) onto ``target`` (open3d
    cloud with normals). Returns (T, fitness, inlier rmse) of the finest stage."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = _o3d_cloud(src_pts)
    T = init.copy()
    res = None
    for d in (distances or cfg.icp_distances):
        est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=float(d * cfg.tukey_k)))
        res = reg.registration_icp(src, target, float(d), T, est,
                                   reg.ICPConvergenceCriteria(1e-7, max(cfg.icp_converged_m, 1e-7), int(cfg.icp_iterations)))
        if len(res.correspondence_set) >= 30:
            T = np.asarray(res.transformation)
    return T, float(res.fitness), float(res.inlier_rmse)


def refine(scans: Scans, init, cfg: SlamConfig, max_range: float, quiet: bool = True, T0: np.ndarray | None = None,
           ready=None, vmap: "VoxelMap | None" = None, grow_map: bool = True,
           vertical: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Scan-to-map refinement (see module doc) of initial poses ``init``: (S,4,4) at the scan stamps,
    or a :class:`KissStream` asked for a scan's kiss-icp pose only when the robot is not at rest (its
    relative motion seeds the ICP; scans at rest are never fed to it). ``T0``: pose of the first scan
    (default ``init``'s); ``ready(i)``: called before scan i is used (scans still being read,
    :func:`stream_scans`); ``vmap``: start from this map (world frame) instead of an empty one, and
    with ``grow_map`` False never add the scans to it (localisation against a fixed map);
    ``vertical``: (S,4,4) world poses of a ground robot's level odometry (:func:`level_seeds`) whose
    height, roll and pitch the refined poses take (:func:`with_vertical_of`); level seeds give them
    when None. Returns the refined (S,4,4) poses and health figures (fitness, rmse per scan)."""
    S = len(scans)
    t_s = (scans.stamp_ns - scans.stamp_ns[0]).astype(np.float64) * 1e-9
    stream = _Fixed(np.asarray(init, np.float64)) if isinstance(init, np.ndarray) else init
    # odometry seeds (_Fixed(seed=True)): deskew with their motion about each scan, not the last step's
    seed_twist = twists_central(stream.poses, scans.stamp_ns) if getattr(stream, "seed", False) else None
    # planar seeds (wheel odometry on a level floor): height, roll and pitch follow them, not the ICP
    vertical_from = "tf" if vertical is not None else None
    if vertical is None and seed_twist is not None and level_seeds(stream.poses):
        vertical = (stream.poses[0] if T0 is None else T0) @ np.linalg.inv(stream.poses[0]) @ stream.poses
        vertical_from = "seeds"
    init = stream.poses
    poses = np.zeros((S, 4, 4))
    poses[0] = stream.pose(0)
    if T0 is not None:
        poses[0] = T0
    use_t = cfg.deskew and scans.times is not None
    vmap = vmap if vmap is not None else VoxelMap(cfg.map_voxel)
    fit = np.zeros(S)
    rmse = np.zeros(S)
    xi_prev = np.zeros(6)
    fallbacks = 0
    last_key, keyframes, still, anchor = None, 0, 0, 0
    beams = cfg.same_beam and scans.pixels is not None and scans.grid is not None
    n_pix = int(np.prod(scans.grid)) if beams else 0
    same, same_beam = None, 0   # _SameBeam reference of the current anchor pose, scans it found at rest
    target = _TargetCache(max_range + 1.0)
    def in_range(p):   # (N,) bool: returns within [min_range, max_range] of the sensor
        r2 = np.einsum("ij,ij->i", p, p)
        return (r2 >= cfg.min_range ** 2) & (r2 <= max_range ** 2)

    def ranged(p, t):
        p = np.asarray(p, np.float64)
        keep = in_range(p)
        return p[keep], (t[keep] if t is not None else None)

    for i in track(range(S), total=S, description="slam: refine (scan-to-map)", quiet=quiet):
        if ready is not None:
            ready(i)
        xi = xi_prev if i > 0 else np.zeros(6)
        if seed_twist is not None:
            xi = seed_twist[i]
        raw_t = scans.times[i] if use_t else None
        if (i > 0 and not _moved(poses[i - 2] if i > 1 else poses[0], poses[i - 1], cfg.still_m * 5, cfg.still_deg * 5)
                and (not isinstance(stream, _Fixed) or not _moved(init[anchor], init[i], cfg.still_m, cfg.still_deg))):
            at_rest = False
            pix = scans.pixels[i] if beams else None
            if same is not None and pix is not None:
                # beam by beam against the last scan that passed the map check at this pose (_SameBeam)
                at_rest = same.at_rest(scans.points[i], pix, in_range(scans.points[i]))
                same_beam += at_rest
            if not at_rest:
                # rest check on the ICP source voxels (no deskew: the robot was at rest or nearly)
                rest, _ = ranged(scans.points[i][_downsample_index(scans.points[i], cfg.source_voxel)], None)
                tgt_tree = target.tree(vmap, poses[anchor][:3, 3])
                at_rest = _at_rest(rest, tgt_tree, poses[anchor], cfg)
                if at_rest and pix is not None:
                    p = np.asarray(scans.points[i], np.float64)
                    keep = in_range(p)
                    same = _SameBeam(p[keep], pix[keep], tgt_tree, poses[anchor], cfg, n_pix, cfg.same_beam_points,
                                     cfg.same_beam_scale, cfg.same_beam_share)
        else:
            at_rest = False
        if not at_rest:
            pts, tm = ranged(scans.points[i], raw_t)
            # deskew only the downsampled points that are used (ICP source, map keyframe)
            i_src = _downsample_index(pts, cfg.source_voxel)
            src = deskew(pts[i_src], tm[i_src], xi) if use_t else pts[i_src]
        if i == 0:
            T = poses[0]
            f, e = 1.0, 0.0
        elif at_rest:
            # at rest: the last step was small, one point-to-plane Gauss-Newton step of this scan from the
            # last refined pose against the map is below still_check_m / still_check_deg (and, with given
            # initial poses, they moved less than still_m since) -> hold that pose; no ICP, no kiss-icp
            stream.hold(i)
            T, f, e = poses[anchor].copy(), float(fit[anchor]), float(rmse[anchor])
            still += 1
            xi = np.zeros(6)
        else:
            guess = poses[i - 1] @ (np.linalg.inv(init[i - 1]) @ stream.pose(i))
            tgt = target.cloud(vmap, guess[:3, 3])
            T, f, e = icp(src, tgt, guess, cfg)
            if f < cfg.min_fitness:  # too few scan points near the map (sparse, far, outdoor): trust kiss-icp
                T = guess
                fallbacks += 1
            if vertical is not None:
                T = with_vertical_of(T, vertical[i])
            xi = twist(poses[i - 1], T, t_s[i] - t_s[i - 1]) if seed_twist is None else seed_twist[i]
            anchor = i
            same = None
        poses[i] = T
        fit[i], rmse[i] = f, e
        xi_prev = xi
        if grow_map and not at_rest and (last_key is None or _moved(last_key, T, cfg.map_keyframe_m, cfg.map_keyframe_deg)):
            i_map = _downsample_index(pts, cfg.map_voxel)
            dp, dn = scan_normals(deskew(pts[i_map], tm[i_map], xi) if use_t else pts[i_map])
            vmap.add(transform_points(T, dp), transform_directions(T, dn))
            last_key = T
            keyframes += 1
    health = {"fitness": fit, "rmse": rmse, "map_points": int(len(vmap.points)), "kiss_fallbacks": fallbacks,
              "vertical_from": vertical_from,
              "map_keyframes": keyframes, "still_scans": still, "still_same_beam": same_beam,
              "kiss_scans": int(stream.fed),
              "kiss_s": float(stream.seconds)}
    return poses, health


def level_seeds(poses: np.ndarray, height_m: float = 0.01, tilt_deg: float = 0.2) -> bool:
    """True when seed poses (S,4,4) are those of a ground robot's odometry on a level floor: their
    height varies by less than ``height_m`` and every tilt (roll/pitch) relative to the first is below
    ``tilt_deg``. Such odometry pins height, roll and pitch better than scan-to-map ICP on a sparse,
    throttled LiDAR (a synth mapping pass at 2 scans/s drifted 5 cm in height over 6 m), so
    :func:`refine` then takes those three from the seeds (:func:`with_vertical_of`)."""
    P = np.asarray(poses, np.float64)
    if len(P) < 2 or np.ptp(P[:, 2, 3]) >= height_m:
        return False
    z0 = P[0, :3, 2]
    return bool(np.degrees(np.arccos(np.clip(P[:, :3, 2] @ z0, -1, 1))).max() < tilt_deg)


def with_vertical_of(T: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``T`` (4,4) with the height, roll and pitch of ``G`` (4,4): the heading (yaw) and the planar
    position of ``T``, the rest of ``G``."""
    from ..conventions import yaw_rad

    def rz(a):
        c, s_ = np.cos(a), np.sin(a)
        return np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])

    out = G.copy()
    out[:3, :3] = rz(yaw_rad(T) - yaw_rad(G)) @ G[:3, :3]
    out[:2, 3] = T[:2, 3]
    return out


def _moved(Ta: np.ndarray, Tb: np.ndarray, dist_m: float, angle_deg: float) -> bool:
    D = np.linalg.inv(Ta) @ Tb
    return bool(np.linalg.norm(D[:3, 3]) >= dist_m or rotation_angle_deg(D) >= angle_deg)


def mesh_scan_subset(poses: np.ndarray, max_n: int, dist_m: float = 0.05, angle_deg: float = 2.0) -> np.ndarray:
    """Indices of at most ``max_n`` scans: keyframes by motion plus scans evenly spread in time."""
    S = len(poses)
    if S <= max_n:
        return np.arange(S)
    key, last = [0], poses[0]
    for i in range(1, S):
        if _moved(last, poses[i], dist_m, angle_deg):
            key.append(i)
            last = poses[i]
    idx = np.union1d(np.asarray(key), np.linspace(0, S - 1, max(2, max_n // 2)).round().astype(int))
    if len(idx) > max_n:
        idx = idx[np.linspace(0, len(idx) - 1, max_n).round().astype(int)]
    return np.unique(idx)


def twists_central(poses: np.ndarray, stamp_ns: np.ndarray) -> np.ndarray:
    """(S,6) body twists per scan from the neighbouring poses (central difference)."""
    S = len(poses)
    t = (stamp_ns - stamp_ns[0]).astype(np.float64) * 1e-9
    out = np.zeros((S, 6))
    for i in range(S):
        a, b = max(0, i - 1), min(S - 1, i + 1)
        if b > a:
            out[i] = twist(poses[a], poses[b], t[b] - t[a])
    return out


def deskewed_scans(scans: Scans, poses: np.ndarray, cfg: SlamConfig, max_range: float, indices=None
                   ) -> list[np.ndarray]:
    """Per scan (or per scan of ``indices``): range-filtered points deskewed to the scan stamp with
    central-difference twists."""
    xis = twists_central(poses, scans.stamp_ns)
    use_t = cfg.deskew and scans.times is not None
    out = []
    for i in (range(len(scans)) if indices is None else indices):
        pts = np.asarray(scans.points[i], np.float64)
        r = np.linalg.norm(pts, axis=1)
        keep = (r >= cfg.min_range) & (r <= max_range)
        out.append(deskew(pts[keep], scans.times[i][keep] if use_t else None, xis[i]))
    return out


def global_refine(scans: Scans, poses: np.ndarray, cfg: SlamConfig, max_range: float, quiet: bool = True,
                  background=None) -> tuple[np.ndarray, dict]:
    """Second pass: every scan (deskewed with central-difference twists) against the whole map built
    from all scans at ``poses``, moving points removed by ``background`` (a VoxelBackground; built here
    when None). Returns refined poses and health figures."""
    import open3d as o3d

    from .background import VoxelBackground

    desk = deskewed_scans(scans, poses, cfg, max_range)
    ds = [downsample(p, cfg.fine_map_voxel) for p in desk]
    world = [transform_points(T, p) for T, p in zip(poses, ds)]
    if background is None:
        background = VoxelBackground.build(world, voxel=cfg.background_voxel, min_fraction=cfg.background_min_fraction,
                                           origins=poses[:, :3, 3])
    allp = np.concatenate([w[background.contains(w, tolerance=0)] for w in world])
    allp = downsample(allp, cfg.fine_map_voxel)
    pc = _o3d_cloud(allp)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.25, max_nn=30))
    # orient normals towards the nearest sensor position
    centers = poses[:, :3, 3]
    from scipy.spatial import cKDTree

    _, ci = cKDTree(centers).query(allp)
    nrm = np.asarray(pc.normals)
    flip = np.einsum("ij,ij->i", nrm, centers[ci] - allp) < 0
    nrm[flip] *= -1
    pc.normals = o3d.utility.Vector3dVector(nrm)
    out = poses.copy()
    fit = np.zeros(len(poses))
    rmse = np.zeros(len(poses))
    for i in track(range(len(poses)), total=len(poses), description="slam: refine (global map)", quiet=quiet):
        src = downsample(desk[i], cfg.fine_source_voxel)
        out[i], fit[i], rmse[i] = icp(src, pc, poses[i], cfg, cfg.fine_distances)
    return out, {"fitness": fit, "rmse": rmse, "map_points": int(len(allp)), "background": background}


# ----------------------------------------------------------------------------------------------
# world frame, per-frame poses, static mesh

def _attr_T(d, key) -> np.ndarray | None:
    v = (d or {}).get(key)
    if v is None:
        return None
    T = np.asarray(v, np.float64)
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None


@functools.lru_cache(maxsize=4)
def _recording_tf(path: str, tf_topics: tuple, static: tuple, mtime_ns: int, size: int):
    """The TF buffer of a recording's ``tf_topics`` (``static`` ones as static), read once per
    (path, mtime, size); None when it does not read."""
    from ..errors import HolodataError
    from ..readers import open_recording
    from ..readers.tf import TransformBuffer

    tf = TransformBuffer()
    try:
        with open_recording(path) as rec:
            for topic, _, msg in rec.messages(list(tf_topics)):
                tf.add_message(msg, static=topic in static)
    except (HolodataError, OSError, ValueError, AttributeError):
        return None
    return tf


def recording_tf_poses(scene, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, str] | None:
    """TF poses T_world_lidar (S,4,4) of the scene's LiDAR frame at ``stamps_ns`` (S,), read from the
    scene's source recording (``source.recording``, its ``ingest.topics`` TF topics), with (S,) bool
    "covered" and the world frame's name; None when the recording is gone, has no TF or TF does not
    connect the LiDAR frame to a world frame. ingest stores TF poses only for radar frames
    (``pose/T_world_radar``), so a LiDAR-only scene (a mapping pass) finds its TF world this way."""
    from ..readers.tf import WORLD_FRAMES

    attrs = scene.attrs
    path = (attrs.get("source") or {}).get("recording")
    topics = (attrs.get("ingest") or {}).get("topics") or {}
    frame = ((attrs.get("sensors") or {}).get("lidar") or {}).get("frame_id")
    tf_topics = list(topics.get("tf") or []) + list(topics.get("tf_static") or [])
    if not path or not frame or not tf_topics or not Path(path).exists():
        return None
    st = Path(path).stat()
    tf = _recording_tf(str(path), tuple(tf_topics), tuple(topics.get("tf_static") or []), st.st_mtime_ns, st.st_size)
    if tf is None:
        return None
    world = topics.get("world_frame") or next((w for w in WORLD_FRAMES if w in tf.frames and
                                               tf._path(w, frame, False) is not None), None)
    if world is None:
        return None
    res = tf.lookup_many(world, frame, np.asarray(stamps_ns, np.int64))
    if res is None:
        return None
    return np.asarray(res[0], np.float64), np.asarray(res[1], bool), str(world)


def tf_lidar_poses(scene, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, str] | None:
    """TF poses T_world_lidar (S,4,4) at ``stamps_ns`` (S,) from ingest's ``tf/T_world_lidar`` (the
    LiDAR frame's TF pose at each frame's scan, NaN where TF does not cover it), with (S,) bool
    "covered" (within the covered frames' time span) and the world frame's name; None without it."""
    if "tf/T_world_lidar" not in set(scene.arrays()):
        return None
    a = scene["tf/T_world_lidar"]
    P = np.asarray(a[...], np.float64)
    name = "lidar/timestamp_ns" if "lidar/timestamp_ns" in set(scene.arrays()) else "time/timestamp_ns"
    t = np.asarray(scene[name][...], np.int64)
    ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1) & (t > 0)
    if not ok.any():
        return None
    t, P = t[ok], P[ok]
    order = np.argsort(t, kind="stable")
    t, P = t[order], P[order]
    keep = np.r_[True, np.diff(t) > 0]
    t, P = t[keep], P[keep]
    s = np.asarray(stamps_ns, np.int64)
    cov = (s >= t[0]) & (s <= t[-1])
    out = Trajectory(t, P).interpolate(np.clip(s, t[0], t[-1])) if len(t) > 1 else np.repeat(P[:1], len(s), 0)
    return out, cov, str(dict(a.attrs).get("world_frame"))


def level_tf_poses(scene, stamps_ns: np.ndarray) -> np.ndarray | None:
    """ingest's TF LiDAR poses (:func:`tf_lidar_poses`, (S,4,4) at ``stamps_ns``, held at the first
    and last covered pose outside TF's span) when they are a ground robot's on a level floor
    (:func:`level_seeds` over the covered scans), else None. A planar TF tree (``map → odom`` from a
    2D localiser, ``odom → base_link`` from wheel odometry) fixes the LiDAR's height, roll and pitch
    without drift — the three degrees of freedom a ground robot's floor fixes (LeGO-LOAM, Shan &
    Englot, IROS 2018, §III-D, solves them from ground points apart from the other three) — where
    scan-to-map ICP on a sparse LiDAR drifts in roll and pitch as the map grows (docs/design/slam.md);
    the kiss-icp-seeded :func:`refine` takes those three from them (``health.sequential.vertical_from``)."""
    rt = tf_lidar_poses(scene, stamps_ns)
    if rt is None or rt[1].sum() < 2 or not level_seeds(rt[0][rt[1]]):
        return None
    return rt[0]


def tf_agreement(scene, stamps_ns: np.ndarray, poses: np.ndarray) -> dict | None:
    """How far slam's LiDAR poses (S,4,4 at ``stamps_ns``) lie from TF's (:func:`tf_lidar_poses`) over
    the scans TF covers: {"scans", "position_max_m", "position_last_m", "yaw_max_deg"}; None without TF
    poses. Both drift away from the anchor scan (odometry in TF; no loop closure in slam), so this
    bounds neither alone, but a map whose world is TF's world is only as close to TF's as this says,
    far from the anchor (a camera pose from TF is a guess good to about that much there)."""
    from ..conventions import yaw_rad

    rt = tf_lidar_poses(scene, stamps_ns)
    if rt is None or not rt[1].any():
        return None
    P, Q = np.asarray(poses, np.float64)[rt[1]], rt[0][rt[1]]
    gap = np.linalg.norm(P[:, :3, 3] - Q[:, :3, 3], axis=1)
    dyaw = np.array([np.degrees(abs(np.angle(np.exp(1j * (yaw_rad(a) - yaw_rad(b)))))) for a, b in zip(P, Q)])
    return {"scans": int(rt[1].sum()), "position_max_m": round(float(gap.max()), 4),
            "position_last_m": round(float(gap[-1]), 4), "yaw_max_deg": round(float(dyaw.max()), 3)}


def anchor_pose(scene, stamps_ns: np.ndarray) -> tuple[np.ndarray, int, dict]:
    """The world pose T_world_lidar of one scan, that scan's index into ``stamps_ns`` (the scans'
    stamps, (S,)) and how it was chosen (see module doc, 4.): the first scan TF covers, from ingest's
    ``tf/T_world_lidar``, else ingest's TF radar poses through the extrinsics, else the source
    recording's TF; else the base frame (``extrinsics.lidar``) or the LiDAR frame at the first scan."""
    stamps_ns = np.asarray(stamps_ns, np.int64).reshape(-1)
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    prev = (scene.attrs.get("slam") or {}).get("anchor")
    names = set(scene.arrays())
    for src, res in (("tf/T_world_lidar", lambda: tf_lidar_poses(scene, stamps_ns)),
                     ("TF of the source recording", lambda: None if "pose/T_world_radar" in names
                      else recording_tf_poses(scene, stamps_ns))):
        r = res()
        if r is not None and r[1].any():
            j = int(np.argmax(r[1]))
            return r[0][j], j, {"kind": "tf", "world_frame": r[2], "via": src, "scan": j}
    if "pose/T_world_radar" in names and T_bl is not None and T_br is not None:
        pa = scene["pose/T_world_radar"]
        src = dict(pa.attrs).get("source")
        if src == "tf":
            P = np.asarray(pa[...], np.float64)
            t = np.asarray(scene["time/timestamp_ns"][...], np.int64)
            ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
            if ok.sum() >= 1:
                T_wr = Trajectory(t[ok], P[ok]).interpolate(stamps_ns[:1])[0]
                return T_wr @ np.linalg.inv(T_br) @ T_bl, 0, {"kind": "tf", "world_frame": dict(pa.attrs).get("world_frame")}
    if prev and prev.get("kind") == "tf" and prev.get("T_world_lidar0") is not None:
        return np.asarray(prev["T_world_lidar0"], np.float64), 0, {"kind": "tf", "world_frame": prev.get("world_frame")}
    if T_bl is not None:
        return T_bl, 0, {"kind": "base", "world_frame": "base frame at the first scan"}
    return np.eye(4), 0, {"kind": "lidar", "world_frame": "LiDAR frame at the first scan"}


def frame_poses(scene, scans: Scans, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """Per-frame (T,4,4) T_world_lidar at each frame's LiDAR stamp (frame time when it has none) and
    T_world_radar at the frame time through the extrinsic (None without one)."""
    names = set(scene.arrays())
    ft = np.asarray(scene["time/timestamp_ns"][...], np.int64) if "time/timestamp_ns" in names else None
    lt = np.asarray(scene["lidar/timestamp_ns"][...], np.int64) if "lidar/timestamp_ns" in names else None
    if ft is None:
        ft = lt
    t_l = np.where(lt > 0, lt, ft) if lt is not None else ft
    traj = Trajectory(scans.stamp_ns, poses)
    Tl = traj.interpolate(t_l)
    outside = int(((ft < scans.stamp_ns[0] - 1) | (ft > scans.stamp_ns[-1] + 1)).sum())
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    info = {"frames_outside_scans": outside}
    Tr = None
    if T_br is not None:
        T_lr = (np.linalg.inv(T_bl) if T_bl is not None else np.eye(4)) @ T_br
        Tr = traj.interpolate(ft) @ T_lr
        info["T_lidar_radar"] = T_lr.tolist()
    elif scene.attrs.get("frame_sensor") == "radar":
        info["warning"] = "no radar extrinsic in scene attrs; pose/T_world_radar not written by slam"
    return Tl, Tr, info


def _mesh_background(world: list, origins: np.ndarray, cfg: SlamConfig):
    """The voxel background model of the mesh scans ``world`` (list of (Ni,3) deskewed world points)
    seen from ``origins`` (S,3), downsampled to ``fine_map_voxel``: numpy and scipy only, so it can run
    in a forked process."""
    from .background import VoxelBackground

    return VoxelBackground.build([downsample(w, cfg.fine_map_voxel) for w in world], voxel=cfg.background_voxel,
                                 min_fraction=cfg.background_min_fraction, origins=origins)


@dataclass
class StaticMap:
    """The static scene :func:`static_mesh` makes: the mesh ``vertices`` (V,3) / ``faces`` (F,3), the
    ``points`` (M,3) float64 m it was reconstructed from (world frame; the scans' static returns
    averaged per ``MeshConfig.voxel`` cell, moving ones removed: the map ``holodata register``
    registers the camera to), ``info`` (mesh figures) and the voxel ``background`` model used."""

    vertices: np.ndarray
    faces: np.ndarray
    points: np.ndarray
    info: dict
    background: object


def static_mesh(scans: Scans, poses: np.ndarray, cfg: SlamConfig, max_range: float, mesh_cfg=None, background=None,
                quiet: bool = True) -> StaticMap:
    """Mesh of the static scene from the scans at ``poses`` (world frame), with its point cloud.

    Without a ``background`` its model is built in a forked process while this one accumulates the
    points split by background voxel (:class:`~.mesh.PointAccumulator` ``split``), whose moving ones
    are dropped once the model is there: the same cloud as filtering each scan first."""
    from ..parallel import cpus, fork_call
    from .mesh import MeshConfig, PointAccumulator, build_mesh

    mesh_cfg = mesh_cfg or MeshConfig()
    sub = mesh_scan_subset(poses, cfg.mesh_max_scans, cfg.map_keyframe_m, cfg.map_keyframe_deg)
    P = poses[sub]
    # each scan deskewed and moved to the world once, for both the background model and the cloud
    world = [transform_points(T, p) for T, p in zip(P, deskewed_scans(scans, poses, cfg, max_range, sub))]
    model = None
    if background is None:
        model = fork_call(_mesh_background, world, P[:, :3, 3], cfg, label="slam: mesh background model",
                          enabled=cpus() > 1)
    acc = PointAccumulator(mesh_cfg.voxel, split=cfg.background_voxel if background is None else background.voxel)
    try:
        for T, w in track(list(zip(P, world)), total=len(P), description="slam: static points", quiet=quiet):
            acc.add(w, T[:3, 3])
    except BaseException:
        if model is not None:
            with contextlib.suppress(Exception):
                model()   # reap the worker before raising
        raise
    del world
    if model is not None:
        background = model()
    removed = acc.drop_split_cells(lambda centres: ~background.contains(centres, tolerance=0))
    pts, view, _ = acc.cloud()
    v, f, info = build_mesh(pts, view, mesh_cfg, sensor_xyz=P[:, :3, 3])
    info["dynamic_points_removed"] = removed
    info["scans_used"] = int(len(sub))
    return StaticMap(v, f, pts, info, background)


# ----------------------------------------------------------------------------------------------
# entry points

def _import_in_background(modules) -> threading.Thread:
    """Start importing ``modules`` in a daemon thread and return it (join it before use). kiss-icp and
    open3d take ~1 s CPU to import (open3d's visualization module pulls in dash and plotly), mostly
    Python; it runs while the scans are read, whose zarr decoding leaves the GIL free at times. An
    import error is left for the real import to raise."""
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


def _fingerprint(scene, cfg: SlamConfig, mesh_cfg) -> str:
    import hashlib
    import json

    h = hashlib.sha256(json.dumps({"slam": cfg.to_attrs(), "mesh": mesh_cfg.to_attrs() if mesh_cfg else None},
                                  sort_keys=True).encode())
    for name in ("lidar/points", "lidar/timestamp_ns", "time/timestamp_ns"):
        if name in scene:
            node = scene.nodes()[name][1]
            h.update(json.dumps(node.get("attributes", {}).get("holodata", {}).get("shards"), sort_keys=True).encode())
    return h.hexdigest()[:16]


def _odometry(scene, scans: Scans, config: SlamConfig, health: dict, timings: dict, feed, quiet: bool):
    """Poses of ``scans`` (module doc, 2.-4.): (max range, T0 the first scan's world pose, anchor info,
    refined poses (S,4,4), kiss-icp poses (S,4,4) in the world frame, their reference stamps (S,),
    the global pass' background model or None). Fills ``health`` and ``timings``; ``feed``: the
    :class:`_ScanFeed` of streamed scans (None: all read)."""
    ready = feed.wait if feed is not None else None
    if ready is not None:
        ready(min(len(scans), 10) - 1)   # data_max_range
    max_range = float(config.max_range or data_max_range(scans))
    T_a, j_a, anchor = anchor_pose(scene, scans.stamp_ns)
    T0 = T_a     # scan 0 seeded at the anchor scan's pose; the trajectory is moved onto it below
    background = None
    guess = None
    if config.refine and len(scans) > 1 and config.seed_poses == "tf":
        if ready is not None:
            ready(len(scans) - 1)
        guess, health["seed_poses"] = guess_poses(scene, scans)
    vertical = level_tf_poses(scene, scans.stamp_ns) if config.refine and guess is None else None
    if config.refine and len(scans) > 1:
        # kiss-icp and the refinement in one pass: kiss-icp is fed only the scans where the robot moves
        t0 = time.perf_counter()
        ks = KissStream(scans, config, max_range) if guess is None else _Fixed(guess, seed=True)
        poses, h1 = refine(scans, ks, config, max_range, quiet=quiet, T0=T0, ready=ready, vertical=vertical)
        K, kref = ks.poses, (ks.ref if guess is None else scans.stamp_ns.copy())
        timings["kiss_icp_s"] = h1["kiss_s"]
        timings["refine_s"] = time.perf_counter() - t0 - h1["kiss_s"]
        health["sequential"] = {"fitness_min": float(h1["fitness"][1:].min()), "fitness_mean": float(h1["fitness"][1:].mean()),
                                "rmse_max_m": float(h1["rmse"][1:].max()), "kiss_fallbacks": h1["kiss_fallbacks"],
                                "still_scans": h1["still_scans"], "still_same_beam": h1["still_same_beam"],
                                "kiss_scans": h1["kiss_scans"], "vertical_from": h1["vertical_from"],
                                "map_keyframes": h1["map_keyframes"]}
        K = (T0 @ np.linalg.inv(K[0])) @ K  # kiss-icp's poses in the world frame (module doc, 4.)
        if config.global_pass:
            t0 = time.perf_counter()
            poses, h2 = global_refine(scans, poses, config, max_range, quiet=quiet)
            timings["global_refine_s"] = time.perf_counter() - t0
            background = h2["background"]
            poses = (T0 @ np.linalg.inv(poses[0])) @ poses  # keep the world frame (the anchor) exact
            health["global"] = {"fitness_min": float(h2["fitness"].min()), "fitness_mean": float(h2["fitness"].mean()),
                                "rmse_max_m": float(h2["rmse"].max()), "rmse_mean_m": float(h2["rmse"].mean()),
                                "map_points": h2["map_points"]}
    else:
        if ready is not None:
            ready(len(scans) - 1)
        t0 = time.perf_counter()
        K, kref = kiss_odometry(scans, config, max_range, quiet=quiet)
        timings["kiss_icp_s"] = time.perf_counter() - t0
        K = (T0 @ np.linalg.inv(K[0])) @ K  # the world frame (module doc, 4.)
        poses = Trajectory(kref, K).interpolate(scans.stamp_ns) if len(scans) > 1 else K.copy()
    if j_a:   # anchored at a later scan (the first TF covers): that scan sits at its TF pose
        A = T_a @ np.linalg.inv(poses[j_a])
        poses, K = A @ poses, A @ K
    T0 = poses[0].copy()
    anchor["T_world_lidar0"] = T0.tolist()
    return max_range, T0, anchor, poses, K, kref, background


def slam_scene(dataset_url, scene_id: str | None = None, *, config: SlamConfig = SlamConfig(), mesh_config=None,
               quiet: bool = False, write: bool = True, tum: str | Path | None = None, ply: str | Path | None = None,
               force: bool = False, map_scene: str | None = None) -> SlamResult:
    """Run SLAM on one scene of the dataset at ``dataset_url`` (``scene_id`` None: its only scene).

    Writes ``pose/T_world_lidar``, ``pose/T_world_radar`` (with a radar extrinsic), ``mesh/*`` and
    the scene attribute ``slam`` when ``write``; exports the LiDAR trajectory as TUM (``tum``) and
    the mesh as PLY (``ply``). A scene already done with the same inputs and settings is not
    recomputed for writing (``force`` recomputes) — the poses are still returned.

    ``map_scene``: localisation mode (:func:`localise_scene`): the scene's scans are localised
    against the map that slam builds from that scene (a mapping pass of the same corner), whose mesh
    and map the scene then gets."""
    from ..dataset import open_dataset
    from .mesh import MeshConfig

    from ..parallel import release_free_memory

    if map_scene is not None:
        return localise_scene(dataset_url, scene_id, map_scene, config=config, mesh_config=mesh_config, quiet=quiet,
                              write=write, tum=tum, ply=ply, force=force)
    t_all = time.perf_counter()
    release_free_memory()      # (slam forks the mesh's background model)
    mesh_config = mesh_config or MeshConfig()
    ds = open_dataset(dataset_url)
    if scene_id is None:
        if len(ds.scenes) != 1:
            raise InputError(f"{dataset_url}: {len(ds.scenes)} scenes ({', '.join(ds.scenes) or 'none'}); give --scene")
        scene_id = ds.scenes[0]
    scene = ds.scene(scene_id)
    scene.require_complete("slam")
    fp = _fingerprint(scene, config, mesh_config if config.mesh else None)
    done = scene.attrs.get("slam") or {}
    if (write and not force and done.get("complete") and done.get("fingerprint") == fp
            and "pose/T_world_lidar" in scene and (not config.mesh or ("mesh/faces" in scene and "map/points" in scene))):
        res = _stored_result(scene, done)
        if tum is not None:
            write_tum(tum, res.trajectory())
        if ply is not None and res.mesh is not None:
            from ..meshio import Mesh, write_ply

            write_ply(ply, Mesh(res.mesh[0], res.mesh[1]))
        return res
    timings: dict = {}
    health: dict = {}
    t0 = time.perf_counter()
    imports = _import_in_background(("kiss_icp.kiss_icp", "open3d"))
    streamed = stream_scans(scene) if config.refine else None
    if streamed is None:
        scans, feed = load_scans(scene, quiet=quiet), None
        timings["read_s"] = time.perf_counter() - t0
    else:
        # read while the refinement works on the first scans (the reading thread's zarr decoding and
        # open3d's ICP leave the GIL free for the other)
        scans, feed = streamed
    try:
        try:
            imports.join()
            odo = _odometry(scene, scans, config, health, timings, feed, quiet)
            if feed is not None:
                feed.wait(len(scans) - 1)   # every scan read (the mesh uses them), or the reader's error
        except _StreamBroken:
            feed.close()
            t0 = time.perf_counter()
            scans, feed = load_scans(scene, quiet=quiet), None
            timings["read_s"] = time.perf_counter() - t0
            odo = _odometry(scene, scans, config, health, timings, None, quiet)
    finally:
        if feed is not None:
            feed.close()
    if feed is not None:
        timings["read_s"], timings["read_wait_s"] = feed.read_s, feed.wait_s   # reading beside the refinement
    max_range, T0, anchor, poses, K, kref, background = odo
    Kw = K
    Tl, Tr, finfo = frame_poses(scene, scans, poses)
    mesh = map_points = minfo = None
    if config.mesh:
        t0 = time.perf_counter()
        sm = static_mesh(scans, poses, config, max_range, mesh_config, background, quiet=quiet)
        timings["mesh_s"] = time.perf_counter() - t0
        mesh, map_points, minfo = (sm.vertices, sm.faces), sm.points, sm.info
    timings = {k: round(v, 3) for k, v in timings.items()}
    summary = {"scene": scene_id, "scans": len(scans), "frames": scene.n_frames, "max_range_m": round(max_range, 3),
               "anchor": {k: v for k, v in anchor.items() if k != "T_world_lidar0"}, "health": health,
               "frames_info": {k: v for k, v in finfo.items() if k != "T_lidar_radar"}, "mesh": minfo,
               "timings": timings, "fingerprint": fp}
    agree = tf_agreement(scene, scans.stamp_ns, poses)
    if agree is not None:
        summary["tf_agreement"] = agree
    res = SlamResult(scene_id, scans.stamp_ns.copy(), poses, Kw, kref, Tl, Tr, mesh, summary, map_points)
    if write:
        _write(dataset_url, ds, scene_id, res, config, mesh_config, anchor, finfo, fp)
    if tum is not None:
        write_tum(tum, res.trajectory())
    if ply is not None and mesh is not None:
        from ..meshio import Mesh, write_ply

        write_ply(ply, Mesh(mesh[0], mesh[1]))
    summary["timings"]["total_s"] = round(time.perf_counter() - t_all, 3)
    return res


# ----------------------------------------------------------------------------------------------
# localisation against a mapping pass

MAPPING_ROLE = "mapping"   # scene attribute ``role`` of a mapping-pass scene (no train/test split, no raytrace-gt)


def check_map_scene(ds, scene_id: str, map_scene: str) -> None:
    """InputError (one line) unless ``map_scene`` is another scene of ``ds`` with LiDAR scans."""
    if map_scene not in ds.scenes:
        raise InputError(f"{ds.url}: no map scene {map_scene!r} (have: {', '.join(ds.scenes) or 'none'})")
    if map_scene == scene_id:
        raise InputError(f"{ds.url}: scene {scene_id!r} cannot be its own map scene")
    if "lidar/points" not in ds.scene(map_scene):
        raise InputError(f"{ds.url}: map scene {map_scene!r} has no lidar/points (a mapping pass needs LiDAR scans)")


def map_target(points: np.ndarray, cfg: SlamConfig) -> VoxelMap:
    """The refinement's point-to-plane map (:class:`VoxelMap`, ``cfg.map_voxel``) of a static point map
    ``points`` (M,3) world frame (normals from open3d, 0.25 m / 30 neighbours)."""
    import open3d as o3d

    pc = _o3d_cloud(points)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.25, max_nn=30))
    vm = VoxelMap(cfg.map_voxel)
    vm.add(np.asarray(pc.points), np.asarray(pc.normals))
    return vm


def guess_poses(scene, scans: Scans) -> tuple[np.ndarray | None, str]:
    """Odometry/TF-based guesses T_world_lidar (S,4,4) at the scan stamps: ingest's TF radar poses
    (``pose/T_world_radar``, source tf) through the extrinsics, else the source recording's TF
    (:func:`recording_tf_poses`); (None, "none") without either."""
    names = set(scene.arrays())
    ext = scene.attrs.get("extrinsics") or {}
    T_bl, T_br = _attr_T(ext, "lidar"), _attr_T(ext, "radar")
    if "pose/T_world_radar" in names and T_br is not None and dict(scene["pose/T_world_radar"].attrs).get("source") == "tf":
        P = np.asarray(scene["pose/T_world_radar"][...], np.float64)
        t = np.asarray(scene["time/timestamp_ns"][...], np.int64)
        ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
        if ok.sum() >= 2:
            T_rl = np.linalg.inv(T_br) @ (T_bl if T_bl is not None else np.eye(4))
            return Trajectory(t[ok], P[ok]).interpolate(scans.stamp_ns) @ T_rl, "tf (pose/T_world_radar)"
    for src, poses in (("tf (tf/T_world_lidar)", tf_lidar_poses),
                       ("tf (source recording)", recording_tf_poses)):   # (the recording is read only if needed)
        rt = poses(scene, scans.stamp_ns)
        if rt is not None and rt[1].all():
            return rt[0], src
    return None, "none"


def localise_first(points: np.ndarray, vmap: VoxelMap, guess: np.ndarray, cfg: SlamConfig, max_range: float,
                   distances=(1.0, 0.5, 0.3, 0.1, 0.05)) -> tuple[np.ndarray, float, float]:
    """Scan-to-map ICP of one scan (sensor frame, (N,3)) from ``guess`` (4,4) with wide-to-fine
    correspondence distances (``distances`` m; the guess may be off by the odometry's drift and the
    two recordings' world frames); returns (T_world_lidar, fitness, inlier RMSE m)."""
    p = np.asarray(points, np.float64)
    r2 = np.einsum("ij,ij->i", p, p)
    p = p[(r2 >= cfg.min_range ** 2) & (r2 <= max_range ** 2)]
    src = p[_downsample_index(p, cfg.source_voxel)]
    tgt = _TargetCache(max_range + 1.5).cloud(vmap, guess[:3, 3])
    return icp(src, tgt, guess, replace_cfg(cfg, icp_iterations=30), distances)


def replace_cfg(cfg: SlamConfig, **kw) -> SlamConfig:
    from dataclasses import replace

    return replace(cfg, **kw)


def localise_scene(dataset_url, scene_id: str | None, map_scene: str, *, config: SlamConfig = SlamConfig(),
                   mesh_config=None, quiet: bool = False, write: bool = True, tum=None, ply=None,
                   force: bool = False) -> SlamResult:
    """Localisation mode of ``holodata slam`` (``--map-scene``): the map first, then the data.

    1. ``map_scene`` (a mapping pass of the same corner, no person: its own LiDAR-only scene) gets
       the ordinary :func:`slam_scene` (poses, ``mesh/*``, ``map/points``; resumed when done; seeded
       by its odometry/TF, ``seed_poses="tf"``, where it has them) and the
       scene attribute ``role: "mapping"`` (``mapping_for``: the scenes localised against it), which
       excludes it from train/test splits and raytrace-gt.
    2. The scene's scans are localised against that map (its ``map/points`` as a fixed point-to-plane
       target, never grown): the first scan by ICP from the odometry/TF-based guess
       (:func:`guess_poses`; else the map scene's anchor) with wide-to-fine distances
       (:func:`localise_first`), every later one by :func:`refine` from the previous pose moved by the
       guesses' relative motion (kiss-icp's without TF), at-rest scans held as in slam.
    3. The scene gets ``pose/T_world_lidar``, ``pose/T_world_radar``, the map's ``mesh/*`` and
       ``map/points`` (copied, source "slam"), all in the map scene's world frame, and the attribute
       ``slam`` with ``mode: "localisation"``, ``map_scene``, the map's anchor and the localisation's
       health (fitness per scan, the first scan's correction from its guess).
    Raises InputError for an unknown map scene or one without LiDAR, DatasetError when the first scan
    does not localise (fitness below ``config.min_fitness``)."""
    from ..dataset import create_dataset, open_dataset
    from ..parallel import release_free_memory
    from .mesh import MeshConfig

    t_all = time.perf_counter()
    mesh_config = mesh_config or MeshConfig()
    ds = open_dataset(dataset_url)
    if scene_id is None:
        others = [s for s in ds.scenes if s != map_scene]
        if len(others) != 1:
            raise InputError(f"{dataset_url}: {len(others)} scenes besides the map scene; give --scene")
        scene_id = others[0]
    if scene_id not in ds.scenes:
        raise InputError(f"{dataset_url}: no scene {scene_id!r} (have: {', '.join(ds.scenes) or 'none'})")
    check_map_scene(ds, scene_id, map_scene)
    timings: dict = {}
    t0 = time.perf_counter()
    # (seeded by its odometry/TF where it has them: a mapping pass is often throttled to a few scans a second)
    mres = slam_scene(dataset_url, map_scene, config=replace_cfg(config, seed_poses="tf"), mesh_config=mesh_config,
                      quiet=quiet, write=write, force=force)
    timings["map_scene_s"] = time.perf_counter() - t0
    ds = open_dataset(dataset_url)
    mscene, scene = ds.scene(map_scene), ds.scene(scene_id)
    scene.require_complete("slam")
    if write:
        for_ = sorted(set((mscene.attrs.get("mapping_for") or [])) | {scene_id})
        if mscene.attrs.get("role") != MAPPING_ROLE or mscene.attrs.get("mapping_for") != for_:
            create_dataset(dataset_url, grid=ds.grid, range_bins=ds.range_bins, created_by="holodata slam").scene(
                map_scene).set_attrs({"role": MAPPING_ROLE, "mapping_for": for_})
    if mres.map_points is None or mres.mesh is None:
        raise DatasetError(f"{dataset_url}: map scene {map_scene!r} has no static map (run slam with a mesh)")
    manchor = dict((mscene.attrs.get("slam") or {}).get("anchor") or {})
    fp = _fingerprint(scene, config, mesh_config) + "-map-" + str((mscene.attrs.get("slam") or {}).get("fingerprint"))
    done = scene.attrs.get("slam") or {}
    if (write and not force and done.get("complete") and done.get("fingerprint") == fp
            and "pose/T_world_lidar" in scene and "mesh/faces" in scene and "map/points" in scene):
        res = _stored_result(scene, done)
        if tum is not None:
            write_tum(tum, res.trajectory())
        return res
    release_free_memory()
    imports = _import_in_background(("open3d",))
    t0 = time.perf_counter()
    scans = load_scans(scene, quiet=quiet)
    timings["read_s"] = time.perf_counter() - t0
    imports.join()
    max_range = float(config.max_range or data_max_range(scans))
    t0 = time.perf_counter()
    vmap = map_target(mres.map_points, config)
    timings["map_target_s"] = time.perf_counter() - t0
    guess, guess_src = guess_poses(scene, scans)
    t0 = time.perf_counter()
    if guess is not None:
        g0 = guess[0]
        init = _Fixed(guess, seed=True)
    else:
        g0 = anchor_pose(scene, scans.stamp_ns[:1])[0]
        init = KissStream(scans, config, max_range) if len(scans) > 1 else _Fixed(np.eye(4)[None].repeat(1, 0))
    T0, fit0, rmse0 = localise_first(scans.points[0], vmap, g0, config, max_range)
    if fit0 < config.min_fitness:
        raise DatasetError(f"{dataset_url}: scene {scene_id!r}: its first scan does not localise in map scene "
                           f"{map_scene!r} (fitness {fit0:.2f} < {config.min_fitness} from the {guess_src} guess)")
    D = np.linalg.inv(g0) @ T0
    if len(scans) > 1:
        poses, h = refine(scans, init, config, max_range, quiet=quiet, T0=T0, vmap=vmap, grow_map=False)
    else:
        poses, h = T0[None].copy(), {"fitness": np.array([fit0]), "rmse": np.array([rmse0]), "kiss_fallbacks": 0,
                                     "still_scans": 0, "kiss_scans": 0}
    timings["localise_s"] = time.perf_counter() - t0
    Tl, Tr, finfo = frame_poses(scene, scans, poses)
    fit = np.r_[fit0, h["fitness"][1:]]
    health = {"localisation": {"guess": guess_src, "first_fitness": fit0, "first_rmse_m": rmse0,
                               "first_correction_m": float(np.linalg.norm(D[:3, 3])),
                               "first_correction_deg": float(rotation_angle_deg(D)),
                               "fitness_min": float(fit.min()), "fitness_mean": float(fit.mean()),
                               "rmse_max_m": float(np.max(np.r_[rmse0, h["rmse"][1:]])),
                               "fallbacks": int(h["kiss_fallbacks"]), "still_scans": int(h["still_scans"])}}
    timings = {k: round(v, 3) for k, v in timings.items()}
    anchor = {**manchor, "map_scene": map_scene}
    summary = {"scene": scene_id, "mode": "localisation", "map_scene": map_scene, "scans": len(scans),
               "frames": scene.n_frames, "max_range_m": round(max_range, 3),
               "anchor": {k: v for k, v in anchor.items() if k != "T_world_lidar0"}, "health": health,
               "frames_info": {k: v for k, v in finfo.items() if k != "T_lidar_radar"},
               "mesh": {"from_map_scene": map_scene, "faces": int(len(mres.mesh[1]))}, "timings": timings,
               "fingerprint": fp}
    res = SlamResult(scene_id, scans.stamp_ns.copy(), poses, None, None, Tl, Tr, mres.mesh, summary, mres.map_points)
    if write:
        _write(dataset_url, ds, scene_id, res, replace_cfg(config, mesh=True), mesh_config, anchor, finfo, fp,
               mode={"mode": "localisation", "map_scene": map_scene})
    if tum is not None:
        write_tum(tum, res.trajectory())
    if ply is not None:
        from ..meshio import Mesh, write_ply

        write_ply(ply, Mesh(mres.mesh[0], mres.mesh[1]))
    summary["timings"]["total_s"] = round(time.perf_counter() - t_all, 3)
    return res


def _stored_result(scene, done: dict) -> SlamResult:
    """A finished scene's result read back from the dataset (no recomputation; no kiss-icp poses)."""
    Tl = np.asarray(scene["pose/T_world_lidar"][...], np.float64)
    Tr = np.asarray(scene["pose/T_world_radar"][...], np.float64) if "pose/T_world_radar" in scene else None
    names = set(scene.arrays())
    st = np.asarray(scene["lidar/timestamp_ns"][...] if "lidar/timestamp_ns" in names else scene["time/timestamp_ns"][...],
                    np.int64)
    _, first = np.unique(st, return_index=True)
    first = np.sort(first[st[first] > 0])
    mesh = None
    if "mesh/faces" in names:
        mesh = (np.asarray(scene["mesh/vertices"][...], np.float32), np.asarray(scene["mesh/faces"][...], np.int32))
    summary = dict(done.get("summary") or {})
    summary["skipped"] = "already done with the same inputs and settings (use --force to recompute)"
    points = np.asarray(scene["map/points"][...], np.float64) if "map/points" in names else None
    return SlamResult(scene.id, st[first], Tl[first], None, None, Tl, Tr, mesh, summary, points)


def _write(url, ds, scene_id, res: SlamResult, cfg: SlamConfig, mesh_cfg, anchor, finfo, fp, mode=None) -> None:
    from ..dataset import create_dataset

    meta = ds.meta
    w = create_dataset(url, grid=ds.grid, range_bins=ds.range_bins, created_by="holodata slam",
                       shard_frames=int(meta.get("shard_frames") or 32))
    sc = w.scene(scene_id)
    if (sc.attrs.get("slam") or {}).get("complete"):
        sc.set_attrs({"slam": {**sc.attrs["slam"], "complete": False}})  # a crash below must not look done
    names = set(sc.arrays())
    stale = sorted(n for n in names if n.startswith("gt/"))
    for n in stale:  # ray-traced from the previous mesh/poses: would be silently wrong (raytrace-gt resumes)
        sc.remove(n)
    res.summary["removed_stale"] = stale
    pose_attrs = {"source": "slam", "world_frame": anchor.get("world_frame"), "anchor": anchor.get("kind"),
                  "method": "kiss-icp 1.3 + open3d scan-to-map point-to-plane ICP" if cfg.refine else "kiss-icp 1.3"}
    if (mode or {}).get("map_scene"):
        pose_attrs["method"] = f"open3d scan-to-map point-to-plane ICP against map scene {mode['map_scene']!r}"
        pose_attrs["map_scene"] = mode["map_scene"]
    arrays = [("pose/T_world_lidar", res.T_world_lidar, {"time": "lidar/timestamp_ns (time/timestamp_ns when 0)"})]
    if res.T_world_radar is not None:
        arrays.append(("pose/T_world_radar", res.T_world_radar, {"time": "time/timestamp_ns",
                                                                 "T_lidar_radar": finfo.get("T_lidar_radar")}))
    for name, P, extra in arrays:
        if name in names:
            sc.remove(name)
        a = sc.frame_array(name, per_frame_shape=(4, 4), dtype="float64", dims=["frame", "row", "col"], units="m",
                           fill_value=float("nan"), attrs={**pose_attrs, **extra})
        for k in range(a.n_shards):
            a.write_shard(k, P[a.frames(k)])
    if res.mesh is not None:
        if "mesh/face_class" in names:
            sc.remove("mesh/face_class")
        write_static_map(sc, res.mesh[0], res.mesh[1], res.map_points, "slam")
    sc.set_attrs({"slam": {"complete": True, "fingerprint": fp, "config": cfg.to_attrs(),
                           "mesh_config": mesh_cfg.to_attrs() if cfg.mesh else None,
                           "anchor": anchor, "summary": json_safe(res.summary), **(mode or {})}})


def write_static_map(sc, vertices: np.ndarray, faces: np.ndarray, points: np.ndarray | None, source: str) -> None:
    """Write a :class:`StaticMap`'s ``mesh/vertices``, ``mesh/faces`` and (when given) ``map/points``
    (M,3) float32 into the scene writer ``sc``, each with the ``source`` of the poses they were built
    from: ``holodata register`` uses them only while that matches ``pose/T_world_lidar``'s."""
    sc.write_array("mesh/vertices", np.asarray(vertices, np.float32), dims=["vertex", "xyz"], units="m",
                   attrs={"source": source, "frame": "world"})
    sc.write_array("mesh/faces", np.asarray(faces, np.int32), dims=["face", "corner"], units="1",
                   attrs={"source": source})
    if points is not None:
        sc.write_array("map/points", np.asarray(points, np.float32), dims=["point", "xyz"], units="m",
                       attrs={"source": source, "frame": "world",
                              "what": "static LiDAR returns averaged per mesh voxel (the mesh's input)"})
    elif "map/points" in sc.arrays():
        sc.remove("map/points")


def json_safe(obj):
    import json

    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def slam_dataset(dataset_url, scene_ids=None, single_exports: bool = False, map_scene: str | None = None,
                 **kwargs) -> list[SlamResult]:
    """:func:`slam_scene` for each of ``scene_ids`` (default: every scene with lidar/points).
    ``single_exports``: ``tum``/``ply`` exports are allowed only when one scene is processed.
    ``map_scene``: localise each scene against that mapping pass (:func:`localise_scene`; needs
    ``scene_ids``); without it a scene localised against a mapping pass before is localised against
    that one again (its ``slam.map_scene``)."""
    from ..dataset import open_dataset

    ds = open_dataset(dataset_url)
    if map_scene is not None:
        if not scene_ids:
            raise InputError(f"{dataset_url}: a map scene needs the scenes to localise (give --scene)")
        for sid in scene_ids:
            if sid not in ds.scenes:
                raise InputError(f"{dataset_url}: no scene {sid!r} (have: {', '.join(ds.scenes) or 'none'})")
            check_map_scene(ds, sid, map_scene)
        if single_exports and len(scene_ids) > 1 and (kwargs.get("tum") or kwargs.get("ply")):
            raise InputError(f"{dataset_url}: {len(scene_ids)} scenes; --ply/--tum need one (give --scene)")
        return [localise_scene(dataset_url, sid, map_scene, **kwargs) for sid in scene_ids]
    if scene_ids:
        for sid in scene_ids:
            if sid not in ds.scenes:
                raise InputError(f"{dataset_url}: no scene {sid!r} (have: {', '.join(ds.scenes) or 'none'})")
        ids = list(scene_ids)
    else:
        ids = [s for s in ds.scenes if "lidar/points" in ds.scene(s)]
    if not ids:
        raise InputError(f"{dataset_url}: no scene has lidar/points (nothing for slam)")
    if single_exports and len(ids) > 1 and (kwargs.get("tum") or kwargs.get("ply")):
        raise InputError(f"{dataset_url}: {len(ids)} scenes; --ply/--tum need one (give --scene)")
    # a scene localised against a mapping pass before stays localised against it
    prev = {sid: (ds.scene(sid).attrs.get("slam") or {}).get("map_scene") for sid in ids}
    return [slam_scene(dataset_url, sid, map_scene=prev[sid] if prev[sid] in ds.scenes else None, **kwargs)
            for sid in ids]


__all__ = ["SlamConfig", "SlamResult", "StaticMap", "write_static_map", "Scans", "load_scans", "kiss_odometry", "refine", "global_refine",
           "static_mesh", "slam_scene", "slam_dataset", "deskew", "twist", "anchor_pose", "tf_lidar_poses", "frame_poses",
           "localise_scene", "check_map_scene", "recording_tf_poses", "guess_poses", "MAPPING_ROLE"]
