"""The dataset layout as one table (docs/format.md §3): every array a scene can hold, its kind,
shape, dtypes, dimension names, units, the stage that writes it and the stages that need it.

The dataset writer (:mod:`holodata.dataset.writer`) takes each array's dtype, dims, units, fill value
and ragged width from it, so the stages that create arrays name them and give their sizes, nothing
more; ``validate`` checks shapes, dtypes, dims and units against it, and ``raytrace-gt`` creates its
arrays from it. Tests (``tests/dataset/test_layout.py``) check that the writer makes every array as its entry
says and that no stage spells dims or units of its own.

The table is also the inventory ``validate`` checks a scene against: ``required_if`` names the
declarations (:data:`DECLARATIONS`: what a scene's attributes say it holds, e.g. ``sensors.radar``
written by ingest, ``gt`` by raytrace-gt, ``slam.complete`` by slam) any of which makes the array
mandatory; :func:`required_arrays` applies them to a scene's attributes.

Shapes are patterns over the symbols of the scene: ``T`` frames, ``R`` range bins, ``H``/``W``
the beam grid, ``B`` bounces, ``K`` humans; ``None`` = any length (sensor grids, point counts). For frame arrays
the pattern is the whole array, frame axis first; for ragged arrays it is one row of ``values``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

NAN = float("nan")


@dataclass(frozen=True)
class ArraySpec:
    """One array of a scene. ``kind``: "frame" (frame axis first, sharded), "static" (no frame
    axis) or "ragged" (values + offsets per frame); ``shape``: pattern (module docstring);
    ``dtypes``: allowed dtypes, the first is what holodata writes; ``fill``: the "no data" value
    of a frame array; ``producer``: the stage that writes it; ``needed_by``: the stages that read it;
    ``required_if``: the declarations (:data:`DECLARATIONS`) that make a scene hold it."""

    name: str
    kind: str
    shape: tuple
    dtypes: tuple[str, ...]
    dims: tuple[str, ...]
    units: str
    producer: str
    needed_by: tuple[str, ...] = ()
    fill: float | int | None = None
    required_if: tuple[str, ...] = ()

    @property
    def dtype(self) -> str:
        return self.dtypes[0]

    def resolve(self, **sizes) -> tuple:
        """The shape pattern with the symbols replaced by ``sizes`` (unknown symbols stay None)."""
        return tuple(sizes.get(s) if isinstance(s, str) else s for s in self.shape)

    def per_frame(self, **sizes) -> tuple:
        """The shape of one frame of a frame array (the pattern without its frame axis)."""
        return self.resolve(**sizes)[1:]


# The array names, one constant each, named by the rule path upper-cased and "/" -> "_" (RADAR_HEATMAP =
# "radar/heatmap"). The table below and every module that reads or writes an array use these: no name is
# spelled anywhere else in the package (tests/dataset/test_layout.py counts).
TIME_TIMESTAMP_NS = "time/timestamp_ns"
RADAR_HEATMAP = "radar/heatmap"
RADAR_CYCLE_NS = "radar/cycle_ns"
RADAR_IQ = "radar/iq"
RADAR_IQ_SPAN = "radar/iq_span"
RADAR_IQ_MOTION = "radar/iq_motion"
RADAR_IQ_STATIC = "radar/iq_static"
POSE_T_WORLD_RADAR = "pose/T_world_radar"
POSE_T_WORLD_LIDAR = "pose/T_world_lidar"
TF_T_WORLD_LIDAR = "tf/T_world_lidar"
LIDAR_RANGE = "lidar/range"
LIDAR_TIMESTAMP_NS = "lidar/timestamp_ns"
LIDAR_INSTANCE = "lidar/instance"
LIDAR_POINTS = "lidar/points"
LIDAR_POINT_TIME_NS = "lidar/point_time_ns"
CAMERA_POINTS = "camera/points"
CAMERA_POINTS_WORLD = "camera/points_world"
CAMERA_TIMESTAMP_NS = "camera/timestamp_ns"
CALIB_T_WORLD_CAMERA = "calib/T_world_camera"
HUMAN_VERTICES = "human/vertices"
HUMAN_FACES = "human/faces"
HUMAN_POINTS = "human/points"
MESH_VERTICES = "mesh/vertices"
MESH_FACES = "mesh/faces"
MESH_FACE_CLASS = "mesh/face_class"
MAP_POINTS = "map/points"
GT_RANGE = "gt/range"
GT_NORMAL = "gt/normal"
GT_POINT = "gt/point"
GT_LABEL = "gt/label"
GT_SEMANTIC = "gt/semantic"
GT_HUMAN_CENTER = "gt/human_center"
POSE_PREFIX = "pose/T_world_"       # pose/T_world_<sensor>: any sensor's poses (spec())
# the point cloud and the frame stamps of each point sensor (ingest's roles)
POINTS_OF = {"lidar": LIDAR_POINTS, "camera": CAMERA_POINTS}
STAMPS_OF = {"lidar": LIDAR_TIMESTAMP_NS, "camera": CAMERA_TIMESTAMP_NS}


_GT = ("frame", "bounce", "elevation", "azimuth")
_POSE = ("frame", "row", "col")

LAYOUT: dict[str, ArraySpec] = {s.name: s for s in (
    ArraySpec(TIME_TIMESTAMP_NS, "frame", ("T",), ("int64",), ("frame",), "ns", "ingest",
              ("slam", "register", "raytrace-gt", "train"), required_if=("scene",)),
    ArraySpec(RADAR_HEATMAP, "frame", ("T", "R", "H", "W"), ("float16", "float32", "uint8"),
              ("frame", "range", "elevation", "azimuth"), "1", "ingest", ("train", "evaluate"), NAN,
              required_if=("radar",)),
    ArraySpec(RADAR_CYCLE_NS, "frame", ("T", 2), ("int64",), ("frame", "start_end"), "ns", "ingest",
              ("raytrace-gt", "evaluate"), required_if=("radar",)),
    ArraySpec(RADAR_IQ, "frame", ("T", None, None, None), ("complex64",), ("frame", "chirp", "antenna", "sample"), "1",
              "ingest", ("beamform",), 0),
    ArraySpec(RADAR_IQ_SPAN, "frame", ("T", 3), ("int32",), ("frame", "before_rotation_after"), "chirp frames",
              "ingest", ("beamform",)),
    ArraySpec(RADAR_IQ_MOTION, "frame", ("T", 2), ("float64",), ("frame", "ds0_heading"), "m, rad", "ingest",
              ("beamform",)),
    ArraySpec(RADAR_IQ_STATIC, "static", (None, None), ("complex64",), ("antenna", "sample"), "1", "ingest",
              ("beamform",)),
    ArraySpec(POSE_T_WORLD_RADAR, "frame", ("T", 4, 4), ("float64",), _POSE, "m", "ingest, slam",
              ("raytrace-gt", "evaluate"), NAN, required_if=("gt", "synth")),
    ArraySpec(POSE_T_WORLD_LIDAR, "frame", ("T", 4, 4), ("float64",), _POSE, "m", "slam", ("register",), NAN,
              required_if=("slam",)),
    ArraySpec(TF_T_WORLD_LIDAR, "frame", ("T", 4, 4), ("float64",), _POSE, "m", "ingest", ("slam",), NAN),
    ArraySpec(LIDAR_RANGE, "frame", ("T", None, None), ("float32",), ("frame", "beam", "column"), "m", "ingest",
              ("slam", "segment"), NAN),
    ArraySpec(LIDAR_TIMESTAMP_NS, "frame", ("T",), ("int64",), ("frame",), "ns", "ingest", ("slam",),
              required_if=("lidar",)),
    ArraySpec(LIDAR_INSTANCE, "frame", ("T", None, None), ("uint16",), ("frame", "beam", "column"), "1", "segment",
              ("slam", "register"), 0),
    ArraySpec(LIDAR_POINTS, "ragged", (3,), ("float32",), ("point", "xyz"), "m", "ingest", ("slam",),
              required_if=("lidar",)),
    ArraySpec(LIDAR_POINT_TIME_NS, "ragged", (1,), ("int64",), ("point", "time"), "ns", "ingest", ("slam",)),
    ArraySpec(CAMERA_POINTS, "ragged", (3,), ("float32",), ("point", "xyz"), "m", "ingest", ("register",),
              required_if=("camera",)),
    ArraySpec(CAMERA_POINTS_WORLD, "ragged", (3,), ("float32",), ("point", "xyz"), "m", "register"),
    ArraySpec(CAMERA_TIMESTAMP_NS, "frame", ("T",), ("int64",), ("frame",), "ns", "ingest", ("register",),
              required_if=("camera",)),
    ArraySpec(CALIB_T_WORLD_CAMERA, "static", (4, 4), ("float64",), ("row", "col"), "m", "register", ("view",),
              required_if=("register",)),
    ArraySpec(HUMAN_VERTICES, "ragged", (3,), ("float32",), ("vertex", "xyz"), "m", "register", ("raytrace-gt",),
              required_if=("register", "synth")),
    ArraySpec(HUMAN_FACES, "ragged", (3,), ("int32",), ("face", "corner"), "1", "register", ("raytrace-gt",),
              required_if=("register", "synth")),
    ArraySpec(HUMAN_POINTS, "ragged", (3,), ("float32",), ("point", "xyz"), "m", "register",
              required_if=("register",)),
    ArraySpec(MESH_VERTICES, "static", (None, 3), ("float32", "float64"), ("vertex", "xyz"), "m", "slam",
              ("raytrace-gt",), required_if=("slam_mesh", "gt", "synth")),
    ArraySpec(MESH_FACES, "static", (None, 3), ("int32", "int64", "uint32"), ("face", "corner"), "1", "slam",
              ("raytrace-gt",), required_if=("slam_mesh", "gt", "synth")),
    ArraySpec(MESH_FACE_CLASS, "static", (None,), ("uint8",), ("face",), "1", "slam", ("raytrace-gt",),
              required_if=("synth",)),
    ArraySpec(MAP_POINTS, "static", (None, 3), ("float32", "float64"), ("point", "xyz"), "m", "slam", ("register",)),
    ArraySpec(GT_RANGE, "frame", ("T", "B", "H", "W"), ("float32",), _GT, "m", "raytrace-gt", ("train", "evaluate"),
              NAN, required_if=("gt",)),
    ArraySpec(GT_NORMAL, "frame", ("T", "B", "H", "W", 3), ("float16", "float32"), _GT + ("xyz",), "1", "raytrace-gt",
              ("evaluate",), NAN, required_if=("gt",)),
    ArraySpec(GT_POINT, "frame", ("T", "B", "H", "W", 3), ("float32",), _GT + ("xyz",), "m", "raytrace-gt",
              ("evaluate",), NAN, required_if=("gt",)),
    ArraySpec(GT_LABEL, "frame", ("T", "B", "H", "W"), ("uint8",), _GT, "1", "raytrace-gt", ("train", "evaluate"), 0,
              required_if=("gt",)),
    ArraySpec(GT_SEMANTIC, "frame", ("T", "B", "H", "W"), ("uint8",), _GT, "1", "raytrace-gt", (), 0,
              required_if=("gt",)),
    ArraySpec(GT_HUMAN_CENTER, "frame", ("T", "K", 3), ("float32",), ("frame", "human", "xyz"), "m", "raytrace-gt",
              ("evaluate",), NAN, required_if=("gt",)),
)}

GT_ARRAYS = tuple(n for n, s in LAYOUT.items() if s.producer == "raytrace-gt")


def _attr(attrs: dict, key: str) -> dict:
    v = attrs.get(key)
    return v if isinstance(v, dict) else {}


def _slam_done(attrs: dict) -> bool:
    """slam's record of a finished run: ``complete`` with the fingerprint it resumes by."""
    slam = _attr(attrs, "slam")
    return slam.get("complete") is True and "fingerprint" in slam


