"""Automatic human (moving-object) instance segmentation on the LiDAR's native range-image grid.

The method of the Ouster OS0 instance-segmentation note, on the organised scan ``lidar/range``
(T, Hl, Wl) of a scene whose scans have poses ``pose/T_world_lidar``:

1. **Background model**: every scan's returns in the world frame go into a 15 cm voxel model of the
   static scene (:class:`holodata.mapping.background.VoxelBackground`: voxels occupied in at least
   ``min_fraction`` of the scans that observed them, free-space test from the scan origins; people
   occupy a voxel only briefly), plus the **floor plane** (:func:`floor_plane`): returns within
   ``floor_margin_m`` of it are background too.
2. **Foreground**: the returns of a scan outside the background (grid mask, (Hl, Wl)).
3. **Seeds by shrinking**: binary erosion of the foreground mask (columns wrap around), which
   removes isolated pixels and the fringe of mixed/edge returns; 3×3, or 1×3 when the rows are
   more than twice as far apart in angle as the columns (:func:`shrink_structure`).
4. **Flood fill** from the seeds over grid neighbours (right, down, both diagonals, and the
   second neighbour along rows and columns to bridge single dropouts; columns wrap) that are
   foreground and within a Euclidean distance ``dist_m + dist_per_m · r + spacing_factor · s · r``
   of each other (3-D points, metres; r the nearer range, s the beam pattern's angular step between
   the two pixels — :func:`neighbour_spacing`, from the row elevations measured in the scan,
   :func:`beam_elevations`). Implemented as connected components of that neighbour graph
   (``scipy.sparse.csgraph``) keeping the components that hold a seed. Clusters standing on the
   same plan-view spot with overlapping heights are joined (:func:`merge_stacked`: a limb split
   off by a depth jump).
5. **Keep the largest cluster(s)**: components with at least ``min_points`` returns whose extent is
   person-like (vertical extent >= ``min_height_m``, horizontal extent <= ``max_width_m``, top at
   most ``max_height_m`` above the floor, not flat), largest first, at most ``max_instances``.

Beam geometry: the link threshold, the shrink structure and the smallest height follow the beam
spacing measured in the scan, so that a coarse wide-FOV LiDAR (an OS0-like 90°, 32 beams) is
segmented as well as a fine narrow one (an OS1-like 33°, 64 beams): on a coarse grid the rows of a
far person lie farther apart than a fixed link threshold, a fixed 3×3 shrink removes whole rows, and
the far floor seen by one coarse ring stays out of the voxel background. What failed and the
accuracy per LiDAR: ``docs/design/segment.md``.

Output per scan: an instance image (Hl, Wl) uint16, 0 = background / no return, 1 = the largest
instance, 2 = the next ... Stored as ``lidar/instance`` (T, Hl, Wl) uint16 with
``dims = [frame, beam, column]`` and the parameters in its attributes (written shard by shard with
the dataset writer: atomic shards, a rerun resumes), with ``poses_sha256``, the fingerprint of the
``pose/T_world_lidar`` it was made with (:func:`instance_state`: masks made with other poses are
made again, not resumed or reused).

Points: ``lidar/points`` holds the valid pixels of ``lidar/range`` in row-major order (see
:mod:`holodata.ingest`), in the sensor frame at each point's own time; with ``lidar/point_time_ns``
(time relative to the scan stamp) the points are de-skewed with poses interpolated between scans
(:meth:`LidarScans.deskew_points`: one transform for a scan taken at rest, one pose per column).

Runtime (400-cycle corner, 400 scans of 64×512, 366 taken at rest; background model + segmentation,
same masks as before): 20.7-22.5 s wall / 16.9-18.1 s CPU → 4.2-4.5 s on 2 shared cores at load ~4-5
(``benchmarks/pipeline.py``) — a dense voxel grid for the occupancy count and lookups
(:mod:`.background`), ``lidar/range`` read a shard at a time, the de-skew shortcuts
(:meth:`LidarScans.scan_world` for the background pass; :mod:`.scans`), and :func:`background_and_segment`, which
reuses the background pass's world points so that scans without foreground are not read twice.

Modules: :mod:`.config` (settings), :mod:`.core` (one scan's segmentation, arrays in and out),
:mod:`.scans` (the scene's scans as the segmentation reads them); this module holds the dataset
passes (background model, :func:`segment_scene`, :func:`background_and_segment`, the instance masks).
"""
from __future__ import annotations

