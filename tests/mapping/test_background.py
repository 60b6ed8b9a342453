"""Voxel background model (holodata.mapping.background): the dense-grid occupancy count and lookups
against the sorted-key versions and brute-force sets."""
from __future__ import annotations

import numpy as np
import pytest

from holodata.geometry import voxels as V
from holodata.mapping import background as B
from holodata.mapping.background import VoxelBackground


def _scene(n_scans=12, seed=0):
    """Scans of a room (walls x = ±3, y = ±4, floor z = 0) from a sensor moving along x, plus a walker
    (a 0.4 m column) moving along y; float32 points as the segmentation passes them, a few NaN rows."""
    rng = np.random.default_rng(seed)
    scans, origins = [], []
    for s in range(n_scans):
        o = np.array([-1.0 + 0.2 * s, 0.0, 1.0])
        wall_x = np.c_[rng.choice([-3.0, 3.0], 1500), rng.uniform(-4, 4, 1500), rng.uniform(0, 2.5, 1500)]
        wall_y = np.c_[rng.uniform(-3, 3, 1500), rng.choice([-4.0, 4.0], 1500), rng.uniform(0, 2.5, 1500)]
        floor = np.c_[rng.uniform(-3, 3, 1500), rng.uniform(-4, 4, 1500), rng.normal(0, 0.01, 1500)]
        walker = np.c_[rng.normal(1.0, 0.1, 300), rng.normal(-3 + 0.5 * s, 0.1, 300), rng.uniform(0, 1.8, 300)]
        p = np.concatenate([wall_x, wall_y, floor, walker]).astype(np.float32)
        p[rng.choice(len(p), 5, replace=False), rng.integers(0, 3)] = np.nan
        scans.append(p)
        origins.append(o)
    return scans, np.array(origins)


def test_dense_occupancy_equals_sorted_keys(monkeypatch):
    scans, _ = _scene()
    pts = [p[np.isfinite(p).all(1)] for p in scans]
    dense = B._occupancy(pts, 0.15, need_inverse=True, need_per_scan=True)
    monkeypatch.setattr(V, "DENSE_MAX_CELLS", 0)
    ref = B._occupancy(pts, 0.15, need_inverse=True, need_per_scan=True)
    for a, b in zip(dense[:2], ref[:2]):
        assert np.array_equal(a, b)
    for a, b in zip(dense[2], ref[2]):
        assert np.array_equal(a, b)
    for a, b in zip(dense[3], ref[3]):
        assert np.array_equal(a, b)
    # independent count: in how many scans each voxel has a point (python sets)
    sets = [set(map(tuple, np.floor(p.astype(np.float64) / 0.15).astype(np.int64))) for p in pts]
    allv = sorted(set().union(*sets))
    keys, occ = dense[0], dense[1]
    assert len(keys) == len(allv)
    want = dict(zip(map(tuple, V.unpack_keys(keys)), occ))
    assert all(want[v] == sum(v in s for s in sets) for v in allv[::37])


@pytest.mark.parametrize("with_origins", [True, False])
def test_build_is_the_same_on_the_dense_grid_and_with_sorted_keys(monkeypatch, with_origins):
    scans, origins = _scene()
    kw = dict(voxel=0.15, min_fraction=0.6, min_hits=2, origins=origins if with_origins else None)
    dense = VoxelBackground.build(scans, **kw)
    monkeypatch.setattr(V, "DENSE_MAX_CELLS", 0)
    ref = VoxelBackground.build(scans, **kw)
    assert len(dense) > 100
    assert np.array_equal(dense.keys, ref.keys) and np.array_equal(dense.hits, ref.hits)
    assert np.array_equal(dense.dilated, ref.dilated)


def test_member_dense_grid_equals_sorted_keys_and_sets(monkeypatch):
    scans, origins = _scene()
    bg = VoxelBackground.build(scans, voxel=0.15, min_fraction=0.6, origins=origins)
    rng = np.random.default_rng(1)
    q = np.concatenate([rng.uniform(-5, 5, (4000, 3)), scans[0][:2000].astype(np.float64),
                        [[np.nan, 0, 0], [1e5, 0, 0], [-1e5, 3, 1]]])   # inside, on, far outside the box
    static = set(map(tuple, V.unpack_keys(bg.keys)))
    grown = set(map(tuple, V.unpack_keys(bg.dilated)))
    for tol, table in ((0, static), (1, grown)):
        got = bg.contains(q, tol)
        fin = np.isfinite(q).all(1)
        ijk = np.floor(q[fin] / 0.15).astype(np.int64)
        want = np.zeros(len(q), bool)
        want[fin] = [tuple(v) in table for v in ijk]
        assert np.array_equal(got, want)
        assert got.sum() > 100
    assert bg._grids[False] is not False          # the dense grids were used
    monkeypatch.setattr(V, "DENSE_MAX_CELLS", 0)
    bg2 = VoxelBackground.build(scans, voxel=0.15, min_fraction=0.6, origins=origins)
    assert np.array_equal(bg2.contains(q, 0), bg.contains(q, 0)) and np.array_equal(bg2.contains(q), bg.contains(q))
    assert bg2._grids[False] is False and bg2._grids[True] is False   # large models: sorted keys


def test_build_float32_and_float64_points_agree():
    scans, origins = _scene(6, seed=3)
    a = VoxelBackground.build(scans, origins=origins)
    b = VoxelBackground.build([p.astype(np.float64) for p in scans], origins=origins)
    assert np.array_equal(a.keys, b.keys) and np.array_equal(a.hits, b.hits)