# What a scene declares -> (does it, given the scene attributes; the words validate prints). The writers
# record these: ingest ``frame_sensor`` and ``sensors.<role>`` (one per sensor it decoded), slam
# ``slam`` = {complete, fingerprint, mesh_config (its mesh; None without), ...} when it finishes,
# register its report ``register``, raytrace-gt ``gt`` = {backend, max_bounces, ...} (how it traced; set
# before its first GT shard; slam's rerun drops the GT arrays and leaves it: raytrace-gt again),
# ``synth --corners`` its corner summary ``synth``. The table's ``required_if`` names them.
DECLARATIONS: dict[str, tuple[Callable[[dict], bool], str]] = {
    "scene": (lambda a: True, "every scene needs frame timestamps"),
    "radar": (lambda a: "radar" in _attr(a, "sensors"), "the scene declares a radar (attrs sensors.radar)"),
    "lidar": (lambda a: "lidar" in _attr(a, "sensors") or a.get("frame_sensor") == "lidar",
              "the scene declares a LiDAR (attrs sensors.lidar / frame_sensor)"),
    "camera": (lambda a: "camera" in _attr(a, "sensors") or a.get("frame_sensor") == "camera",
               "the scene declares a camera (attrs sensors.camera / frame_sensor)"),
    "gt": (lambda a: "max_bounces" in _attr(a, "gt"), "the scene declares ray-traced ground truth (attrs gt): "
                                           "rerun holodata raytrace-gt"),
    "slam": (_slam_done, "the scene declares slam finished (attrs slam.complete)"),
    "slam_mesh": (lambda a: _slam_done(a) and bool(_attr(a, "slam").get("mesh_config")),
                  "the scene declares a slam mesh (attrs slam.mesh_config)"),
    "register": (lambda a: bool(_attr(a, "register")), "the scene declares register finished (attrs register)"),
    "synth": (lambda a: bool(_attr(a, "synth")), "the scene declares a synthetic corner (attrs synth)"),
}


