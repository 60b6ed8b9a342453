"""The LiDAR half of :func:`~holodata.mapping.register.pipeline.register_scene` (step 2 and the
segmentation): the static map of the scene's scans without the LiDAR foreground and the segmented
people (:func:`map_cloud`), built with the background model and ``lidar/instance``
(:func:`lidar_map`), in a forked process beside the camera half (:func:`lidar_half`)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...dataset.layout import LIDAR_INSTANCE
from ...geometry.voxels import voxel_average
from ...parallel import fork_call
from .config import RegisterConfig
from .scene_inputs import scene_map


@dataclass
class MapInputs:
    """The scans :func:`map_cloud` builds the map from: ``scans`` (the scene's
    :class:`~holodata.mapping.segment.LidarScans`), their trajectory ``traj``, the background model
    ``bg`` (None: every return counts) and ``world_points``: {frame: world points of the valid returns
    (N,3)} already de-skewed with ``traj`` (the segmentation's background pass), or None."""

    scans: object
    bg: object
    traj: object
    world_points: dict | None = None


def map_cloud(inputs: MapInputs, voxel: float, deskew: bool = True, instances=None, margin_m: float = 0.25,
              max_scans: int = 0) -> np.ndarray:
    """World-frame static map of ``inputs`` (:class:`MapInputs`): every scan's returns inside the
    background model and farther than ``margin_m`` from the scan's segmented instances ``instances``
    (lazy (T,H,W) array or None), voxel-thinned; at most ``max_scans`` scans (0: all): motion keyframes
    plus scans spread in time, as for slam's mesh (a 400-cycle corner has 400 scans, most taken at
    rest). The instance margin removes the parts of people that fall into static voxels (a hand near a
    wall, feet on the floor), which would otherwise bias the registration. Scans in the inputs' world
    points without instances are taken from them instead of being read and de-skewed again."""
    from scipy.spatial import cKDTree

    from ..segment import in_background

    scans, bg, traj, world_points = inputs.scans, inputs.bg, inputs.traj, inputs.world_points
    pts = []
    ks = list(range(len(scans.stamps)))
    if max_scans and len(ks) > max_scans:  # long recordings: motion keyframes + scans evenly spread in time
        from ..slam import mesh_scan_subset

        ks = [k for k in ks if scans.usable(k)]
        ks = [ks[i] for i in mesh_scan_subset(np.asarray(scans.poses)[ks], max_scans)]
    for k in ks:
        inst = np.asarray(instances[k]) > 0 if instances is not None else None
        if world_points is not None and k in world_points and (inst is None or not inst.any()):
            p = np.asarray(world_points[k], np.float64)
        else:
            valid, _, Pw = scans.scan(k, traj, deskew)
            if inst is not None and (inst & valid).any():
                d, _ = cKDTree(Pw[inst & valid]).query(Pw[valid], k=1, distance_upper_bound=margin_m, workers=-1)
                keep = np.zeros_like(valid)
                keep[valid] = ~np.isfinite(d)
                valid = keep
            p = Pw[valid]
        if bg is not None and len(p):
            p = p[in_background(bg, p, 0)]
        if len(p):
            pts.append(voxel_average(p, voxel))
    if not pts:
        return np.zeros((0, 3))
    return voxel_average(np.concatenate(pts), voxel)


def lidar_map(scene, cfg: RegisterConfig, segment: bool, quiet: bool = True, build_map: bool = True,
              segment_cfg=None, early=None) -> tuple[np.ndarray | None, dict | None, dict]:
    """The LiDAR half of :func:`register_scene` (step 2 and the segmentation) of ``scene`` (a read
    handle; run in a forked process, which opens its own writers): background model,
    the static map (when ``build_map``) and, when ``segment``, ``lidar/instance``. The map is built
    first, with the instance masks of the few map scans that have foreground computed on the spot,
    and handed to ``early`` (a callback, or None) before the segmentation of every scan starts.
    Returns (map points (M,3) float64 world or None, segmentation summary or None, timings
    {background_s, map_s, segment_s})."""
    from ..segment import InstanceMasks, LidarScans, SegmentConfig, background_and_segment, write_instances

    t0 = time.perf_counter()
    scans = LidarScans.open(scene, scene.ds.url)
    traj = scans.trajectory()
    scfg = segment_cfg or SegmentConfig()
    bg, _, world_points = background_and_segment(scene, scfg, quiet, segment=False, scans=scans, traj=traj)
    t1 = time.perf_counter()
    if segment:
        inst = InstanceMasks(scans, bg, scfg, traj, world_points)
    else:
        inst = scene[LIDAR_INSTANCE] if LIDAR_INSTANCE in set(scene.arrays()) else None
    M = map_cloud(MapInputs(scans, bg, traj, world_points), cfg.map_voxel, instances=inst,
                  max_scans=cfg.map_max_scans) if build_map else None
    t2 = time.perf_counter()
    if early is not None:
        early(M)
    seg_summary = (write_instances(scene, scfg, quiet, masks=inst)
                   if segment else None)         # the masks the map asked for are not computed again
    return M, seg_summary, {"background_s": t1 - t0, "map_s": t2 - t1, "segment_s": time.perf_counter() - t2}



def lidar_half(scene, cfg: RegisterConfig, segment_cfg, processes: int, quiet: bool, where: str):
    """(slam's static map of ``scene`` or None, the forked :func:`lidar_map` or None): the LiDAR half
    runs when the scene needs ``lidar/instance`` (made with other poses: made again; left unfinished:
    resumed) or has no map of slam's to register against; with ``processes`` > 1 in a second process."""
    from ..segment import instance_state

    segment = cfg.segment_lidar and instance_state(scene) != "current"
    stored_map = scene_map(scene) if cfg.slam_map else None
    if not segment and stored_map is not None:
        return stored_map, None
    return stored_map, fork_call(lidar_map, scene, cfg, segment, quiet or processes > 1, stored_map is None, segment_cfg,
                                 label=f"{where}: LiDAR map", enabled=processes > 1, early=stored_map is None)