import numpy as np

from ...dataset.layout import POSE_T_WORLD_LIDAR
from ...errors import InputError
from ...progress import track
from .config import INSTANCE_ARRAY, SegmentConfig
from .core import (above_floor, beam_elevations, destagger, erode, flood_fill, floor_plane, merge_stacked,
                   neighbour_spacing, row_shifts, segment_scan, shrink_structure)
from .scans import LidarScans


def background_from_points(points_world: list, origins, cfg: SegmentConfig):
    """:class:`VoxelBackground` of world-frame scans with the segmentation's settings (free-space test
    with the scans' ``origins`` when ``cfg.free_space``)."""
    from ..background import VoxelBackground

    use = cfg.free_space and origins is not None and len(origins)
    return VoxelBackground.build(points_world, voxel=cfg.voxel, min_fraction=cfg.min_fraction, min_hits=cfg.min_hits,
                                 origins=np.asarray(origins) if use else None)


def build_background(scans: LidarScans, cfg: SegmentConfig, traj=None, quiet: bool = True):
    """Voxel background model of a scene's scans (world frame). With ``cfg.free_space`` the scan
    origins go to :meth:`VoxelBackground.build` (free-space test: a voxel people walk through is seen
    through by other scans and drops out; the comparison with the occupancy count alone:
    ``docs/design/segment.md``)."""
    return _background_pass(scans, cfg, traj, quiet)[0]


def _background_pass(scans: LidarScans, cfg: SegmentConfig, traj=None, quiet: bool = True, keep: bool = False):
    """(background model, kept) of :func:`build_background`; ``keep``: kept = {frame: float32 world
    points (N,3) of the valid returns in row-major order} of the usable
    scans (the lists the model is built from, no copy), for :func:`segment_scene` ``world_points``."""
    pts, origins, kept = [], [], {}
    for k in track(range(len(scans.stamps)), len(scans.stamps), "background", quiet):
        _, pw = scans.scan_world(k, traj, cfg.deskew)
        if not scans.usable(k):
            continue
        pts.append(pw.astype(np.float32))
        origins.append(scans.poses[k][:3, 3])
        if keep:
            kept[k] = pts[-1]
    origins = np.array(origins) if origins else None
    bg = background_from_points(pts, origins, cfg)
    if cfg.floor_margin_m > 0:
        bg.floor = floor_plane(pts, origins)
    return bg, kept


def background_and_segment(scene, cfg: SegmentConfig | None = None, quiet: bool = True, overwrite: bool = False,
                           segment: bool = True, scans=None, traj=None):
    """(background model, :func:`write_instances` summary or None, world points) of ``scene`` (a read
    handle, :meth:`Dataset.scene <holodata.dataset.Dataset.scene>`; a forked child gets the handle and
    opens no dataset of its own for reading): :func:`build_background` of the scene's scans and, with
    ``segment``, their segmentation, which reuses the background pass's world points: scans without
    foreground are not read and de-skewed a second time (366 of the 400 scans of a 400-cycle corner are
    taken at rest, most of them without foreground). World points: {frame: float32 world points (N,3)
    of the valid returns in row-major order} of the usable scans, the lists the model was built from
    (``holodata register`` builds its map from them). ``scans`` / ``traj``: the scene's
    :class:`LidarScans` and trajectory when the caller has them."""
    cfg = cfg or SegmentConfig()
    if scans is None:
        scans = LidarScans.open(scene, scene.ds.url)
    if traj is None:
        traj = scans.trajectory()
    bg, kept = _background_pass(scans, cfg, traj, quiet, keep=True)
    if not segment:
        return bg, None, kept
    with _segment_stage(scene):
        return bg, write_instances(scene, cfg, quiet, overwrite, background=bg, world_points=kept, scans=scans,
                                   traj=traj), kept