def required_arrays(attrs: dict) -> dict[str, str]:
    """{array name: why} of the arrays a scene with attributes ``attrs`` must hold: the table's
    entries whose ``required_if`` names a declaration the attributes make (the first one's words)."""
    made = {k: words for k, (test, words) in DECLARATIONS.items() if test(attrs)}
    out = {}
    for name, s in LAYOUT.items():
        why = [made[d] for d in s.required_if if d in made]
        if why:
            out[name] = why[0]
    return out


def spec(name: str) -> ArraySpec | None:
    """The table's entry for ``name``; any ``pose/T_world_<sensor>`` is a pose (None: not in the layout)."""
    if name in LAYOUT:
        return LAYOUT[name]
    if name.startswith(POSE_PREFIX):
        p = LAYOUT[POSE_T_WORLD_RADAR]
        return ArraySpec(name, p.kind, p.shape, p.dtypes, p.dims, p.units, "slam", (), p.fill)
    return None


__all__ = ["ArraySpec", "LAYOUT", "GT_ARRAYS", "DECLARATIONS", "required_arrays", "POSE_PREFIX", "POINTS_OF",
           "STAMPS_OF", "spec", "TIME_TIMESTAMP_NS",
           "RADAR_HEATMAP", "RADAR_CYCLE_NS", "RADAR_IQ", "RADAR_IQ_SPAN", "RADAR_IQ_MOTION", "RADAR_IQ_STATIC",
           "POSE_T_WORLD_RADAR", "POSE_T_WORLD_LIDAR", "TF_T_WORLD_LIDAR", "LIDAR_RANGE", "LIDAR_TIMESTAMP_NS",
           "LIDAR_INSTANCE", "LIDAR_POINTS", "LIDAR_POINT_TIME_NS", "CAMERA_POINTS", "CAMERA_POINTS_WORLD",
           "CAMERA_TIMESTAMP_NS", "CALIB_T_WORLD_CAMERA", "HUMAN_VERTICES", "HUMAN_FACES", "HUMAN_POINTS",
           "MESH_VERTICES", "MESH_FACES", "MESH_FACE_CLASS", "MAP_POINTS", "GT_RANGE", "GT_NORMAL", "GT_POINT",
           "GT_LABEL", "GT_SEMANTIC", "GT_HUMAN_CENTER"]
