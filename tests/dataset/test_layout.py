"""The layout table (holodata.dataset.layout): consistent entries, validate checks against it
(shape, dtype, dims, units), and raytrace-gt creates its arrays from it."""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from _paths import REPO

from holodata.conventions import Grid, RangeBins
from holodata.dataset import create_dataset
from holodata.dataset.layout import GT_ARRAYS, LAYOUT, spec
from holodata.dataset.validate import expected_spec, validate_dataset

ROOT = REPO


def test_every_entry_is_consistent():
    for name, s in LAYOUT.items():
        assert s.name == name and s.kind in ("frame", "static", "ragged"), name
        assert s.dtype in s.dtypes and s.units and s.producer, name
        if s.kind == "frame":
            assert s.shape[0] == "T" and s.dims[0] == "frame" and len(s.dims) == len(s.shape), name
        elif s.kind == "static":
            assert len(s.dims) == len(s.shape), name
        else:                       # a row of values: (point, xyz) dims for width-w rows
            assert len(s.dims) == 2 and len(s.shape) == 1, name
    assert GT_ARRAYS == ("gt/range", "gt/normal", "gt/point", "gt/label", "gt/semantic", "gt/human_center")
    assert spec("pose/T_world_camera").shape == ("T", 4, 4) and spec("nope/x") is None


def test_expected_shapes_follow_the_grid_and_range_bins():
    g, rb = Grid(8, 32), RangeBins(128, 0.05)
    assert expected_spec("radar/heatmap", 5, g, rb) == ((5, 128, 8, 32), ("float16", "float32", "uint8"))
    assert expected_spec("gt/normal", 5, g, rb) == ((5, None, 8, 32, 3), ("float16", "float32"))
    assert expected_spec("gt/semantic", 5, g, rb) == ((5, None, 8, 32), ("uint8",))
    assert expected_spec("mesh/faces", 5, g, rb)[0] == (None, 3)
    assert expected_spec("camera/points", 5, g, rb) == (None, None)      # ragged: checked by its offsets


def test_raytrace_gt_creates_the_layout_s_arrays():
    from holodata.groundtruth import gt_array_specs

    specs = gt_array_specs(Grid(8, 32), 3)
    assert tuple(specs) == GT_ARRAYS
    for name, kw in specs.items():
        s = LAYOUT[name]
        assert kw["dtype"] == s.dtype and kw["dims"] == list(s.dims) and kw["units"] == s.units
    assert specs["gt/normal"]["per_frame_shape"] == (3, 8, 32, 3) and specs["gt/human_center"]["per_frame_shape"] == (1, 3)


def test_validate_names_an_array_whose_dims_or_units_are_not_the_layout_s(tmp_path):
    url = str(tmp_path / "d.zarr")
    g = Grid(8, 32)
    sc = create_dataset(url, grid=g, range_bins=RangeBins()).scene("s", n_frames=2)
    t = sc.frame_array("time/timestamp_ns", (), "int64", ["frame"], "ns")
    t.write_shard(0, np.array([1, 2], np.int64))
    r = sc.frame_array("gt/range", (3, 8, 32), "float32", ["frame", "bounce", "row", "col"], "cm")
    r.write_shard(0, np.full((2, 3, 8, 32), np.nan, np.float32))
    lab = sc.frame_array("gt/label", (3, 8, 32), "uint8", ["frame", "bounce", "elevation", "azimuth"], "1")
    lab.write_shard(0, np.zeros((2, 3, 8, 32), np.uint8))
    rep = validate_dataset(url)
    bad = [p for p in rep["problems"] if p["rule"] == "attrs"]
    assert [p["array"] for p in bad] == ["gt/range"] and "the layout has" in bad[0]["message"], rep["problems"]


def array_name_literals(path: Path) -> list[tuple[int, str]]:
    """(line, name) of every string constant in ``path``'s code that is an array name of the layout;
    docstrings (prose for the reader) are left out."""
    tree = ast.parse(path.read_text())
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in LAYOUT and id(n) not in docs]


def test_the_name_constants_follow_the_table():
    import holodata.dataset.layout as layout

    for name in LAYOUT:
        assert getattr(layout, name.upper().replace("/", "_")) == name and name.upper().replace("/", "_") in layout.__all__
    assert spec(layout.POSE_PREFIX + "camera").kind == "frame"
    for role in ("lidar", "camera"):
        assert layout.POINTS_OF[role] == f"{role}/points" and LAYOUT[layout.POINTS_OF[role]].kind == "ragged"
        assert layout.STAMPS_OF[role] == f"{role}/timestamp_ns" and LAYOUT[layout.STAMPS_OF[role]].units == "ns"


def test_no_array_name_is_spelled_outside_the_layout():
    files = [p for p in sorted((ROOT / "holodata").rglob("*.py")) if p != ROOT / "holodata/dataset/layout.py"]
    found = {str(p.relative_to(ROOT)): array_name_literals(p) for p in files}
    spelled = {f: hits for f, hits in found.items() if hits}
    assert not spelled, f"array names spelled outside holodata/dataset/layout.py (use its constants): {spelled}"


