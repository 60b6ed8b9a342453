"""What slam writes into a scene and reads back: the inputs' and settings' fingerprint, a finished
scene's result, the poses, the static map and the ``slam`` attribute."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...dataset.layout import (
    LIDAR_POINTS,
    LIDAR_TIMESTAMP_NS,
    MAP_POINTS,
    MESH_FACE_CLASS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_LIDAR,
    POSE_T_WORLD_RADAR,
    TIME_TIMESTAMP_NS,
)
from .config import SlamConfig, SlamResult

# The version of slam's method, in the fingerprint: raised with every deliberate change of slam's output
# (its settings unchanged), so that scenes mapped by the older method are mapped again instead of read
# as done. 2: scans deskewed to and registered at the middle of their sweep (docs/design/slam.md).
METHOD_VERSION = 2

# Settings added after datasets were mapped (inline constants made settings): left out of
# the fingerprint at their default, so a scene mapped before still reads as done.
ADDED_SETTINGS = ("scan_normal_radius", "scan_normal_nn", "map_normal_radius", "map_normal_nn")


def fingerprint_settings(attrs: dict, added, defaults) -> dict:
    """``attrs`` (a config's ``to_attrs()``) less the fields in ``added`` that hold their value in
    ``defaults`` (the config class): what a fingerprint hashes, the same as before those fields existed."""
    return {k: v for k, v in attrs.items() if not (k in added and v == getattr(defaults, k))}


def _fingerprint(scene, cfg: SlamConfig, mesh_cfg) -> str:
    import hashlib
    import json

    h = hashlib.sha256(json.dumps({"slam": fingerprint_settings(cfg.to_attrs(), ADDED_SETTINGS, SlamConfig),
                                   "mesh": mesh_cfg.to_attrs() if mesh_cfg else None, "method": METHOD_VERSION},
                                  sort_keys=True).encode())
    for name in (LIDAR_POINTS, LIDAR_TIMESTAMP_NS, TIME_TIMESTAMP_NS):
        if name in scene:
            node = scene.nodes()[name][1]
            h.update(json.dumps(node.get("attributes", {}).get("holodata", {}).get("shards"), sort_keys=True).encode())
    return h.hexdigest()[:16]


def _stored_result(scene, done: dict) -> SlamResult:
    """A finished scene's result read back from the dataset (no recomputation; no kiss-icp poses)."""
    Tl = np.asarray(scene[POSE_T_WORLD_LIDAR][...], np.float64)
    Tr = np.asarray(scene[POSE_T_WORLD_RADAR][...], np.float64) if POSE_T_WORLD_RADAR in scene else None
    names = set(scene.arrays())
    st = np.asarray(scene[LIDAR_TIMESTAMP_NS][...] if LIDAR_TIMESTAMP_NS in names else scene[TIME_TIMESTAMP_NS][...],
                    np.int64)
    _, first = np.unique(st, return_index=True)
    first = np.sort(first[st[first] > 0])
    mesh = None
    if MESH_FACES in names:
        mesh = (np.asarray(scene[MESH_VERTICES][...], np.float32), np.asarray(scene[MESH_FACES][...], np.int32))
    summary = dict(done.get("summary") or {})
    summary["skipped"] = "already done with the same inputs and settings (use --force to recompute)"
    points = np.asarray(scene[MAP_POINTS][...], np.float64) if MAP_POINTS in names else None
    return SlamResult(scene.id, st[first], Tl[first], None, None, Tl, Tr, mesh, summary, points)


@dataclass
class SlamRecord:
    """What :func:`_write` records of a run besides its result: the settings ``config`` and
    ``mesh_config``, the world frame's ``anchor`` (:func:`~.world.anchor_pose`'s info), the inputs'
    and settings' ``fingerprint``, the per-frame poses' ``frames_info`` (:func:`~.world.frame_poses`:
    its ``T_lidar_radar``) and ``mode``: the localisation's {mode, map_scene}, None for SLAM proper."""

    config: SlamConfig
    mesh_config: object
    anchor: dict
    fingerprint: str
    frames_info: dict
    mode: dict | None = None


def _write(url, ds, res: SlamResult, record: SlamRecord) -> None:
    """Write ``res`` into its scene of the dataset at ``url`` (``ds`` its reader): the poses, the static
    map and the ``slam`` attribute (``record``); ray-traced ground truth made from the previous poses
    removed."""
    from ...dataset import open_dataset

    scene_id, cfg, mesh_cfg, anchor = res.scene, record.config, record.mesh_config, record.anchor
    finfo, fp, mode = record.frames_info, record.fingerprint, record.mode
    meta = ds.meta
    w = open_dataset(url, "r+", created_by="holodata slam", shard_frames=int(meta.get("shard_frames") or 32))
    sc = w.scene(scene_id)
    prev = sc.attrs.get("slam") or {}
    # marked unfinished before the first write (a crash below must not look done), finished with the
    # ``slam`` attribute after the last
    sc.begin("slam", rerun=f"rerun holodata slam DATASET --scene {scene_id} to finish it",
             attrs={"slam": {**prev, "complete": False}} if prev.get("complete") else None)
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
    arrays = [(POSE_T_WORLD_LIDAR, res.T_world_lidar, {"time": "lidar/timestamp_ns (time/timestamp_ns when 0)"})]
    if res.T_world_radar is not None:
        arrays.append((POSE_T_WORLD_RADAR, res.T_world_radar, {"time": TIME_TIMESTAMP_NS,
                                                                 "T_lidar_radar": finfo.get("T_lidar_radar")}))
    for name, P, extra in arrays:
        if name in names:
            sc.remove(name)
        a = sc.frame_array(name, per_frame_shape=(4, 4), attrs={**pose_attrs, **extra})
        for k in range(a.n_shards):
            a.write_shard(k, P[a.frames(k)])
    if res.mesh is not None:
        if MESH_FACE_CLASS in names:
            sc.remove(MESH_FACE_CLASS)
        write_static_map(sc, res.mesh[0], res.mesh[1], res.map_points, "slam")
    sc.finish("slam", {"slam": {"complete": True, "fingerprint": fp, "config": cfg.to_attrs(),
                                "mesh_config": mesh_cfg.to_attrs() if cfg.mesh else None,
                                "anchor": anchor, "summary": json_safe(res.summary), **(mode or {})}})


def write_static_map(sc, vertices: np.ndarray, faces: np.ndarray, points: np.ndarray | None, source: str) -> None:
    """Write a :class:`StaticMap`'s ``mesh/vertices``, ``mesh/faces`` and (when given) ``map/points``
    (M,3) float32 into the scene writer ``sc``, each with the ``source`` of the poses they were built
    from: ``holodata register`` uses them only while that matches ``pose/T_world_lidar``'s."""
    sc.write_array(MESH_VERTICES, vertices, attrs={"source": source, "frame": "world"})
    sc.write_array(MESH_FACES, faces, attrs={"source": source})
    if points is not None:
        sc.write_array(MAP_POINTS, points, attrs={"source": source, "frame": "world",
                              "what": "static LiDAR returns averaged per mesh voxel (the mesh's input)"})
    elif MAP_POINTS in sc.arrays():
        sc.remove(MAP_POINTS)


def json_safe(obj):
    import json

    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
