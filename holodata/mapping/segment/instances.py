"""The dataset passes of the segmentation (steps 2-5 of :mod:`holodata.mapping.segment` on every
scan of a scene): :func:`segment_scene` / :func:`write_instances` write ``lidar/instance`` shard by
shard, :func:`background_and_segment` reuses the background pass's world points, :class:`InstanceMasks`
computes a scan's masks on demand, :func:`instance_state` says whether the stored masks are current."""
from __future__ import annotations

import numpy as np

from ...dataset.layout import POSE_T_WORLD_LIDAR
from ...errors import InputError
from ...progress import track
from .background_model import _background_pass, background_masks, surely_without_foreground
from .config import INSTANCE_ARRAY, SegmentConfig
from .core import beam_elevations, row_shifts, segment_scan
from .scans import LidarScans


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
        return bg, write_instances(scene, cfg, quiet, overwrite, masks=InstanceMasks(scans, bg, cfg, traj, kept)), kept


def _segment_stage(scene):
    """The scene marked unfinished by ``segment`` while the segmentation's API entry points write
    ``lidar/instance`` (:meth:`holodata.dataset.SceneWriter.stage`); ``holodata register``, which writes it
    through :func:`write_instances` too, holds its own mark over it."""
    from ...dataset import open_dataset

    return open_dataset(scene.ds.url, "r+").scene(scene.id).stage(
        "segment", rerun=f"rerun holodata.mapping.segment.segment_scene on scene {scene.id!r} to finish it")



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



def segment_scene(url: str, scene_id: str | None = None, cfg: SegmentConfig | None = None, quiet: bool = True,
                  overwrite: bool = False, background=None, world_points: dict | None = None,
                  masks: InstanceMasks | None = None) -> dict:
    """Segment every scan of scene ``scene_id`` (None: the only one) of dataset ``url`` and write
    ``lidar/instance``: :func:`write_instances` of the scene (the arguments are its)."""
    from ...dataset import open_dataset

    ds = open_dataset(url)
    scene = ds.scene(_scene_id(ds, url, scene_id))
    with _segment_stage(scene):
        return write_instances(scene, cfg, quiet, overwrite, background=background, world_points=world_points,
                               masks=masks)


def write_instances(scene, cfg: SegmentConfig | None = None, quiet: bool = True, overwrite: bool = False,
                    background=None, world_points: dict | None = None, masks: InstanceMasks | None = None) -> dict:
    """Segment every scan of ``scene`` (a read handle; the writes go through a writer opened on its
    dataset) and write ``lidar/instance`` (T,Hl,Wl) uint16 (resumable: finished shards are kept).
    ``background``: a prebuilt model of these scans (else built here); ``world_points``: {frame:
    float32 world points of the valid returns (N,3)} from the pass that built ``background``
    (:func:`background_and_segment`): scans that are :func:`surely_without_foreground` are written
    empty without reading them again (the same result). ``masks``: the :class:`InstanceMasks` of
    these scans (which another user may already have asked, ``holodata register``'s map: the masks
    it holds are not computed again); its scans, trajectory, background and world points are used
    instead of ``background`` / ``world_points``. Returns a summary {scene, frames,
    instances_per_scan, ...}."""
    import time

    from ...dataset import open_dataset

    cfg = cfg or SegmentConfig()
    t0 = time.perf_counter()
    sid = scene.id
    if masks is not None:
        scans, bg = masks.scans, masks.bg
    else:
        scans = LidarScans.open(scene, scene.ds.url)
        traj = scans.trajectory()
        if background is None:
            background, world_points = _background_pass(scans, cfg, traj, quiet, keep=True)
        bg = background
    sw = open_dataset(scene.ds.url, "r+").scene(sid)
    poses = pose_fingerprint(scene)
    if INSTANCE_ARRAY in sw.arrays() and (overwrite or instance_state(scene) == "stale"):
        sw.remove(INSTANCE_ARRAY)
    arr = sw.frame_array(INSTANCE_ARRAY, per_frame_shape=scans.shape,
                         attrs={"method": "voxel background + erosion seeds + Euclidean flood fill (Ouster OS0)",
                                "values": "0 = background or no return; 1..n instances by decreasing size",
                                "params": cfg.to_attrs(), "background_voxels": int(len(bg)), "poses_sha256": poses})
    counts = []
    masks = masks or InstanceMasks(scans, bg, cfg, traj, world_points or {})
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
