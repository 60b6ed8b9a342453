"""meshio's binary PLY fast path (``_ply_binary_fixed``) against trimesh's reader, which it skips."""
from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pytest

import holodata.meshio as meshio
from holodata.meshio import Mesh, read_mesh, write_ply


def _both(path, monkeypatch):
    """(fast-path mesh, trimesh-path mesh, whether the fast path answered) for one file."""
    calls = []
    real = meshio._ply_binary_fixed

    def spy(*a):
        calls.append(real(*a))
        return calls[-1]

    monkeypatch.setattr(meshio, "_ply_binary_fixed", spy)
    fast = read_mesh(path)
    monkeypatch.setattr(meshio, "_ply_binary_fixed", lambda *a: None)
    slow = read_mesh(path)
    return fast, slow, bool(calls) and calls[0] is not None


def _same(a: Mesh, b: Mesh) -> None:
    for x, y in ((a.vertices, b.vertices), (a.faces, b.faces)):
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    assert (a.face_class is None) == (b.face_class is None)
    if a.face_class is not None:
        assert a.face_class.dtype == b.face_class.dtype and a.face_class.tobytes() == b.face_class.tobytes()
    assert a.class_names == b.class_names


@pytest.mark.parametrize("with_class", [False, True])
def test_holodata_binary_ply_fast_equals_trimesh(tmp_path, monkeypatch, with_class):
    rng = np.random.default_rng(3)
    v = rng.normal(size=(50, 3))
    f = rng.integers(0, 50, size=(80, 3)).astype(np.int32)
    fc = rng.integers(0, 9, 80).astype(np.uint8) if with_class else None
    write_ply(tmp_path / "m.ply", Mesh(v, f, fc, {int(k): f"c{k}" for k in np.unique(fc)} if with_class else {}))
    fast, slow, used = _both(tmp_path / "m.ply", monkeypatch)
    assert used
    _same(fast, slow)
    np.testing.assert_array_equal(fast.faces, f)


@pytest.mark.parametrize("order", ["<", ">"])
def test_foreign_binary_layouts_fast_equals_trimesh(tmp_path, monkeypatch, order):
    # float vertices with an extra property, quads only (one list length), int label after the list
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    head = (f"ply\nformat {fmt} 1.0\ncomment x\nelement vertex 5\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nelement face 2\nproperty list uchar int vertex_indices\n"
            "property int label\nend_header\n").encode()
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0.5), (0, 1, 0), (0, 0, 1)]
    body = b"".join(struct.pack(f"{order}fffB", *p, 9) for p in verts)
    body += struct.pack(f"{order}B4ii", 4, 0, 1, 2, 3, 5) + struct.pack(f"{order}B4ii", 4, 0, 1, 4, 2, 7)
    (tmp_path / "q.ply").write_bytes(head + body)
    fast, slow, used = _both(tmp_path / "q.ply", monkeypatch)
    assert used
    _same(fast, slow)
    assert fast.faces.tolist() == [[0, 1, 2], [0, 1, 4], [0, 2, 3], [0, 4, 2]]


def test_trimesh_written_binary_fast_equals_trimesh(tmp_path, monkeypatch):
    import trimesh

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    t = trimesh.Trimesh(v, f, process=False, face_attributes={"label": np.array([5, 1, 1, 200], np.uint8)})
    (tmp_path / "t.ply").write_bytes(trimesh.exchange.ply.export_ply(t, encoding="binary", include_attributes=True))
    fast, slow, used = _both(tmp_path / "t.ply", monkeypatch)
    assert used
    _same(fast, slow)


def test_mixed_lists_and_bad_bodies_fall_back(tmp_path, monkeypatch):
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
            b"property double z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n")
    body = np.arange(12, dtype="<f8").tobytes()
    mixed = body + struct.pack("<B3i", 3, 0, 1, 2) + struct.pack("<B4i", 4, 0, 1, 2, 3)
    tris = body + struct.pack("<B3i", 3, 0, 1, 2) + struct.pack("<B3i", 3, 1, 2, 3)
    header = head[:head.find(b"end_header")].decode().splitlines()
    assert meshio._ply_binary_fixed(mixed, header, "<") is None          # list lengths differ
    assert meshio._ply_binary_fixed(tris + b"\0", header, "<") is None   # longer than the header says
    assert meshio._ply_binary_fixed(tris[:-1], header, "<") is None      # shorter
    assert meshio._ply_binary_fixed(tris, header, "<") is not None
    (tmp_path / "m.ply").write_bytes(head + mixed)
    fast, slow, used = _both(tmp_path / "m.ply", monkeypatch)
    assert not used
    _same(fast, slow)
    assert fast.faces.tolist() == [[0, 1, 2], [0, 1, 2], [0, 2, 3]]


def test_binary_triangle_ply_does_not_import_trimesh(tmp_path):
    write_ply(tmp_path / "m.ply", Mesh(np.eye(3), np.array([[0, 1, 2]])))
    code = ("import sys; from holodata.meshio import read_mesh; m = read_mesh(sys.argv[1]); "
            "print(len(m.faces), 'trimesh' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "m.ply")], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "False"]
