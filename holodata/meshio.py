"""Triangle mesh files: read PLY / OBJ / STL, write PLY with a per-face class.

PLY: ascii, binary_little_endian and binary_big_endian; vertex ``x y z``; faces from the
``vertex_indices`` (or ``vertex_index``) list, polygons fan-triangulated; a scalar face
property named ``label``, ``class``, ``semantic``, ``face_class`` or ``category`` becomes
``Mesh.face_class``. Class names come from ``comment class <id> <name>`` header lines (what
:func:`write_ply` writes). OBJ: ``v`` and ``f`` records (``f a/b/c ...``, negative indices),
``usemtl``/``g`` names become face classes when present. STL: ascii or binary.

What trimesh does and what stays here (docs/design/meshio.md has the checks behind each point):

- PLY reading: trimesh (``trimesh.exchange.ply.load_ply``) parses the header and the element data
  of all three formats; holodata takes the face property from its ``metadata['_ply_raw']``. Kept
  here: the ``comment class`` lines (trimesh's header parser drops comments), the polygon fan with
  the source polygon of each triangle (trimesh's ``triangulate_quads`` does not say it, so a face
  label could not follow), a row count check (trimesh accepts a truncated ascii PLY silently) and
  :func:`_ply_binary_records` for binary faces of mixed polygon sizes (trimesh sizes a list from the
  first record and rejects the file).
- STL reading: trimesh; the shared vertices of its triangle soup are merged here.
- OBJ reading stays here: trimesh splits an OBJ by material into a scene, drops the ``g``/``usemtl``
  names and reorders fan triangles, so face classes would not survive.
- PLY writing stays here: trimesh's ``export_ply`` writes another header (its own comment, no class
  comments, other property types), so the files holodata has written would change bytes.
"""
from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError

FACE_CLASS_PROPERTIES = ("label", "class", "semantic", "face_class", "category")

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


@dataclass
class Mesh:
    """``vertices`` (V,3) float64 m; ``faces`` (F,3) int32; ``face_class`` (F,) uint8 or None;
    ``class_names`` {id: name} for the ids in ``face_class``."""

    vertices: np.ndarray
    faces: np.ndarray
    face_class: np.ndarray | None = None
    class_names: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int32).reshape(-1, 3)
        if self.face_class is not None:
            self.face_class = np.asarray(self.face_class, dtype=np.uint8).reshape(-1)


def merge_meshes(parts) -> tuple[np.ndarray, np.ndarray]:
    """One triangle soup from ``parts`` [(vertices (Vi,3), faces (Fi,3)), ...]: vertices stacked,
    faces re-indexed by each part's vertex offset (int64)."""
    vs, fs, n = [], [], 0
    for v, f in parts:
        vs.append(np.asarray(v))
        fs.append(np.asarray(f, dtype=np.int64).reshape(-1, 3) + n)
        n += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def read_mesh(path: str | Path) -> Mesh:
    """Read a PLY, OBJ or STL triangle mesh, or a directory holding one mesh file per class
    (``floor.ply``, ``wall.obj``, ...: class ids 1.. in file-name order, names from the file stems).
    Raises InputError (naming the file) if it cannot be read, has no triangles, non-finite vertices
    or out-of-range face indices."""
    path = Path(path)
    if path.is_dir():
        return _read_class_dir(path)
    ext = path.suffix.lower()
    readers = {".ply": _read_ply, ".obj": _read_obj, ".stl": _read_stl}
    if ext not in readers:
        raise InputError(f"{path}: unsupported mesh format {ext!r} (use .ply, .obj or .stl)")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise InputError(f"{path}: cannot read mesh ({err.strerror or err})") from err
    try:
        mesh = readers[ext](data)
    except InputError as err:
        raise InputError(f"{path}: {err}") from err
    except Exception as err:  # noqa: BLE001 - any parse failure is a bad file
        raise InputError(f"{path}: malformed {ext[1:].upper()} mesh ({err})") from err
    if len(mesh.faces) == 0:
        raise InputError(f"{path}: mesh has no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError(f"{path}: mesh has non-finite vertex coordinates")
    if mesh.faces.min() < 0 or mesh.faces.max() >= len(mesh.vertices):
        raise InputError(f"{path}: face index out of range (mesh has {len(mesh.vertices)} vertices)")
    return mesh


def _read_class_dir(path: Path) -> Mesh:
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".ply", ".obj", ".stl"))
    if not files:
        raise InputError(f"{path}: directory holds no .ply/.obj/.stl meshes")
    if len(files) > 255:
        raise InputError(f"{path}: more than 255 class meshes")
    vs, fs, cs, n = [], [], [], 0
    for k, p in enumerate(files, start=1):
        m = read_mesh(p)
        vs.append(m.vertices)
        fs.append(m.faces + n)
        cs.append(np.full(len(m.faces), k, np.uint8))
        n += len(m.vertices)
    return Mesh(np.concatenate(vs), np.concatenate(fs), np.concatenate(cs), {k: p.stem for k, p in enumerate(files, 1)})


