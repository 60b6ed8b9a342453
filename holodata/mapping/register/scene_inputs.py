"""What ``holodata register`` reads from a scene besides the camera and LiDAR arrays: slam's
products (poses' anchor, static map, mesh) when they were built from the poses the scene holds
now, the camera's static TF pose, whether the map lives in TF's world frame, the scene with a
camera, and ``--init``."""
from __future__ import annotations

import numpy as np

from ...dataset.layout import CAMERA_POINTS, MAP_POINTS, MESH_FACES, MESH_VERTICES, POSE_T_WORLD_LIDAR
from ...errors import InputError


def _parse_init(init) -> np.ndarray | None:
    if init is None:
        return None
    a = np.asarray(init, float)
    if a.shape == (4, 4):
        return a
    if a.shape == (6,):
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", np.deg2rad(a[3:])).as_matrix()
        T[:3, 3] = a[:3]
        return T
    raise InputError(f"--init needs x,y,z,roll,pitch,yaw (m, degrees), got {init!r}")


def _built_from_the_poses(scene, names: tuple) -> bool:
    """True when the scene holds the arrays ``names`` and each one's ``source`` attribute equals
    ``pose/T_world_lidar``'s (``holodata slam`` writes "slam" on its poses, mesh and map; poses
    replaced afterwards, e.g. by the true ones, leave products that no longer match them)."""
    nodes = scene.nodes()
    names = names + (POSE_T_WORLD_LIDAR,)
    if not all(n in nodes for n in names):
        return False
    src = [(nodes[n][1].get("attributes") or {}).get("source") for n in names]
    return src[0] is not None and len(set(src)) == 1


def slam_anchor(scene) -> np.ndarray | None:
    """(3,) m: the LiDAR position at the first scan when the scene's poses are ``holodata slam``'s,
    anchored at the TF pose of that scan (their world is the TF world, off by the odometry's error
    there); None otherwise."""
    nodes = scene.nodes()
    if POSE_T_WORLD_LIDAR not in nodes:
        return None
    if (nodes[POSE_T_WORLD_LIDAR][1].get("attributes") or {}).get("source") != "slam":
        return None
    anchor = (scene.attrs.get("slam") or {}).get("anchor") or {}
    T0 = anchor.get("T_world_lidar0")
    if anchor.get("kind") != "tf" or T0 is None:
        return None
    return np.asarray(T0, np.float64)[:3, 3]


def scene_mesh(scene) -> tuple[np.ndarray, np.ndarray] | None:
    """The scene's static mesh (``mesh/vertices`` (V,3), ``mesh/faces`` (F,3)) when it was built from
    the poses the scene holds now (:func:`_built_from_the_poses`); None otherwise."""
    if not _built_from_the_poses(scene, (MESH_VERTICES, MESH_FACES)):
        return None
    return np.asarray(scene[MESH_VERTICES][...], np.float64), np.asarray(scene[MESH_FACES][...], np.int64)


def scene_map(scene) -> np.ndarray | None:
    """slam's static map ``map/points`` (M,3) float64 world when it was built from the poses the scene
    holds now (:func:`_built_from_the_poses`); None otherwise."""
    if not _built_from_the_poses(scene, (MAP_POINTS,)):
        return None
    return np.asarray(scene[MAP_POINTS][...], np.float64)


def camera_tf_guess(scene) -> tuple[str | None, list | None]:
    """(world frame, T_world_camera 4x4 nested list) of the camera's static TF pose that ingest stored
    (``sensors.camera.T_<world>_sensor``); (None, None) without one."""
    cam = (scene.attrs.get("sensors") or {}).get("camera") or {}
    for k, v in cam.items():
        if k.startswith("T_") and k.endswith("_sensor") and v is not None:
            return k[2:-len("_sensor")], v
    return None, None


def map_frame_problem(scene, world: str) -> str | None:
    """Why the scene's LiDAR poses (``pose/T_world_lidar``, hence its map) are not in the TF frame
    ``world``, or None when they are: slam found no TF pose of the LiDAR (its world is then the
    first scan's frame: ``anchor`` base or lidar), or its poses name another world frame."""
    nodes = scene.nodes()
    if POSE_T_WORLD_LIDAR not in nodes:
        return None
    a = nodes[POSE_T_WORLD_LIDAR][1].get("attributes") or {}
    if a.get("source") == "slam" and a.get("anchor") not in (None, "tf"):
        return (f"the LiDAR map is in the {a.get('world_frame') or 'first scan frame'} (slam found no TF pose of "
                f"the LiDAR: TF does not connect its frame to {world!r})")
    wf = a.get("world_frame")
    if wf and (a.get("source") != "slam" or a.get("anchor") == "tf") and str(wf).lstrip("/") != world.lstrip("/"):
        return f"the LiDAR map is in {wf!r}"
    return None


def camera_scenes(ds) -> list[str]:
    """The scenes of dataset ``ds`` (a read handle) that have a camera (``camera/points``): the ones
    register can register. A mapping pass (LiDAR + odometry only, ``role: mapping``) has none."""
    return [sid for sid in ds.scenes if CAMERA_POINTS in set(ds.scene(sid).arrays())]


def only_camera_scene(ds, url: str) -> str:
    """The one scene of ``ds`` with a camera (:func:`camera_scenes`); InputError (one line) with none or
    several."""
    cams = camera_scenes(ds)
    if len(cams) == 1:
        return cams[0]
    if not cams:
        raise InputError(f"{url}: no scene has a camera (camera/points) to register; scenes: {', '.join(ds.scenes) or 'none'}")
    raise InputError(f"{url}: {len(cams)} scenes have a camera ({', '.join(cams)}); pick one with --scene")
