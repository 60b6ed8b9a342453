"""LiDAR-grid human segmentation (holodata.mapping.segment) and its AP50 scoring."""
from __future__ import annotations

import numpy as np
import pytest

from holodata.mapping.human_eval import ap50, average_precision, match_scan
from holodata.mapping.segment import SegmentConfig, destagger, row_shifts, segment_scan


def _scan(H=32, W=256, az_offsets=None):
    """Organised scan of a wall (plane x = 5 m) with a box x in [3, 3.4], |y| <= 0.3, |z| <= 0.5 in
    front of it, ray-cast analytically. Row i looks at elevation th_i, column j at azimuth
    -2*pi*j/W - az_offsets[i] (a staggered grid when offsets are given). Returns points (H,W,3),
    valid, box mask, wall mask."""
    th = np.deg2rad(np.linspace(15, -15, H))[:, None]
    off = np.zeros(H) if az_offsets is None else np.asarray(az_offsets, float)
    ph = -2 * np.pi * np.arange(W)[None, :] / W - off[:, None]
    d = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.broadcast_to(np.sin(th), ph.shape)], -1)
    t = np.full((H, W), np.inf)
    box = np.zeros((H, W), bool)
    fwd = d[..., 0] > 1e-6
    # box: slab intersection
    lo, hi = np.array([3.0, -0.3, -0.5]), np.array([3.4, 0.3, 0.5])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = lo / d, hi / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit_box = fwd & (tmax >= tmin) & (tmin > 0)
    t[hit_box] = tmin[hit_box]
    box[hit_box] = True
    tw = np.where(fwd, 5.0 / np.where(fwd, d[..., 0], 1.0), np.inf)
    wall = fwd & ~hit_box & (np.abs(tw * d[..., 1]) < 4) & (np.abs(tw * d[..., 2]) < 3)
    t[wall] = tw[wall]
    valid = np.isfinite(t)
    P = np.where(valid[..., None], d * np.where(valid, t, 0)[..., None], 0.0)
    return P, valid, box, wall


def test_box_in_front_of_wall_is_exactly_one_instance():
    P, valid, box, wall = _scan()
    assert box.sum() > 50 and wall.sum() > 500
    cfg = SegmentConfig(min_points=5, min_height_m=0.2, min_depth_m=0.0)
    out = segment_scan(P, valid, background=wall, cfg=cfg)
    assert out.max() == 1
    np.testing.assert_array_equal(out == 1, box)


def test_staggered_grid_is_destaggered_from_the_data():
    W = 256
    step = 2 * np.pi / W
    shifts_true = np.array([-3, -1, 1, 3] * 8)
    P, valid, box, wall = _scan(W=W, az_offsets=shifts_true * step)
    sh = row_shifts(P, valid)
    # column azimuth = encoder - offset -> measured offset in columns = -shift
    np.testing.assert_array_equal(sh, -shifts_true)
    # destaggered, the box occupies the same columns in every row it covers
    bd = destagger(box, sh)
    cols = [np.flatnonzero(r) for r in bd if r.any()]
    assert all(len(c) == len(cols[0]) and (c == cols[0]).all() for c in cols)
    np.testing.assert_array_equal(destagger(bd, sh, inverse=True), box)
    out = segment_scan(P, valid, background=wall, cfg=SegmentConfig(min_points=5, min_height_m=0.2, min_depth_m=0.0))
    np.testing.assert_array_equal(out == 1, box)


def test_far_apart_objects_split_and_noise_is_not_seeded():
    P, valid, box, wall = _scan()
    fg = box.copy()
    # a single isolated foreground pixel on the wall (no seed survives erosion) -> dropped
    iso = np.argwhere(wall)[len(np.argwhere(wall)) // 3]
    fg[tuple(iso)] = True
    out = segment_scan(P, valid, background=~fg & valid,
                       cfg=SegmentConfig(min_points=1, min_height_m=0.0, min_depth_m=0.0))
    assert out[tuple(iso)] == 0 and (out == 1).sum() == box.sum()
    # the flood-fill distance threshold splits the box from a wall patch touching it in the grid
    patch = wall & (np.roll(box, 3, axis=1) | np.roll(box, -3, axis=1))
    out2 = segment_scan(P, valid, background=~(box | patch) & valid,
                        cfg=SegmentConfig(min_points=1, min_height_m=0.0, min_depth_m=0.0, max_width_m=np.inf))
    assert set(np.unique(out2[box])) == {1} or set(np.unique(out2[box])) == {2}
    assert not np.intersect1d(np.unique(out2[box]), np.unique(out2[patch & ~box])).size


def test_ap50_counts_and_ranks():
    t = np.zeros((4, 10), np.uint16)
    t[0, :5] = 1
    # perfect
    assert ap50([t], [t], min_truth_pixels=1)["ap"] == pytest.approx(1.0)
    # a larger false positive ranked first: precision 1/2 at recall 1 -> AP 0.5
    p = t.copy()
    p[2:, :] = 2
    r, n = match_scan(p, t, min_truth_pixels=1)
    assert n == 1 and sorted(r) == [(5.0, True), (20.0, False)]
    assert average_precision(r, n)["ap"] == pytest.approx(0.5)
    # IoU below 0.5 is a miss; tiny truth instances are ignored, predictions on them not counted
    q = np.zeros_like(t)
    q[0, :2] = 1
    assert ap50([q], [t], min_truth_pixels=1)["ap"] == 0.0
    small = np.zeros_like(t)
    small[3, 0] = 7
    res = ap50([small], [small], min_truth_pixels=5)
    assert res["n_truth"] == 0 and res["n_pred"] == 0


def test_segment_scene_on_synth_walkers():
    from _mapping_synth import small_corner

    from holodata import open_dataset
    from holodata.mapping.human_eval import segmentation_ap50
    from holodata.mapping.segment import segment_scene

    url, truth = small_corner()
    s = segment_scene(url, "recording", overwrite=True)
    sc = open_dataset(url).scene("recording")
    inst = sc["lidar/instance"]
    assert inst.dtype == np.uint16 and inst.shape == sc["lidar/range"].shape
    assert dict(inst.attrs)["dims"] == ["frame", "beam", "column"]
    assert s["instances_per_scan"] > 0.5
    res = segmentation_ap50(url, "recording", truth)
    # 32-beam scans of 10 frames: weaker than the benchmark's 64 beams (AP50 >= 0.9 there)
    assert res["n_truth"] >= 10 and res["ap"] >= 0.5, res
    # resumable: a rerun keeps the finished shards
    s2 = segment_scene(url, "recording")
    assert s2["instances_per_scan"] == 0.0
