"""The flat surface check of holodata.mapping.segment (issue 25 point 11): a thin cluster is dropped
only when its border continues the surrounding surface, with the thinness and the continuity measured
against the scan's own range noise (range_noise, surface_share)."""
from __future__ import annotations

import numpy as np
import pytest

from holodata.mapping.segment import SegmentConfig, segment_scan
from holodata.mapping.segment.core import _thickness, range_noise, surface_share

SLAB = dict(y=0.22, z=0.5)   # half-width, half-height (m) of the flat object / the missed wall patch


def _scan(wall_x: float, slab_x: float | None, sigma: float, seed: int = 0, H=32, W=512, fov_deg=30.0):
    """Organised scan of a face-on wall (plane x = ``wall_x``) and optionally a 1 cm thick flat
    object x in [slab_x, slab_x + 0.01], |y| <= 0.22, |z| <= 0.5 in front of it, with Gaussian range
    noise ``sigma`` (m) along the rays. Returns points (H,W,3), valid, slab mask, patch mask (the
    wall's returns in the slab's |y|, |z| window)."""
    th = np.deg2rad(np.linspace(fov_deg / 2, -fov_deg / 2, H))[:, None]
    ph = -2 * np.pi * np.arange(W)[None, :] / W + np.zeros((H, 1))
    d = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.broadcast_to(np.sin(th), ph.shape)], -1)
    fwd = d[..., 0] > 0.05
    dx = np.where(fwd, d[..., 0], 1.0)
    t = np.full((H, W), np.inf)
    tw = wall_x / dx
    wall = fwd & (np.abs(tw * d[..., 1]) < 4) & (np.abs(tw * d[..., 2]) < 3)
    t[wall] = tw[wall]
    slab = np.zeros((H, W), bool)
    if slab_x is not None:
        ts = slab_x / dx
        slab = fwd & (np.abs(ts * d[..., 1]) <= SLAB["y"]) & (np.abs(ts * d[..., 2]) <= SLAB["z"])
        t[slab] = ts[slab]
    patch = wall & ~slab & (np.abs(tw * d[..., 1]) <= SLAB["y"]) & (np.abs(tw * d[..., 2]) <= SLAB["z"])
    valid = np.isfinite(t)
    r = np.where(valid, t + sigma * np.random.default_rng(seed).normal(size=(H, W)), 0.0)
    return d * r[..., None], valid, slab, patch


CFG = SegmentConfig(min_points=5, min_height_m=0.2)


@pytest.mark.parametrize("sigma", [0.005, 0.02])
def test_range_noise_is_measured_from_the_background(sigma):
    P, valid, slab, _ = _scan(5.0, 3.0, sigma)
    est = range_noise(np.linalg.norm(P, axis=-1), valid & ~slab)
    assert est == pytest.approx(sigma, rel=0.15)
    assert np.isnan(range_noise(np.linalg.norm(P, axis=-1), slab & ~slab))   # nothing to measure on


@pytest.mark.parametrize("sigma", [0.005, 0.02])
def test_flat_object_in_front_of_the_wall_is_kept(sigma):
    """A 1 cm flat object face-on (a box robot, a board carried) is noise-thin but stands in front
    of the wall: kept. The fixed 6 cm of before rejected it."""
    P, valid, slab, _ = _scan(6.0, 3.0, sigma)
    assert slab.sum() > 50
    r = np.linalg.norm(P, axis=-1)
    assert _thickness(P[slab]) < CFG.min_depth_sigmas * range_noise(r, valid & ~slab)   # the thin branch is tested
    assert surface_share(r, valid, slab, CFG.surface_sigmas * np.sqrt(6) * sigma) < 0.2
    out = segment_scan(P, valid, background=valid & ~slab, cfg=CFG)
    assert out.max() == 1
    assert ((out == 1) == slab).mean() > 0.99


@pytest.mark.parametrize("sigma", [0.005, 0.02])
def test_wall_patch_the_background_missed_is_rejected(sigma):
    """The same-sized patch of the wall itself, left out of the background: thin and continuous
    with the wall on its border, so dropped at either noise; with the check off it is found."""
    P, valid, _, patch = _scan(4.0, None, sigma)
    assert patch.sum() > 50
    r = np.linalg.norm(P, axis=-1)
    assert surface_share(r, valid, patch, CFG.surface_sigmas * np.sqrt(6) * sigma) > 0.9
    assert segment_scan(P, valid, background=valid & ~patch, cfg=CFG).max() == 0
    off = SegmentConfig(min_points=5, min_height_m=0.2, min_depth_m=0.0)
    assert segment_scan(P, valid, background=valid & ~patch, cfg=off).max() == 1


def test_thick_object_is_not_tested_for_continuity():
    """A cluster thicker than min_depth_sigmas x the noise is kept whatever its border (a person
    leaning on a wall): a patch of wall with a 20 cm bump is not thin."""
    P, valid, _, patch = _scan(4.0, None, 0.005)
    r = np.linalg.norm(P, axis=-1)
    bump = patch & (np.arange(P.shape[1])[None, :] % 2 == 0)
    P2 = P * np.where(bump, (r - 0.2) / np.maximum(r, 1e-9), 1.0)[..., None]
    assert _thickness(P2[patch]) > 0.1
    assert segment_scan(P2, valid, background=valid & ~patch,
                        cfg=SegmentConfig(min_points=5, min_height_m=0.2, merge_xy_m=0.3)).max() >= 1