def _segment_stage(scene):
    """The scene marked unfinished by ``segment`` while the segmentation's API entry points write
    ``lidar/instance`` (:meth:`holodata.dataset.SceneWriter.stage`); ``holodata register``, which writes it
    through :func:`write_instances` too, holds its own mark over it."""
    from ...dataset import open_dataset

    return open_dataset(scene.ds.url, "r+").scene(scene.id).stage(
        "segment", rerun=f"rerun holodata.mapping.segment.segment_scene on scene {scene.id!r} to finish it")


def surely_without_foreground(bg, points_world32: np.ndarray, cfg: SegmentConfig) -> bool:
    """True when a scan whose valid returns have the float32 world points ``points_world32`` (N,3)
    has fewer than ``cfg.min_points`` foreground returns (returns outside the background model
    ``bg`` and its floor, as :func:`background_masks` decides on the float64 points), so that
    :func:`segment_scan` finds nothing in it. Returns whose float64 point might be classified
    otherwise — within 1e-6·(|x|+1) m (>15x the float32 rounding) of a voxel face or of the floor
    margin — count as foreground, so the answer is exact for the float64 points."""
    p = np.asarray(points_world32, np.float64).reshape(-1, 3)
    need = max(cfg.min_points, 1)
    if len(p) < need:
        return True
    q = np.divide(p, bg.voxel, dtype=np.float64)
    ijk = np.floor(q)                                # voxel indices, as VoxelBackground.contains computes them
    fg = ~bg._lookup(ijk, bool(cfg.tolerance_voxels))
    q -= ijk
    tol = 1e-6 * (np.abs(p) + 1.0)
    near = np.minimum(q, 1.0 - q) * bg.voxel <= tol
    amb = near[:, 0] | near[:, 1] | near[:, 2]
    floor = getattr(bg, "floor", None)
    if floor is not None and cfg.floor_margin_m > 0:
        h = above_floor(floor, p)
        fg &= ~(h < cfg.floor_margin_m)
        amb |= np.abs(h - cfg.floor_margin_m) <= tol[:, 2] + abs(floor[0]) * tol[:, 0] + abs(floor[1]) * tol[:, 1]
    return int((fg | amb).sum()) < need


def in_background(bg, points_world: np.ndarray, tolerance_voxels: int = 0) -> np.ndarray:
    """(N,) bool: world points whose voxel is a background voxel (``tolerance_voxels`` 0), or lies
    within one voxel of one (1: :meth:`VoxelBackground.contains`)."""
    if tolerance_voxels:
        return bg.contains(points_world)
    return bg.contains(points_world, 0)


