"""Bounded reads of a dataset's chunk objects, for validate: an object's size is asked of the store
and a Blosc chunk's header checked against what ``zarr.json`` declares before anything of the
declared size is allocated, so that metadata from elsewhere cannot make a reader allocate what it
merely claims (docs/format.md, "Sizes")."""
from __future__ import annotations

import numpy as np

from . import shards as sh

READ_BYTES = 8 << 20           # rows of small arrays and ragged values decoded at a time (at least one chunk)
MAX_FILL_BYTES = 64 << 20      # an absent chunk is filled (zarr's rule) only up to this size


def is_int(v) -> bool:
    """``v`` is an int (a JSON integer), not a bool."""
    return isinstance(v, int) and not isinstance(v, bool)


def fill_value(meta: dict, dt: np.dtype):
    """The fill value ``zarr.json`` (``meta``) states, as a number (0 where it states none or text
    that is not one): what zarr reads an absent chunk as."""
    f = meta.get("fill_value", 0)
    if isinstance(f, str):
        try:
            return float(f)
        except ValueError:
            return 0
    return 0 if f is None else f


BLOSC_OVERHEAD = 16   # a Blosc chunk is at most its data + a 16-byte header (incompressible data: copied)


def get_chunk(store, key: str, want: int, what: str) -> bytes | None:
    """The Blosc chunk object ``key`` that decodes to ``want`` bytes: its size asked of the store
    first, so that an object larger than such a chunk can be is never read (None: absent)."""
    try:
        size = store.size(key)
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        return None
    if size > want + BLOSC_OVERHEAD:
        raise ValueError(f"{what} object holds {size} bytes, more than a Blosc chunk of {want} bytes can; not read")
    return store.get(key)


class Rows:
    """Rows of a ragged array's ``values``, read a chunk at a time. holodata's layout (``bytes`` +
    ``blosc``, whole rows per chunk) is read object by object, each chunk's Blosc header checked
    against the declared chunk size before it is decoded; any other through zarr, in row blocks."""

    def __init__(self, ds, path: str, vm: dict):
        self.ds, self.store, self.path = ds, ds.store, path
        self.dt = np.dtype(vm["data_type"])
        self.width = int(vm["shape"][1])
        cs = list(((vm.get("chunk_grid") or {}).get("configuration") or {}).get("chunk_shape") or [])
        self.rows = int(cs[0]) if cs and is_int(cs[0]) and cs[0] > 0 else 0
        self.codec = sh.chunk_codec(vm) if self.rows and cs[1:] == [self.width] else None
        self.fill = fill_value(vm, self.dt)
        self._cache: tuple = (None, None)

    def read(self, r0: int, r1: int):
        if r1 <= r0:
            return
        if self.codec is None:
            z = self.ds.zgroup[self.path]
            step = max(1, READ_BYTES // max(1, self.width * self.dt.itemsize))
            for i in range(r0, r1, step):
                yield np.ascontiguousarray(np.asarray(z[i:min(r1, i + step)]))
            return
        for c in range(r0 // self.rows, (r1 - 1) // self.rows + 1):
            lo = c * self.rows
            yield self._chunk(c)[max(r0, lo) - lo:min(r1, lo + self.rows) - lo]

    def _chunk(self, c: int) -> np.ndarray:
        if self._cache[0] == c:
            return self._cache[1]
        want = self.rows * self.width * self.dt.itemsize
        b = get_chunk(self.store, f"{self.path}/c/{c}/0", want, f"values chunk {c}")
        if b is None:   # zarr reads an absent chunk as the fill value
            if want > MAX_FILL_BYTES:
                raise ValueError(f"values chunk {c} is absent and declared {want} bytes")
            a = np.full((self.rows, self.width), self.fill, self.dt)
        else:
            if sh.blosc_sizes(b) != (want, len(b)):
                raise ValueError(f"values chunk {c} is damaged or not what zarr.json declares (its Blosc header "
                                 f"does not state {self.rows} rows of {self.width} {self.dt})")
            a = np.empty((self.rows, self.width), self.dt)
            assert self.codec is not None   # (read() comes here only with one)
            self.codec.decode(b, out=a)
        self._cache = (c, a)
        return a


def read_offsets(ds, path: str, om: dict, T: int) -> np.ndarray:
    """offsets (T+1,) int64 of a ragged array; its one chunk's Blosc header is checked against the
    T+1 offsets the metadata declares before anything is allocated."""
    want = (T + 1) * 8
    codec = sh.chunk_codec(om)
    cs = ((om.get("chunk_grid") or {}).get("configuration") or {}).get("chunk_shape")
    if codec is not None and cs == om.get("shape"):
        b = get_chunk(ds.store, f"{path}/offsets/c/0", want, "the offsets chunk")
        if b is None:
            raise ValueError("its chunk is missing")
        got = sh.blosc_sizes(b)
        if got != (want, len(b)):
            raise ValueError(f"its chunk holds {got[0] if got else 0} bytes, zarr.json declares {T + 1} offsets "
                             f"({want} bytes)")
        out = np.empty(T + 1, "<i8")
        codec.decode(b, out=out)
        return out
    if want > MAX_FILL_BYTES * 16:
        raise ValueError(f"{T + 1} offsets declared in a layout read through zarr: too many to read")
    return np.asarray(ds.zgroup[f"{path}/offsets"][...])
