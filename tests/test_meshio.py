"""Mesh files: PLY (ascii/binary, per-face label), OBJ, STL round trips and bad input."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from holodata.errors import InputError
from holodata.meshio import Mesh, read_mesh, write_ply


def tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.5]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip_with_face_class(tmp_path, binary):
    v, f = tetra()
    m = Mesh(v, f, np.array([1, 3, 3, 7], np.uint8), {1: "floor", 3: "wall", 7: "door frame"})
    write_ply(tmp_path / "m.ply", m, binary=binary)
    r = read_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(r.vertices, v)
    np.testing.assert_array_equal(r.faces, f)
    assert r.face_class.tolist() == [1, 3, 3, 7]
    assert r.class_names == {1: "floor", 3: "wall", 7: "door_frame"}


@pytest.mark.parametrize("binary", [True, False])
def test_holodata_ply_reads_in_trimesh(tmp_path, binary):
    # holodata writes, trimesh reads: same vertices, faces and the uchar label face property
    import trimesh
    v, f = tetra()
    write_ply(tmp_path / "m.ply", Mesh(v, f, np.array([2, 0, 9, 4], np.uint8), {2: "wall"}), binary=binary)
    t = trimesh.load(tmp_path / "m.ply", process=False)
    np.testing.assert_array_equal(t.vertices, v)
    np.testing.assert_array_equal(t.faces, f)
    face = t.metadata["_ply_raw"]["face"]["data"]
    assert np.asarray(face["label"]).reshape(-1).tolist() == [2, 0, 9, 4]


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_trimesh_ply_reads_in_holodata(tmp_path, encoding):
    # trimesh writes (float vertices, a face attribute), holodata reads the label as face_class
    import trimesh
    v, f = tetra()
    label = np.array([5, 1, 1, 200], np.uint8)
    t = trimesh.Trimesh(v, f, process=False, face_attributes={"label": label})
    (tmp_path / "t.ply").write_bytes(trimesh.exchange.ply.export_ply(t, encoding=encoding, include_attributes=True))
    r = read_mesh(tmp_path / "t.ply")
    np.testing.assert_array_equal(r.vertices, v.astype(np.float32))  # trimesh writes float32 vertices
    np.testing.assert_array_equal(r.faces, f)
    assert r.face_class.tolist() == label.tolist()
    assert r.class_names == {int(k): f"class_{k}" for k in np.unique(label)}


@pytest.mark.parametrize("order", ["<", ">"])
def test_ply_binary_mixed_polygons_either_byte_order(tmp_path, order):
    # the layout trimesh's binary reader cannot size (list length changes per record)
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    head = (f"ply\nformat {fmt} 1.0\nelement vertex 6\nproperty double x\nproperty double y\nproperty double z\n"
            "element face 3\nproperty list uchar int vertex_indices\nproperty uchar label\nend_header\n").encode()
    verts = np.arange(18, dtype=float).reshape(6, 3)
    polys, labels = [[0, 1, 2], [1, 2, 3, 4, 5], [5, 4, 3, 2]], [7, 8, 9]
    body = verts.astype(order + "f8").tobytes()
    for p, lab in zip(polys, labels):
        body += struct.pack(f"{order}B{len(p)}iB", len(p), *p, lab)
    (tmp_path / "m.ply").write_bytes(head + body)
    r = read_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(r.vertices, verts)
    assert r.faces.tolist() == [[0, 1, 2], [1, 2, 3], [1, 3, 4], [1, 4, 5], [5, 4, 3], [5, 3, 2]]
    assert r.face_class.tolist() == [7, 8, 8, 8, 9, 9]
    (tmp_path / "short.ply").write_bytes(head + body[:-1])
    with pytest.raises(InputError, match="does not match its header"):
        read_mesh(tmp_path / "short.ply")


def test_ply_foreign_layout_quads_and_label_property(tmp_path):
    # vertex with extra properties, a quad and a triangle, int label after the list, ushort counts
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
            b"property float z\nproperty uchar red\nelement face 2\nproperty list uchar int vertex_indices\n"
            b"property int label\nend_header\n")
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1)]
    body = b"".join(struct.pack("<fffB", *p, 9) for p in verts)
    body += struct.pack("<B4ii", 4, 0, 1, 2, 3, 5) + struct.pack("<B3ii", 3, 0, 1, 4, 2)
    (tmp_path / "q.ply").write_bytes(head + body)
    r = read_mesh(tmp_path / "q.ply")
    assert r.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 4]]
    assert r.face_class.tolist() == [5, 5, 2]
    np.testing.assert_allclose(r.vertices[4], [0, 0, 1])


def test_ply_ascii_without_class(tmp_path):
    txt = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n" \
          "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    (tmp_path / "a.ply").write_text(txt)
    r = read_mesh(tmp_path / "a.ply")
    assert r.faces.tolist() == [[0, 1, 2]] and r.face_class is None


def test_obj_with_groups(tmp_path):
    txt = "# obj\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\ng floor\nf 1/1 2/2 3/3 4/4\nusemtl wall\nf -5 -4 -1\n"
    (tmp_path / "m.obj").write_text(txt)
    r = read_mesh(tmp_path / "m.obj")
    assert r.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 4]]
    assert [r.class_names[k] for k in r.face_class] == ["floor", "floor", "wall"]


def test_stl_binary_and_ascii(tmp_path):
    v, f = tetra()
    tri = v[f].astype(np.float32)
    data = b"solid exported by a CAD tool".ljust(80, b"\0") + struct.pack("<I", len(f))
    for t in tri:
        data += struct.pack("<3f", 0, 0, 0) + t.tobytes() + b"\0\0"
    (tmp_path / "b.stl").write_bytes(data)
    txt = "solid t\n" + "".join(
        "facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {a} {b} {c}\n" for a, b, c in t) + "endloop\nendfacet\n"
        for t in tri) + "endsolid t\n"
    (tmp_path / "a.stl").write_text(txt)
    for name in ("b.stl", "a.stl"):
        r = read_mesh(tmp_path / name)
        assert len(r.vertices) == 4 and len(r.faces) == 4  # shared corners merged
        np.testing.assert_allclose(np.sort(r.vertices[r.faces].reshape(-1, 9), 0), np.sort(tri.reshape(-1, 9), 0))


@pytest.mark.parametrize("name,content,msg", [
    ("missing.ply", None, "cannot read"),
    ("empty.ply", b"", "not a PLY"),
    ("noface.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                   b"property float z\nend_header\n0 0 0\n", "no triangles"),
    ("trunc.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                  b"property float z\nend_header\n0 0 0\n", "truncated"),
    ("trunc_bin.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                      b"property float y\nproperty float z\nend_header\n\0\0\0\0", "malformed"),
    ("trunc_face.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                       b"property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                       b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "truncated"),
    ("bad.obj", b"v 0 0 0\nf 1 2 3\n", "out of range"),
    ("x.stl", b"hello", "not an ASCII or binary STL"),
    ("m.off", b"OFF", "unsupported"),
])
def test_bad_meshes_name_the_file(tmp_path, name, content, msg):
    p = tmp_path / name
    if content is not None:
        p.write_bytes(content)
    with pytest.raises(InputError) as e:
        read_mesh(p)
    assert str(p) in str(e.value) and msg in str(e.value) and "\n" not in str(e.value)


def test_directory_of_class_meshes(tmp_path):
    v, f = tetra()
    write_ply(tmp_path / "wall.ply", Mesh(v, f))
    write_ply(tmp_path / "floor.ply", Mesh(v + 10, f[:2]))
    r = read_mesh(tmp_path)
    assert r.class_names == {1: "floor", 2: "wall"}
    assert r.face_class.tolist() == [1, 1, 2, 2, 2, 2]
    np.testing.assert_array_equal(r.vertices[r.faces[:2]], (v + 10)[f[:2]])
    np.testing.assert_array_equal(r.vertices[r.faces[2:]], v[f])
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="holds no"):
        read_mesh(empty)