def grid_geometry(scans: LidarScans, n: int = 5) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(destagger shifts (H,) int, beam elevations (H,) rad) of a scene's organised scans, measured
    once from up to ``n`` scans spread over the recording (:func:`row_shifts` — the most common value
    per row — and the median of :func:`beam_elevations`); (None, None) without usable scans (then
    :func:`segment_scan` measures them per scan)."""
    sh, el = [], []
    H = scans.shape[0]
    for k in np.unique(np.linspace(0, len(scans.stamps) - 1, min(n, len(scans.stamps))).round().astype(int)):
        valid, P, _ = scans.scan(int(k), None, False)
        if valid.sum() >= 8 * H:
            sh.append(row_shifts(P, valid))
            el.append(beam_elevations(P, valid))
    if not sh:
        return None, None
    sh = np.array(sh)
    mode = np.array([np.bincount(c - c.min()).argmax() + c.min() for c in sh.T], np.int64)
    return mode, np.median(el, axis=0)


def background_masks(bg, valid: np.ndarray, points_world: np.ndarray, cfg: SegmentConfig) -> np.ndarray:
    """The background (H,W) bool of one scan for :func:`segment_scan`: returns in a background voxel
    (:func:`in_background`, ``cfg.tolerance_voxels``) or within ``cfg.floor_margin_m`` of the floor
    plane ``bg.floor`` (when the model has one)."""
    v = np.asarray(valid, bool)
    p = points_world[v]
    bgm = np.zeros(v.shape, bool)
    bgm[v] = in_background(bg, p, cfg.tolerance_voxels)
    floor = getattr(bg, "floor", None)
    if floor is not None and cfg.floor_margin_m > 0:
        bgm[v] |= above_floor(floor, p) < cfg.floor_margin_m
    return bgm


def segment_scene(url: str, scene_id: str | None = None, cfg: SegmentConfig | None = None, quiet: bool = True,
                  overwrite: bool = False, background=None, world_points: dict | None = None,
                  masks: "InstanceMasks | None" = None) -> dict:
    """Segment every scan of scene ``scene_id`` (None: the only one) of dataset ``url`` and write
    ``lidar/instance``: :func:`write_instances` of the scene (the arguments are its)."""
    from ...dataset import open_dataset

    ds = open_dataset(url)
    scene = ds.scene(_scene_id(ds, url, scene_id))
    with _segment_stage(scene):
        return write_instances(scene, cfg, quiet, overwrite, background=background, world_points=world_points,
                               masks=masks)


def write_instances(scene, cfg: SegmentConfig | None = None, quiet: bool = True, overwrite: bool = False,
                    background=None, world_points: dict | None = None, masks: "InstanceMasks | None" = None,
                    scans: LidarScans | None = None, traj=None) -> dict:
    """Segment every scan of ``scene`` (a read handle; the writes go through a writer opened on its
    dataset) and write ``lidar/instance`` (T,Hl,Wl) uint16 (resumable: finished shards are kept).
    ``background``: a prebuilt model of these scans (else built here); ``world_points``: {frame:
    float32 world points of the valid returns (N,3)} from the pass that built ``background``
    (:func:`background_and_segment`): scans that are :func:`surely_without_foreground` are written
    empty without reading them again (the same result). ``masks``: the :class:`InstanceMasks` of
    these scans and this background that another user already asked (``holodata register``'s map):
    the masks it holds are not computed again. ``scans`` / ``traj``: the scene's :class:`LidarScans`
    and trajectory when the caller has them. Returns a summary {scene, frames, instances_per_scan, ...}."""
    import time

    from ...dataset import open_dataset

    cfg = cfg or SegmentConfig()
    t0 = time.perf_counter()
    sid = scene.id
    if scans is None:
        scans = LidarScans.open(scene, scene.ds.url)
    if traj is None:
        traj = scans.trajectory()
    if background is None:
        background, world_points = _background_pass(scans, cfg, traj, quiet, keep=True)
    bg = background
    world_points = world_points or {}
    sw = open_dataset(scene.ds.url, "r+").scene(sid)
    poses = pose_fingerprint(scene)
    if INSTANCE_ARRAY in sw.arrays() and (overwrite or instance_state(scene) == "stale"):
        sw.remove(INSTANCE_ARRAY)
    arr = sw.frame_array(INSTANCE_ARRAY, per_frame_shape=scans.shape,
                         attrs={"method": "voxel background + erosion seeds + Euclidean flood fill (Ouster OS0)",
                                "values": "0 = background or no return; 1..n instances by decreasing size",
                                "params": cfg.to_attrs(), "background_voxels": int(len(bg)), "poses_sha256": poses})
    counts = []
    masks = masks or InstanceMasks(scans, bg, cfg, traj, world_points)
    for s in track(range(arr.n_shards), arr.n_shards, f"segment {sid}", quiet):
        sl = arr.frames(s)
        if arr.is_done(s):
            continue
        out = np.zeros((sl.stop - sl.start,) + scans.shape, np.uint16)
        for i, k in enumerate(range(sl.start, sl.stop)):
            m = masks.mask(k)
            if m is not None:
                out[i] = m
                counts.append(int(m.max()))
        arr.write_shard(s, out)
    return {"scene": sid, "frames": scene.n_frames, "array": INSTANCE_ARRAY, "background_voxels": int(len(bg)),
            "instances_per_scan": float(np.mean(counts)) if counts else 0.0, "seconds": time.perf_counter() - t0}


def pose_fingerprint(scene) -> str | None:
    """sha256 of the scene's ``pose/T_world_lidar`` (float64, C order); None without poses. Stored
    with ``lidar/instance`` as ``poses_sha256``: the poses its scans were segmented with."""
    import hashlib

    if POSE_T_WORLD_LIDAR not in set(scene.arrays()):
        return None
    P = np.ascontiguousarray(scene[POSE_T_WORLD_LIDAR][...], np.float64)
    return hashlib.sha256(P.tobytes()).hexdigest()


def instance_state(scene) -> str:
    """What the scene's ``lidar/instance`` is worth now: "current" (every shard written, segmented
    with the poses the scene holds), "partial" (same poses, shards missing: :func:`segment_scene`
    resumes it), "stale" (segmented with other poses, or with unknown ones: ``holodata slam`` ran
    again, or the poses were replaced) or "absent"."""
    nodes = scene.nodes()
    if INSTANCE_ARRAY not in nodes:
        return "absent"
    attrs = nodes[INSTANCE_ARRAY][1].get("attributes") or {}
    fp = attrs.get("poses_sha256")
    if fp is None or fp != pose_fingerprint(scene):
        return "stale"
    n = int((attrs.get("holodata") or {}).get("n_shards") or 0)
    done = n > 0 and all(scene.is_done(INSTANCE_ARRAY, k) for k in range(n))
    return "current" if done else "partial"


class InstanceMasks:
    """Per-scan instance masks of :func:`segment_scene`, computed on demand: ``masks[k]`` (H,W)
    uint16 (0 = background / no return, 1..n instances). ``world_points`` {frame: float32 world points
    of the valid returns} from the background pass: scans that are :func:`surely_without_foreground`
    are answered from them without reading the scan again. A mask asked by index (``masks[k]``) is
    kept until :meth:`mask` hands it out (to :func:`segment_scene`), so it is computed once."""

    def __init__(self, scans: LidarScans, bg, cfg: SegmentConfig, traj=None, world_points: dict | None = None):
        self.scans, self.bg, self.cfg, self.traj = scans, bg, cfg, traj
        self.world_points = world_points or {}
        self.shifts, self.elev = grid_geometry(scans)
        self._kept: dict = {}

    def mask(self, k: int) -> np.ndarray | None:
        """Scan ``k``'s mask, or None for a scan without returns (counted by nobody)."""
        if k in self._kept:
            return self._kept.pop(k)
        wp = self.world_points.get(k)
        if wp is not None and surely_without_foreground(self.bg, wp, self.cfg):
            return np.zeros(self.scans.shape, np.uint16) if len(wp) else None
        valid, P, Pw = self.scans.scan(k, self.traj, self.cfg.deskew)
        if not valid.any():
            return None
        bgm = background_masks(self.bg, valid, Pw, self.cfg)
        return segment_scan(P, valid, bgm, self.cfg, points_world=np.where(valid[..., None], Pw, 0.0),
                            floor=getattr(self.bg, "floor", None), shifts=self.shifts, elev=self.elev)

    def __getitem__(self, k: int) -> np.ndarray:
        m = self._kept[k] = self.mask(k)
        return np.zeros(self.scans.shape, np.uint16) if m is None else m


def _scene_id(ds, url: str, scene_id: str | None) -> str:
    if scene_id is None:
        if len(ds.scenes) != 1:
            raise InputError(f"{url}: holds {len(ds.scenes)} scenes ({', '.join(ds.scenes) or 'none'}); pick one with --scene")
        return ds.scenes[0]
    if scene_id not in ds.scenes:
        raise InputError(f"{url}: no scene {scene_id!r} (have: {', '.join(ds.scenes) or 'none'})")
    return scene_id


__all__ = ["SegmentConfig", "segment_scan", "flood_fill", "erode", "LidarScans", "build_background", "segment_scene",
           "write_instances", "InstanceMasks",
           "background_and_segment", "surely_without_foreground", "INSTANCE_ARRAY", "instance_state",
           "pose_fingerprint", "destagger", "row_shifts", "merge_stacked", "neighbour_spacing", "shrink_structure",
           "beam_elevations", "floor_plane", "grid_geometry", "background_masks", "in_background"]