def _stored_facts(url: str, sid: str) -> dict:
    """{array name: (kind, dtype, dims, units, fill value or None, ragged width or None)} as stored."""
    import json

    from holodata.dataset import open_dataset

    sc = open_dataset(url).scene(sid)
    out = {}
    for name, (kind, meta) in sc.nodes().items():
        a = meta.get("attributes", {})
        if kind == "ragged":
            values = json.loads((Path(url) / "scenes" / sid / name / "values" / "zarr.json").read_text())
            out[name] = (kind, values["data_type"], a.get("dims"), a.get("units"), None, a["holodata"]["width"])
        else:
            fill = np.asarray(sc[name].fill_value) if kind == "frame" else None
            out[name] = (kind, meta["data_type"], a.get("dims"), a.get("units"), fill, None)
    return out


def _mismatches(facts: dict, strict_dtype: bool = True) -> list[str]:
    """The stored arrays whose kind, dtype, dims, units, fill value or ragged width is not their layout entry's."""
    kinds = {"frame": "frame", "static": "array", "ragged": "ragged"}
    bad = []
    for name, (kind, dt, dims, units, fill, width) in facts.items():
        s = spec(name)
        if s is None:
            bad.append(f"{name}: not in the layout")
            continue
        if kind != kinds[s.kind] or dims != list(s.dims) or units != s.units:
            bad.append(f"{name}: {kind} {dims} {units!r}, the layout has {s.kind} {list(s.dims)} {s.units!r}")
        if (dt != s.dtype) if strict_dtype else (dt not in s.dtypes):
            bad.append(f"{name}: dtype {dt}, the layout has {s.dtypes}")
        if fill is not None:
            want = np.asarray(s.fill if s.fill is not None else (np.nan if np.dtype(dt).kind == "f" else 0))
            if not (np.array_equal(fill, want) or (np.isnan(want).all() and np.isnan(fill).all())):
                bad.append(f"{name}: fill {fill}, the layout has {want}")
        if width is not None and width != s.shape[0]:
            bad.append(f"{name}: width {width}, the layout has {s.shape[0]}")
    return bad


def test_the_writer_makes_every_array_as_its_layout_entry_says(tmp_path):
    """Made from its name and sizes alone (a static array from float64 data), every array of the table
    has its entry's kind, dtype, dims, units, fill value and ragged width: the writer takes them from
    the layout, so a stage states none of them."""
    url = str(tmp_path / "d.zarr")
    sizes = {"T": 2, "R": 4, "H": 2, "W": 3, "B": 2, "K": 1}
    sc = create_dataset(url, grid=Grid(2, 3), range_bins=RangeBins(4, 0.1)).scene("s", n_frames=2)
    entries = {**LAYOUT, "pose/T_world_camera": spec("pose/T_world_camera")}
    for name, s in entries.items():
        shape = tuple(2 if d is None else d for d in s.resolve(**sizes))
        if s.kind == "frame":
            sc.frame_array(name, shape[1:])
        elif s.kind == "static":
            sc.write_array(name, np.ones(shape, np.float64))
        else:
            sc.ragged_array(name)
    facts = _stored_facts(url, "s")
    assert sorted(facts) == sorted(entries)
    assert _mismatches(facts) == []
    # what the check would catch: arrays written off the layout
    sc.remove("gt/range")
    sc.frame_array("gt/range", (2, 2, 3), dims=["frame", "bounce", "row", "col"], units="cm")
    sc.write_array("mesh/faces", np.ones((2, 3), np.int64), dtype="int64")
    assert [m.split(":")[0] for m in _mismatches(_stored_facts(url, "s"))] == ["gt/range", "mesh/faces"]


def test_the_toy_dataset_s_arrays_are_the_layout_s(tmp_path):
    from holodata.dataset.synthetic import write_toy_dataset

    url = write_toy_dataset(str(tmp_path / "toy.zarr"), n_frames=3)
    assert _mismatches(_stored_facts(url, "c1"), strict_dtype=False) == []


WRITER_CALLS = {"frame_array": 3, "ragged_array": 1, "write_array": 2}   # positional arguments a stage may give


def test_no_stage_states_dims_units_fill_or_width_of_its_own():
    """The writer calls in holodata/ (the CLI included) name the array and give its sizes or data (and a dtype
    where the layout allows several: the heatmap's float16 or float32): dims, units, fill values and
    ragged widths are the layout's, stated once (the writer takes them from it)."""
    found = []
    files = [p for p in sorted((ROOT / "holodata").rglob("*.py")) if p != ROOT / "holodata/dataset/writer.py"]
    for p in files:
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in WRITER_CALLS:
                stated = sorted({k.arg for k in n.keywords} & {"dims", "units", "fill_value", "width"})
                if len(n.args) > WRITER_CALLS[n.func.attr] or stated:
                    found.append(f"{p.relative_to(ROOT)}:{n.lineno} {n.func.attr} {stated or len(n.args)}")
    assert not found, f"writer calls stating what the layout states: {found}"
