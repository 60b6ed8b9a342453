"""Range pooling and normalisation of a stored heatmap in one pass over its codes (the loader's core).

A heatmap frame is stored as codes ``q`` (R, H, W): uint8 log-amplitude codes
(:class:`holodata.conventions.LogCode`) or the bit patterns of float16 linear amplitude (uint16).
The normalised network input of a code is a table lookup (:class:`holodata.torch.data.HeatmapNorm`
evaluated once per code), and max-pooling range bins by ``f`` picks, per beam and group of ``f``
bins, the code whose normalised value is largest:

    out[r, h, w] = table_out[argmax_{j<f} value[q[r·f + j, h, w]]]

``value`` (float32) is what is compared, ``table_out`` what is written (float32, or float16 as its
uint16 bit pattern): numba has no float16, and comparing the normalised values (not the codes)
keeps negative and NaN patterns of float16 where the norm puts them. Equal to numpy's
``norm(pool(decode(q)))`` for any monotone norm (tests/torch_/test_loader.py checks it against numpy).
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _pool_lookup(q, value, table_out, f, out):
    R2, H, W = out.shape
    for r in range(R2):
        for h in range(H):
            for w in range(W):
                m = q[r * f, h, w]
                mv = value[m]
                for j in range(1, f):
                    c = q[r * f + j, h, w]
                    if value[c] > mv:
                        m, mv = c, value[c]
                out[r, h, w] = table_out[m]


def pool_lookup(q: np.ndarray, value: np.ndarray, f: int = 1, dtype=np.float32) -> np.ndarray:
    """(R // f, H, W) ``dtype`` (float32 or float16): ``value`` (256 or 65536,) float32 of the codes
    ``q`` (R, H, W) uint8 / uint16, range-pooled by ``f`` (the last ``R % f`` bins dropped, as
    :func:`holodata.torch.data.apply_transform` does)."""
    dtype = np.dtype(dtype)
    value = np.ascontiguousarray(value, np.float32)
    table_out = value.astype(np.float16).view(np.uint16) if dtype == np.float16 else value
    R, H, W = q.shape
    out = np.empty((R // f, H, W), np.uint16 if dtype == np.float16 else np.float32)
    _pool_lookup(q, value, table_out, int(f), out)
    return out.view(np.float16) if dtype == np.float16 else out
