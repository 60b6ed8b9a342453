"""The dataset layout as one table (docs/format.md §3): every array a scene can hold, its kind,
shape, dtypes, dimension names, units, the stage that writes it and the stages that need it.

``validate`` checks shapes and dtypes against it, and ``raytrace-gt`` creates its arrays from it.
A test (``tests/test_layout.py``) checks that every array the pipeline writes is in the table, with
the same dims, units and dtype.

Shapes are patterns over the symbols of the scene: ``T`` frames, ``R`` range bins, ``H``/``W``
the beam grid, ``B`` bounces, ``K`` humans; ``None`` = any length (sensor grids, point counts). For frame arrays
the pattern is the whole array, frame axis first; for ragged arrays it is one row of ``values``.
"""
from __future__ import annotations

from dataclasses import dataclass

NAN = float("nan")


@dataclass(frozen=True)
class ArraySpec:
    """One array of a scene. ``kind``: "frame" (frame axis first, sharded), "static" (no frame
    axis) or "ragged" (values + offsets per frame); ``shape``: pattern (module docstring);
    ``dtypes``: allowed dtypes, the first is what holodata writes; ``fill``: the "no data" value
    of a frame array; ``producer``: the stage that writes it; ``needed_by``: the stages that read it."""

    name: str
    kind: str
    shape: tuple
    dtypes: tuple[str, ...]
    dims: tuple[str, ...]
    units: str
    producer: str
    needed_by: tuple[str, ...] = ()
    fill: float | int | None = None

    @property
    def dtype(self) -> str:
        return self.dtypes[0]

    def resolve(self, **sizes) -> tuple:
        """The shape pattern with the symbols replaced by ``sizes`` (unknown symbols stay None)."""
        return tuple(sizes.get(s) if isinstance(s, str) else s for s in self.shape)

    def per_frame(self, **sizes) -> tuple:
        """The shape of one frame of a frame array (the pattern without its frame axis)."""
        return self.resolve(**sizes)[1:]


_GT = ("frame", "bounce", "elevation", "azimuth")
_POSE = ("frame", "row", "col")