def write_ply(path: str | Path, mesh: Mesh, binary: bool = True) -> None:
    """Write ``mesh`` as PLY (binary little endian by default): float vertices, int faces and,
    if ``mesh.face_class`` is set, a ``uchar label`` face property plus ``comment class <id> <name>``."""
    v = np.asarray(mesh.vertices, dtype="<f8")
    f = np.asarray(mesh.faces, dtype="<i4")
    fc = mesh.face_class
    lines = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "comment written by holodata"]
    for k, name in sorted(mesh.class_names.items()):
        lines.append(f"comment class {int(k)} {str(name).replace(' ', '_')}")
    lines += [f"element vertex {len(v)}", "property double x", "property double y", "property double z",
              f"element face {len(f)}", "property list uchar int vertex_indices"]
    if fc is not None:
        lines.append("property uchar label")
    lines.append("end_header")
    header = ("\n".join(lines) + "\n").encode("ascii")
    if binary:
        fields = [("n", "u1"), ("idx", "<i4", (3,))] + ([("label", "u1")] if fc is not None else [])
        rec = np.zeros(len(f), dtype=fields)
        rec["n"] = 3
        rec["idx"] = f
        if fc is not None:
            rec["label"] = fc
        body = v.tobytes() + rec.tobytes()
    else:
        vt = "\n".join(" ".join(repr(float(c)) for c in row) for row in v)
        ft = [f"3 {a} {b} {c}" for a, b, c in f]
        if fc is not None:
            ft = [s + f" {int(k)}" for s, k in zip(ft, fc)]
        body = (vt + "\n" + "\n".join(ft) + "\n").encode("ascii")
    Path(path).write_bytes(header + body)


