"""The tracer's compiled float16 rounding (_kernels.to_half) against numpy's cast, bit for bit.

Every one of the 2**32 float32 bit patterns was checked once (docs/design/raytrace.md); here a
sample that covers every branch: specials and NaN payloads, a stride over all patterns, exact
ties between neighbouring halves (normal and subnormal), unit-vector components."""
from __future__ import annotations

import numpy as np
import pytest

from holodata.raytrace._kernels import to_half
from holodata.raytrace.frames import _half


def _check(bits: np.ndarray) -> None:
    x = np.ascontiguousarray(bits, dtype=np.uint32).view(np.float32)
    with np.errstate(all="ignore"):
        want = x.astype(np.float16).view(np.uint16)
    got = np.empty(len(x), np.uint16)
    to_half(x, got)
    bad = np.flatnonzero(want != got)
    assert len(bad) == 0, [(hex(int(bits[i])), hex(int(want[i])), hex(int(got[i]))) for i in bad[:5]]


def test_specials_and_nan_payloads():
    special = [0, 0x80000000, 0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00000, 0x7F800001, 0x7F801FFF, 0x7F802000,
               0x7FBFFFFF, 0xFF800001, 0x477FE000, 0x477FEFFF, 0x477FF000, 0x477FFFFF, 0x47800000, 0x387FC000,
               0x38800000, 0x33000000, 0x33000001, 0x33800000, 0x00000001, 0x007FFFFF, 0x3F800000, 0xBF800000]
    _check(np.array(special, np.uint64))


def test_stride_over_all_bit_patterns():
    _check(np.arange(0, 1 << 32, 4099, dtype=np.uint64))


def test_ties_and_near_ties_between_halves():
    h = np.arange(0, 0x7C00, dtype=np.uint32)  # every finite positive half
    lo = h.astype(np.uint16)
    a = lo.view(np.float16).astype(np.float32).astype(np.float64)
    b = (lo + 1).view(np.float16).astype(np.float32).astype(np.float64)
    mid = ((a + b) / 2).astype(np.float32)  # exact in float32: the tie
    m = mid.view(np.uint32).astype(np.uint64)
    ties = np.concatenate([m, m - 1, m + 1])
    _check(np.concatenate([ties, ties | 0x80000000]))


def test_unit_vector_components():
    rng = np.random.default_rng(7)
    v = rng.normal(size=(200_000, 3)).astype(np.float32)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    _check(v.reshape(-1).view(np.uint32))


def test_half_helper_takes_any_layout():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 50, 3)).astype(np.float32)
    a[0, 3] = np.nan
    for arr in (a, a.transpose(1, 0, 2), a.astype(np.float64)):
        got = _half(arr)
        want = arr.astype(np.float16)
        assert got.dtype == np.float16 and got.shape == want.shape and got.tobytes() == want.tobytes()


def _numpy_face_normals(v, f):
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def test_compiled_face_normals_equal_numpys_to_the_bit():
    from holodata.raytrace.labels import face_normals

    rng = np.random.default_rng(11)
    for scale, vdt, fdt in ((1e-3, np.float64, np.int64), (1.0, np.float32, np.int32), (1e3, np.float64, np.uint32)):
        v = (rng.normal(size=(500, 3)) * scale).astype(vdt)
        f = rng.integers(0, 500, size=(3000, 3)).astype(fdt)
        f[:20, 2] = f[:20, 0]  # degenerate: zero normals
        got, want = face_normals(v, f), _numpy_face_normals(v, f)
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
        distinct = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        assert (got[:20] == 0).all() and np.allclose(np.linalg.norm(got[distinct], axis=1), 1)
    with pytest.raises(IndexError):  # out-of-range faces fail as numpy's indexing does
        face_normals(np.zeros((3, 3)), np.array([[0, 1, 3]]))