LAYOUT: dict[str, ArraySpec] = {s.name: s for s in (
    ArraySpec("time/timestamp_ns", "frame", ("T",), ("int64",), ("frame",), "ns", "ingest",
              ("slam", "register", "raytrace-gt", "train")),
    ArraySpec("radar/heatmap", "frame", ("T", "R", "H", "W"), ("float16", "float32"),
              ("frame", "range", "elevation", "azimuth"), "1", "ingest", ("train", "evaluate"), 0.0),
    ArraySpec("radar/cycle_ns", "frame", ("T", 2), ("int64",), ("frame", "start_end"), "ns", "ingest",
              ("raytrace-gt", "evaluate")),
    ArraySpec("radar/iq", "frame", ("T", None, None, None), ("complex64",), ("frame", "chirp", "antenna", "sample"), "1",
              "ingest", ("beamform",), 0),
    ArraySpec("radar/iq_span", "frame", ("T", 3), ("int32",), ("frame", "before_rotation_after"), "chirp frames",
              "ingest", ("beamform",)),
    ArraySpec("radar/iq_motion", "frame", ("T", 2), ("float64",), ("frame", "ds0_heading"), "m, rad", "ingest",
              ("beamform",)),
    ArraySpec("radar/iq_static", "static", (None, None), ("complex64",), ("antenna", "sample"), "1", "ingest",
              ("beamform",)),
    ArraySpec("pose/T_world_radar", "frame", ("T", 4, 4), ("float64",), _POSE, "m", "ingest, slam",
              ("raytrace-gt", "evaluate"), NAN),
    ArraySpec("pose/T_world_lidar", "frame", ("T", 4, 4), ("float64",), _POSE, "m", "slam", ("register",), NAN),
    ArraySpec("tf/T_world_lidar", "frame", ("T", 4, 4), ("float64",), _POSE, "m", "ingest", ("slam",), NAN),
    ArraySpec("lidar/range", "frame", ("T", None, None), ("float32",), ("frame", "beam", "column"), "m", "ingest",
              ("slam", "segment"), NAN),
    ArraySpec("lidar/timestamp_ns", "frame", ("T",), ("int64",), ("frame",), "ns", "ingest", ("slam",)),
    ArraySpec("lidar/instance", "frame", ("T", None, None), ("uint16",), ("frame", "beam", "column"), "1", "segment",
              ("slam", "register"), 0),
    ArraySpec("lidar/points", "ragged", (3,), ("float32",), ("point", "xyz"), "m", "ingest", ("slam",)),
    ArraySpec("lidar/point_time_ns", "ragged", (1,), ("int64",), ("point", "time"), "ns", "ingest", ("slam",)),
    ArraySpec("camera/points", "ragged", (3,), ("float32",), ("point", "xyz"), "m", "ingest", ("register",)),
    ArraySpec("camera/points_world", "ragged", (3,), ("float32",), ("point", "xyz"), "m", "register"),
    ArraySpec("camera/timestamp_ns", "frame", ("T",), ("int64",), ("frame",), "ns", "ingest", ("register",)),
    ArraySpec("calib/T_world_camera", "static", (4, 4), ("float64",), ("row", "col"), "m", "register", ("view",)),
    ArraySpec("human/vertices", "ragged", (3,), ("float32",), ("vertex", "xyz"), "m", "register", ("raytrace-gt",)),
    ArraySpec("human/faces", "ragged", (3,), ("int32",), ("face", "corner"), "1", "register", ("raytrace-gt",)),
    ArraySpec("human/points", "ragged", (3,), ("float32",), ("point", "xyz"), "m", "register"),
    ArraySpec("mesh/vertices", "static", (None, 3), ("float32", "float64"), ("vertex", "xyz"), "m", "slam",
              ("raytrace-gt",)),
    ArraySpec("mesh/faces", "static", (None, 3), ("int32", "int64", "uint32"), ("face", "corner"), "1", "slam",
              ("raytrace-gt",)),
    ArraySpec("mesh/face_class", "static", (None,), ("uint8",), ("face",), "1", "slam", ("raytrace-gt",)),
    ArraySpec("map/points", "static", (None, 3), ("float32", "float64"), ("point", "xyz"), "m", "slam", ("register",)),
    ArraySpec("gt/range", "frame", ("T", "B", "H", "W"), ("float32",), _GT, "m", "raytrace-gt", ("train", "evaluate"),
              NAN),
    ArraySpec("gt/normal", "frame", ("T", "B", "H", "W", 3), ("float16", "float32"), _GT + ("xyz",), "1", "raytrace-gt",
              ("evaluate",), NAN),
    ArraySpec("gt/point", "frame", ("T", "B", "H", "W", 3), ("float32",), _GT + ("xyz",), "m", "raytrace-gt",
              ("evaluate",), NAN),
    ArraySpec("gt/label", "frame", ("T", "B", "H", "W"), ("uint8",), _GT, "1", "raytrace-gt", ("train", "evaluate"), 0),
    ArraySpec("gt/semantic", "frame", ("T", "B", "H", "W"), ("uint8",), _GT, "1", "raytrace-gt", (), 0),
    ArraySpec("gt/human_center", "frame", ("T", "K", 3), ("float32",), ("frame", "human", "xyz"), "m", "raytrace-gt",
              ("evaluate",), NAN),
)}

GT_ARRAYS = tuple(n for n, s in LAYOUT.items() if s.producer == "raytrace-gt")


def spec(name: str) -> ArraySpec | None:
    """The table's entry for ``name``; any ``pose/T_world_<sensor>`` is a pose (None: not in the layout)."""
    if name in LAYOUT:
        return LAYOUT[name]
    if name.startswith("pose/T_world_"):
        p = LAYOUT["pose/T_world_radar"]
        return ArraySpec(name, p.kind, p.shape, p.dtypes, p.dims, p.units, "slam", (), p.fill)
    return None


__all__ = ["ArraySpec", "LAYOUT", "GT_ARRAYS", "spec"]