# ---------------------------------------------------------------- PLY
def _read_ply(data: bytes) -> Mesh:
    """PLY via trimesh's parser (header, ascii and binary element data of either byte order), then
    holodata's part: class comments, the face class property and the polygon fan (module docstring).
    Binary files whose lists all have one length are read without trimesh (:func:`_ply_binary_fixed`)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError("not a PLY file (missing 'ply' magic or 'end_header')")
    header = data[:end].decode("ascii", "replace").splitlines()
    fmt = next((t[1] for t in (line.split() for line in header) if len(t) > 1 and t[0] == "format"), None)
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"unsupported PLY format {fmt!r}")
    class_names = {int(t[2]): " ".join(t[3:]) for t in (line.split() for line in header)
                   if len(t) >= 4 and t[0] == "comment" and t[1] == "class"}
    elements = None
    if fmt != "ascii":  # the common binary layout without trimesh (slow to import: docs/design/raytrace.md)
        elements = _ply_binary_fixed(data[data.find(b"\n", end) + 1:], header,
                                     "<" if fmt.endswith("little_endian") else ">")
    try:
        if elements is None:
            from trimesh.exchange.ply import load_ply

            elements = load_ply(io.BytesIO(data), fix_texture=False, skip_materials=True)["metadata"]["_ply_raw"]
    except ValueError as err:
        # trimesh sizes a binary list element from its first record: faces of mixed sizes end here
        if fmt == "ascii" or "list" not in data[:end].decode("ascii", "replace"):
            raise
        body = data[data.find(b"\n", end) + 1:]
        elements = _ply_binary_records(body, header, "<" if fmt.endswith("little_endian") else ">")
        if elements is None:
            raise InputError(f"binary PLY body does not match its header ({err})") from err
    cols = {name: _ply_columns(el) for name, el in elements.items()}
    for name, el in elements.items():
        n = {len(c) for c in cols[name].values()}
        if el["length"] and n != {el["length"]}:
            raise InputError(f"PLY element {name!r} truncated ({min(n, default=0)} of {el['length']} rows)")
    if "vertex" not in cols:
        raise InputError("PLY has no vertex element")
    vert = cols["vertex"]
    vertices = np.stack([np.asarray(vert[c], dtype=np.float64).reshape(-1) for c in ("x", "y", "z")], axis=1)
    face = cols.get("face", {})
    lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        return Mesh(vertices, np.zeros((0, 3), np.int32))
    cls = next((face[p] for p in FACE_CLASS_PROPERTIES if p in face), None)
    tris, owner = _fan(lists)
    face_class = None if cls is None else np.asarray(cls).reshape(-1)[owner].astype(np.uint8)
    if face_class is not None and not class_names:
        class_names = {int(k): f"class_{int(k)}" for k in np.unique(face_class)}
    return Mesh(vertices, tris, face_class, class_names)


def _ply_columns(element: dict) -> dict:
    """One element of trimesh's ``_ply_raw`` -> {property: column}: scalars (N,) arrays, lists an
    (N,k) array or a list of N index arrays. trimesh gives binary data as a structured array (a list
    as a (count, values) pair) and ascii data as a dict with scalars as (N,1) columns."""
    data = element.get("data")
    if data is None:
        return {name: np.zeros(0) for name in element["properties"]}
    if isinstance(data, dict):
        return {k: (v if "$LIST" in str(element["properties"][k]) else np.asarray(v).reshape(-1))
                for k, v in data.items()}
    return {k: (data[k]["f1"] if data.dtype[k].names else data[k]) for k in data.dtype.names}


def _fan(lists) -> tuple[np.ndarray, np.ndarray]:
    """Polygons (list of index arrays, or (F,k) array) -> triangles (F',3) and source polygon index."""
    if isinstance(lists, np.ndarray) and lists.ndim == 2:
        k = lists.shape[1]
        if k == 3:
            return lists.astype(np.int32), np.arange(len(lists))
        tri = np.concatenate([np.stack([lists[:, 0], lists[:, i], lists[:, i + 1]], 1) for i in range(1, k - 1)])
        owner = np.concatenate([np.arange(len(lists))] * (k - 2))
        return tri.astype(np.int32), owner
    tris: list[tuple] = []
    owners: list[int] = []
    for n, poly in enumerate(lists):
        for i in range(1, len(poly) - 1):
            tris.append((poly[0], poly[i], poly[i + 1]))
            owners.append(n)
    return np.asarray(tris, dtype=np.int32).reshape(-1, 3), np.asarray(owners, dtype=np.int64)


def _ply_binary_fixed(body: bytes, header: list[str], order: str) -> dict | None:
    """Binary PLY elements read whole with one numpy record type each, when every list property
    has the same length in every record (triangle meshes): trimesh's ``_ply_raw`` shape with lists
    as (N, k) arrays, the values trimesh's reader gives. None for anything else (empty or
    mixed-length lists, a body shorter or longer than the header says): the caller reads those
    with trimesh."""
    out, pos = {}, 0
    try:
        for name, count, props in _ply_elements(header):
            fields, at = [], pos
            for p in props:
                if p[1] == "list":
                    if count == 0:
                        return None
                    k = int(np.frombuffer(body, order + p[2], 1, at)[0])
                    fields += [(p[0] + "#n", order + p[2]), (p[0], order + p[3], (k,))]
                    at += np.dtype(p[2]).itemsize + np.dtype(p[3]).itemsize * k
                else:
                    fields.append((p[0], order + p[1]))
                    at += np.dtype(p[1]).itemsize
            rec = np.frombuffer(body, np.dtype(fields), count, pos)
            for p in props:
                if p[1] == "list" and np.any(rec[p[0] + "#n"] != rec[p[0]].shape[1]):
                    return None
            pos += rec.dtype.itemsize * count
            out[name] = {"length": count, "properties": {p[0]: "$LIST" if p[1] == "list" else p[1] for p in props},
                         "data": {p[0]: rec[p[0]] for p in props}}
    except (ValueError, KeyError, IndexError):
        return None
    return out if pos == len(body) else None


def _ply_elements(header: list[str]) -> list[tuple[str, int, list[tuple]]]:
    """[(element name, count, [(property, type) | (property, "list", count type, value type)])] of a PLY header."""
    elements: list[tuple[str, int, list[tuple]]] = []
    for tok in (line.split() for line in header):
        if tok and tok[0] == "element":
            elements.append((tok[1], int(tok[2]), []))
        elif tok and tok[0] == "property" and elements:
            prop = (tok[4], "list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]) if tok[1] == "list" else (tok[2], _PLY_TYPES[tok[1]])
            elements[-1][2].append(prop)
    return elements


def _ply_binary_records(body: bytes, header: list[str], order: str) -> dict | None:
    """Binary PLY elements read record by record, for the one layout trimesh's reader cannot size:
    list properties whose length changes from record to record (faces mixing triangles, quads and
    other polygons). Elements without lists are read whole. Returns trimesh's ``_ply_raw`` shape
    ({name: {"length", "properties", "data"}}), or None if the body is shorter or longer than the
    header says."""
    elements = _ply_elements(header)
    out, pos = {}, 0
    try:
        for name, count, props in elements:
            if not any(p[1] == "list" for p in props):
                dt = np.dtype([(p[0], order + p[1]) for p in props])
                arr = np.frombuffer(body, dt, count, pos)
                data = {p[0]: arr[p[0]] for p in props}
                pos += dt.itemsize * count
            else:
                data = {p[0]: [] for p in props}
                for _ in range(count):
                    for p in props:
                        if p[1] == "list":
                            n = int(np.frombuffer(body, order + p[2], 1, pos)[0])
                            pos += np.dtype(p[2]).itemsize
                            data[p[0]].append(np.frombuffer(body, order + p[3], n, pos))
                            pos += np.dtype(p[3]).itemsize * n
                        else:
                            data[p[0]].append(np.frombuffer(body, order + p[1], 1, pos)[0])
                            pos += np.dtype(p[1]).itemsize
                data = {p[0]: (data[p[0]] if p[1] == "list" else np.asarray(data[p[0]])) for p in props}
            out[name] = {"length": count, "properties": {p[0]: "$LIST" if p[1] == "list" else p[1] for p in props},
                         "data": data}
    except ValueError:
        return None
    return out if pos == len(body) else None


# ---------------------------------------------------------------- OBJ
def _read_obj(data: bytes) -> Mesh:
    verts: list[list[float]] = []
    polys: list[list[int]] = []
    owner_names: list[str | None] = []
    current: str | None = None
    for line in data.decode("utf-8", "replace").splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "v":
            verts.append([float(t) for t in tok[1:4]])
        elif tok[0] == "f":
            idx = [int(t.split("/")[0]) for t in tok[1:]]
            idx = [k - 1 if k > 0 else len(verts) + k for k in idx]
            polys.append(idx)
            owner_names.append(current)
        elif tok[0] in ("usemtl", "g", "o") and len(tok) > 1 and (tok[0] != "o" or current is None):
            current = " ".join(tok[1:])
    tris, owner = _fan(polys)
    vertices = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    names = [n for n in dict.fromkeys(owner_names) if n is not None]
    if not names or len(tris) == 0:
        return Mesh(vertices, tris)
    ids = {n: k + 1 for k, n in enumerate(names)}
    fc = np.asarray([ids.get(owner_names[o], 0) for o in owner], dtype=np.uint8)
    return Mesh(vertices, tris, fc, {v: k for k, v in ids.items()})


# ---------------------------------------------------------------- STL
def _read_stl(data: bytes) -> Mesh:
    """ASCII or binary STL via trimesh; its triangle soup gets shared vertices here (:func:`_soup`)."""
    from trimesh.exchange.stl import load_stl

    try:
        kw = load_stl(io.BytesIO(data))
        tri = np.asarray(kw["vertices"], dtype=np.float64)[np.asarray(kw["faces"])]
    except (KeyError, ValueError, IndexError, struct.error) as err:  # trimesh: no 'faces' when nothing parses
        raise InputError("not an ASCII or binary STL file") from err
    return _soup(tri)


def _soup(tri: np.ndarray) -> Mesh:
    """(F,3,3) triangle soup -> shared vertices (exact duplicates merged)."""
    flat = tri.reshape(-1, 3)
    verts, inv = np.unique(flat, axis=0, return_inverse=True)
    return Mesh(verts, inv.reshape(-1, 3))
