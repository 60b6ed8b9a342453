"""Property tests (hypothesis): shard index math, shard objects, ragged offsets and the sync's
nearest-neighbour matching hold for every size hypothesis can think of, not only the sizes the
example tests pick."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

hp = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from holodata.conventions import Grid  # noqa: E402
from holodata.dataset import FrameStorage, create_dataset, open_dataset  # noqa: E402
from holodata.dataset import shards as sh  # noqa: E402
from holodata.ingest.plan import _nearest  # noqa: E402

_ids = itertools.count()
FEW = settings(max_examples=40, deadline=None)


def _scene(n_frames: int, shard_frames: int):
    url = f"memory://props-{next(_ids)}.zarr"
    return url, create_dataset(url, grid=Grid(4, 8), shard_frames=shard_frames).scene("s", n_frames=n_frames)


@FEW
@given(n=st.integers(1, 200), s=st.integers(1, 64))
def test_shards_partition_the_frames_in_order(n, s):
    _, sc = _scene(n, s)
    w = sc.frame_array("a", (2,), "float32", storage=FrameStorage(shard_frames=s))
    assert w.n_shards == -(-n // s)
    frames = [list(range(n))[w.frames(k)] for k in range(w.n_shards)]
    assert [f for part in frames for f in part] == list(range(n))
    assert all(1 <= len(p) <= s for p in frames) and all(len(p) == s for p in frames[:-1])


@FEW
@given(n=st.integers(1, 9), per=st.lists(st.integers(1, 5), max_size=3),
       dt=st.sampled_from(["float32", "float16", "int64", "uint16", "uint8"]), seed=st.integers(0, 2**31 - 1),
       codec=st.sampled_from(["zstd", "lz4"]))
def test_shard_objects_round_trip_and_equal_zarrs_bytes(n, per, dt, seed, codec):
    url = f"memory://props-{next(_ids)}.zarr"
    sc = create_dataset(url, grid=Grid(4, 8), codec=codec).scene("s", n_frames=n)
    w = sc.frame_array("a", tuple(per), dt, storage=FrameStorage(shard_frames=max(n, 1)))
    data = (np.random.default_rng(seed).normal(size=(n,) + tuple(per)) * 50).astype(dt)
    blob = sh.encode_shard(w.meta, data)
    assert blob == sh._encode_shard_zarr(w.meta, data)
    assert np.array_equal(sh.decode_shard(w.meta, n, blob), data)


@FEW
@given(rows=st.lists(st.integers(0, 12), min_size=1, max_size=30), s=st.integers(1, 8))
def test_ragged_offsets_and_rows_round_trip(rows, s):
    url, sc = _scene(len(rows), s)
    rag = sc.ragged_array("camera/points", width=3)
    data = [np.full((r, 3), i, np.float32) for i, r in enumerate(rows)]
    for k in range(-(-len(rows) // s)):
        rag.write_shard(k, data[k * s:(k + 1) * s])
    back = open_dataset(url).scene("s")
    off = np.asarray(back["camera/points"].offsets[...])
    assert off[0] == 0 and off[-1] == sum(rows) and np.all(np.diff(off) == rows)
    for i in range(len(rows)):
        np.testing.assert_array_equal(back.ragged("camera/points", i), data[i])


@settings(max_examples=200, deadline=None)
@given(frames=st.lists(st.integers(-10**6, 10**6), max_size=40), items=st.lists(st.integers(-10**6, 10**6), max_size=40),
       tol=st.integers(0, 10**6))
def test_nearest_matching_equals_brute_force(frames, items, tol):
    """Every frame gets an item at the smallest distance when that distance is within tol, else
    -1; the offset is item - frame."""
    f = np.asarray(frames, np.int64)
    t = np.sort(np.asarray(items, np.int64))
    idx, off = _nearest(f, t, tol)
    for i, x in enumerate(f):
        best = int(np.abs(t - x).min()) if len(t) else None
        if best is None or best > tol:
            assert idx[i] == -1 and off[i] == 0
        else:
            assert idx[i] >= 0 and abs(int(t[idx[i]]) - int(x)) == best and off[i] == t[idx[i]] - x
