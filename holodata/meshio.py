"""Triangle mesh files: read PLY / OBJ / STL, write PLY with a per-face class.

PLY: ascii, binary_little_endian and binary_big_endian; vertex ``x y z``; faces from the
``vertex_indices`` (or ``vertex_index``) list, polygons fan-triangulated; a scalar face
property named ``label``, ``class``, ``semantic``, ``face_class`` or ``category`` becomes
``Mesh.face_class``. Class names come from ``comment class <id> <name>`` header lines (what
:func:`write_ply` writes). OBJ: ``v`` and ``f`` records (``f a/b/c ...``, negative indices),
``usemtl``/``g`` names become face classes when present. STL: ascii or binary.
"""
from __future__ import annotations

import re
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
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError("not a PLY file (missing 'ply' magic or 'end_header')")
    nl = data.find(b"\n", end)
    header = data[:end].decode("ascii", "replace").splitlines()
    body = data[nl + 1:]
    fmt, elements, class_names = None, [], {}
    for line in header:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "comment" and len(tok) >= 4 and tok[1] == "class":
            class_names[int(tok[2])] = " ".join(tok[3:])
        elif tok[0] == "element":
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if tok[1] == "list":
                elements[-1][2].append((tok[4], "list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]))
            else:
                elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"unsupported PLY format {fmt!r}")
    endian = "<" if fmt.endswith("little_endian") else ">"
    values = _ply_ascii(body, elements) if fmt == "ascii" else _ply_binary(body, elements, endian)
    if "vertex" not in values:
        raise InputError("PLY has no vertex element")
    vert = values["vertex"]
    vertices = np.stack([np.asarray(vert[c], dtype=np.float64) for c in ("x", "y", "z")], axis=1)
    face = values.get("face", {})
    lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        return Mesh(vertices, np.zeros((0, 3), np.int32))
    cls = next((face[p] for p in FACE_CLASS_PROPERTIES if p in face), None)
    tris, owner = _fan(lists)
    face_class = None if cls is None else np.asarray(cls)[owner].astype(np.uint8)
    if face_class is not None and not class_names:
        class_names = {int(k): f"class_{int(k)}" for k in np.unique(face_class)}
    return Mesh(vertices, tris, face_class, class_names)


def _fan(lists) -> tuple[np.ndarray, np.ndarray]:
    """Polygons (list of index arrays, or (F,k) array) -> triangles (F',3) and source polygon index."""
    if isinstance(lists, np.ndarray) and lists.ndim == 2:
        k = lists.shape[1]
        if k == 3:
            return lists.astype(np.int32), np.arange(len(lists))
        tri = np.concatenate([np.stack([lists[:, 0], lists[:, i], lists[:, i + 1]], 1) for i in range(1, k - 1)])
        owner = np.concatenate([np.arange(len(lists))] * (k - 2))
        return tri.astype(np.int32), owner
    tris, owner = [], []
    for n, poly in enumerate(lists):
        for i in range(1, len(poly) - 1):
            tris.append((poly[0], poly[i], poly[i + 1]))
            owner.append(n)
    return np.asarray(tris, dtype=np.int32).reshape(-1, 3), np.asarray(owner, dtype=np.int64)


def _ply_binary(body: bytes, elements, order: str) -> dict:
    out, pos = {}, 0
    for name, count, props in elements:
        if not any(p[1] == "list" for p in props):
            dt = np.dtype([(p[0], order + p[1]) for p in props])
            arr = np.frombuffer(body, dtype=dt, count=count, offset=pos)
            pos += dt.itemsize * count
            out[name] = {p[0]: arr[p[0]] for p in props}
            continue
        # fast path: one list whose count is constant (triangle meshes), scalars around it
        cols = _ply_binary_lists(body, pos, count, props, order)
        pos = cols.pop("__end__")
        out[name] = cols
    return out


def _ply_binary_lists(body: bytes, pos: int, count: int, props, order: str) -> dict:
    if count == 0:
        return {"__end__": pos, **{p[0]: np.zeros((0, 3) if p[1] == "list" else 0) for p in props}}
    # try constant list length, read the first record's count
    off, lens = pos, None
    first = props[[p[1] for p in props].index("list")]
    for p in props:
        if p[1] == "list":
            lens = int(np.frombuffer(body, order + p[2], 1, off)[0])
            break
        off += np.dtype(p[1]).itemsize
    fields = []
    for p in props:
        if p[1] == "list":
            fields += [(p[0] + "__n", order + p[2]), (p[0], order + p[3], (lens,))]
        else:
            fields.append((p[0], order + p[1]))
    dt = np.dtype(fields)
    if sum(p[1] == "list" for p in props) == 1 and pos + dt.itemsize * count <= len(body):
        arr = np.frombuffer(body, dtype=dt, count=count, offset=pos)
        if np.all(arr[first[0] + "__n"] == lens):
            res = {p[0]: arr[p[0]] for p in props}
            res["__end__"] = pos + dt.itemsize * count
            return res
    # general (slow) path: variable-length polygons
    res = {p[0]: [] for p in props}
    for _ in range(count):
        for p in props:
            if p[1] == "list":
                n = int(np.frombuffer(body, order + p[2], 1, pos)[0])
                pos += np.dtype(p[2]).itemsize
                res[p[0]].append(np.frombuffer(body, order + p[3], n, pos))
                pos += np.dtype(p[3]).itemsize * n
            else:
                res[p[0]].append(np.frombuffer(body, order + p[1], 1, pos)[0])
                pos += np.dtype(p[1]).itemsize
    res = {k: (v if k == first[0] else np.asarray(v)) for k, v in res.items()}
    res["__end__"] = pos
    return res


def _ply_ascii(body: bytes, elements) -> dict:
    lines = body.decode("ascii", "replace").splitlines()
    out, i = {}, 0
    for name, count, props in elements:
        rows = lines[i:i + count]
        if len(rows) < count:
            raise InputError(f"PLY element {name!r} truncated ({len(rows)} of {count} rows)")
        i += count
        cols = {p[0]: [] for p in props}
        for row in rows:
            tok = row.split()
            j = 0
            for p in props:
                if p[1] == "list":
                    n = int(tok[j])
                    cols[p[0]].append(np.asarray(tok[j + 1:j + 1 + n], dtype=np.int64))
                    j += 1 + n
                else:
                    cols[p[0]].append(float(tok[j]))
                    j += 1
        out[name] = {k: (v if any(p[0] == k and p[1] == "list" for p in props) else np.asarray(v)) for k, v in cols.items()}
    return out


# ---------------------------------------------------------------- OBJ
def _read_obj(data: bytes) -> Mesh:
    verts, polys, owner_names = [], [], []
    current = None
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
        elif tok[0] in ("usemtl", "g", "o") and len(tok) > 1:
            if tok[0] != "o" or current is None:
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
    if len(data) >= 84:
        n = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if 84 + 50 * n == len(data):
            rec = np.frombuffer(data, np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), n, 84)
            return _soup(rec["v"].astype(np.float64))
    text = data.decode("ascii", "replace")
    if not text.lstrip().startswith("solid"):
        raise InputError("not an ASCII or binary STL file")
    nums = re.findall(r"vertex\s+(\S+)\s+(\S+)\s+(\S+)", text)
    v = np.asarray(nums, dtype=np.float64).reshape(-1, 3, 3)
    return _soup(v)


def _soup(tri: np.ndarray) -> Mesh:
    """(F,3,3) triangle soup -> shared vertices (exact duplicates merged)."""
    flat = tri.reshape(-1, 3)
    verts, inv = np.unique(flat, axis=0, return_inverse=True)
    return Mesh(verts, inv.reshape(-1, 3))
