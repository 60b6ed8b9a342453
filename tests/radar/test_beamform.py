"""The beamformer (holodata.radar) against simulated point scatterers, the aperture's predicted
main lobes, motion compensation, and a plain direct-sum implementation (tests/_radar_reference.py)."""
from __future__ import annotations

import numpy as np
import pytest
from _radar_reference import beamform_direct, beamform_direct_near, columns_direct

from holodata.conventions import Grid
from holodata.radar import (
    BeamformParams,
    ChirpConfig,
    RigEffects,
    beam_indices,
    beamform,
    beamform_attrs,
    point_at,
    simulate_rotation,
)
from holodata.radar.chirp import SPEED_OF_LIGHT

# a small radar with the same physics (chirp spacing on the circle below λ/4, 90° apertures)
SMALL = ChirpConfig(n_samples=64, rotation_radius_m=0.03, chirps_per_rotation=256)
SMALL_P = BeamformParams(grid=Grid(16, 128))
ZERO = None


def _zero(chirp):
    return np.zeros((chirp.n_virtual, chirp.n_samples), np.complex64)


def _peak(hm):
    return np.unravel_index(int(np.argmax(hm)), hm.shape)


def _subbin(profile, k):
    """Parabolic sub-bin position of a peak at index k of a 1-D magnitude profile."""
    a, b, c = profile[k - 1], profile[k], profile[k + 1]
    return k + 0.5 * (a - c) / (a - 2 * b + c)


def _width(profile, k, spacing, circular=False):
    """−3 dB (1/√2 amplitude) full width around index k, linearly interpolated, in units of spacing."""
    half = profile[k] / np.sqrt(2)
    n = profile.size

    def side(step):
        i = k
        while True:
            j = (i + step) % n if circular else i + step
            if profile[j] < half:
                return (i - k) + step * (profile[i] - half) / (profile[i] - profile[j])
            i = j

    return (side(1) - side(-1)) * spacing


def _pslr_db(cut, k, half):
    """Peak-to-sidelobe ratio (dB) of a circular 1-D cut: the peak over the highest value more than
    ``half`` samples from it (the main lobe)."""
    n = cut.size
    mask = np.ones(n, bool)
    mask[np.arange(k - half, k + half + 1) % n] = False
    return 20 * np.log10(cut[k] / cut[mask].max())


# -- geometry: peak position, range origin, main lobes -------------------------------------------------
def test_point_scatterer_peak_at_its_bin_row_and_column_full_size():
    """PanoRadar geometry, 1024 chirps → 64×512×256: a point at a bin centre, column and row lands there;
    ranges are from the rotation centre (the antennas are 10.5 cm closer: 2.8 bins)."""
    ch, p = ChirpConfig(), BeamformParams()
    dr = ch.range_resolution_m
    k0, i0, j0 = 93, 22, 371
    el = p.grid.elevations()[i0]
    az = -2 * np.pi * j0 / p.grid.W
    rot, _, _ = simulate_rotation([point_at((k0 + 0.5) * dr, az, el)], chirp=ch)
    hm = beamform(rot, ch, p, static_refl=_zero(ch))
    assert hm.shape == (256, 64, 512) and hm.dtype == np.float32
    k, i, j = _peak(hm)
    assert k == k0 and abs(i - i0) <= 1 and abs(j - j0) <= 1, (k, i, j)
    # sub-bin: the peak sits at bin k0 + 0.5 in FFT units, i.e. centre (k0 + 0.5)·dr from the centre
    assert abs(_subbin(hm[:, i, j], k) - k0) <= 0.1
    assert beamform_attrs(ch, p)["range_origin"] == "rotation_centre"


def test_main_lobe_widths_are_the_apertures():
    """−3 dB widths against the aperture's array factors at the centre wavelength: azimuth from the
    90° Hann-weighted arc of radius r, elevation from 8 antennas with uniform weights (PanoRadar's
    imaging of this geometry: 1.76° and 12.9°, issue 26)."""
    ch = ChirpConfig()
    p = BeamformParams(grid=Grid(W=1024))       # one column per chirp position: 0.35° sampling
    dr = ch.range_resolution_m
    k0, i0, j0 = 80, 31, 300                   # row 31: -0.71°
    el = p.grid.elevations()[i0]
    rot, _, _ = simulate_rotation([point_at((k0 + 0.5) * dr, -2 * np.pi * j0 / 1024, el)], chirp=ch)
    hm = beamform(rot, ch, p, static_refl=_zero(ch))
    k, i, j = _peak(hm)
    assert k == k0 and abs(i - i0) <= 1 and abs(j - j0) <= 1, (k, i, j)
    az_w = _width(hm[k, i, :], j, 360 / 1024, circular=True)
    el_w = _width(hm[k, :, j], i, 90 / 63)
    # predictions: the Hann-weighted 90° arc as a matched filter for a point at this range (exact
    # distances: at 3 m the arc's sagitta adds a quadratic phase of ~2.9 rad at its ends, which
    # widens the lobe by ~15 % over the far-field 0.98°), and the 8-antenna column (far field)
    lam = SPEED_OF_LIGHT / ch.frequencies().mean()
    R0 = (k0 + 0.5) * dr
    n_syn = p.syn_count(1024)
    m = np.arange(n_syn) - n_syn // 2
    h_ang = 2 * np.pi * m / 1024
    w = np.hanning(n_syn)
    dphi = np.deg2rad(np.linspace(-3, 3, 6001))
    r = ch.rotation_radius_m
    tgt = R0 * np.stack([np.cos(el) * np.cos(dphi), np.cos(el) * np.sin(dphi), np.full_like(dphi, np.sin(el))], -1)
    ant = r * np.stack([np.cos(h_ang), np.sin(h_ang), np.zeros_like(h_ang)], -1)
    dist = np.linalg.norm(tgt[:, None, :] - ant[None], axis=-1)
    af = np.abs((w[None] * np.exp(4j * np.pi * (dist + r * np.cos(h_ang)[None] * np.cos(el)) / lam)).sum(1))
    az_pred = _width(af, int(np.argmax(af)), 6 / 6000)
    th = np.deg2rad(np.linspace(-30, 30, 6001))
    v = np.arange(8)
    ef = np.abs(np.exp(2j * np.pi * ch.antenna_spacing_m * (7 - v)[None] * (np.sin(th)[:, None] - np.sin(el)) / lam).sum(1))
    el_pred = _width(ef, int(np.argmax(ef)), 60 / 6000)
    print(f"azimuth -3 dB: measured {az_w:.3f}°, aperture {az_pred:.3f}°; elevation: measured {el_w:.2f}°, "
          f"aperture {el_pred:.2f}°")
    assert az_w == pytest.approx(az_pred, rel=0.10)
    assert el_w == pytest.approx(el_pred, rel=0.10)


@pytest.mark.parametrize("k0, i0", [(20, 31), (39, 31), (20, 20), (39, 20)])
def test_near_field_focus_at_short_range(k0, i0):
    """PanoRadar geometry, 1024 columns: a point at 0.77 m or 1.48 m (bins 20 and 39), elevation -0.7°
    or 16.4° (rows 31 and 20). With ``focus="near"`` it lands on its bin, row and column with the −3 dB
    azimuth width of the 90° Hann arc focused on it (exact distances, the matched filter), and the
    level beyond 3° is below −35 dB; the far-field compensation smears the same point over several
    degrees (levels beyond 3° above −25 dB)."""
    ch = ChirpConfig()
    dr = ch.range_resolution_m
    j0 = 300
    out = {}
    for focus in ("far", "near"):
        p = BeamformParams(grid=Grid(W=1024), focus=focus)
        el = p.grid.elevations()[i0]
        R0 = (k0 + 0.5) * dr
        rot, _, _ = simulate_rotation([point_at(R0, -2 * np.pi * j0 / 1024, el)], chirp=ch)
        hm = beamform(rot, ch, p, static_refl=_zero(ch))
        k, i, j = _peak(hm)
        cut = hm[k, i, :]
        off = (np.arange(1024) - j) * 360 / 1024
        off = (off + 180) % 360 - 180
        out[focus] = (k, i, j, _width(cut, j, 360 / 1024, circular=True),
                      20 * np.log10(cut[np.abs(off) > 3].max() / cut[j]))
    k, i, j, width, side = out["near"]
    assert k == k0 and abs(i - i0) <= 1 and j == j0, out
    # the aperture focused on the point: sum over the arc with the exact two-way phase differences
    lam = SPEED_OF_LIGHT / ch.frequencies().mean()
    r, n_syn = ch.rotation_radius_m, BeamformParams().syn_count(1024)
    a = 2 * np.pi * (np.arange(n_syn) - n_syn // 2) / 1024
    w = np.hanning(n_syn)
    ce = np.cos(BeamformParams().grid.elevations()[i0])
    dphi = np.deg2rad(np.linspace(-3, 3, 6001))
    d = np.sqrt(R0 ** 2 + r * r - 2 * R0 * r * ce * np.cos(a[None] + dphi[:, None]))
    d0 = np.sqrt(R0 ** 2 + r * r - 2 * R0 * r * ce * np.cos(a))
    af = np.abs((w * np.exp(4j * np.pi * (d - d0[None]) / lam)).sum(1))
    pred = _width(af, int(np.argmax(af)), 6 / 6000)
    print(f"R {R0:.2f} m row {i0}: near {out['near']}, far {out['far']}, predicted width {pred:.3f} deg")
    assert width == pytest.approx(pred, rel=0.10)
    assert side < -35.0 and out["far"][4] > -25.0 and out["far"][3] > 1.5 * width, out


def test_static_reflection_removal():
    """A constant TX→RX leakage 1000× the target swamps the image unless the static reflection is removed."""
    ch, p = SMALL, SMALL_P
    dr = ch.range_resolution_m
    pt = point_at(20.5 * dr, -2 * np.pi * 40 / 128, 0.0)
    rng = np.random.default_rng(0)
    leak = 1000 * (rng.standard_normal((8, 64)) + 1j * rng.standard_normal((8, 64)))
    rot, _, _ = simulate_rotation([pt], chirp=ch, effects=RigEffects(leakage=leak))
    clean = beamform(rot, ch, p)                                   # rotation mean removed (no trajectory mean given)
    assert _peak(clean)[0] == 20 and _peak(clean)[2] == 40
    raw = beamform(rot, ch, BeamformParams(grid=Grid(16, 128), static_removal="none"))
    assert raw.max() > 10 * clean.max()


# -- moving platform -------------------------------------------------------------------------------------
def _moving_case(velocity, compensate=True):
    """PanoRadar geometry (1024 chirps, 257 per beam), three rows around 0° and one column per beam;
    antennas with a 100° (−3 dB) azimuth pattern (isotropic ones also image a point from the far side
    of the circle, 185° away, at −19 dB)."""
    ch = ChirpConfig()
    p = BeamformParams(grid=Grid(3, 1024, 1.5, -1.5))
    dr = ch.range_resolution_m
    pt = point_at(120.5 * dr, -2 * np.pi * 700 / 1024, 0.0)
    h = p.syn_count(1024) // 2
    rot, bef, aft = simulate_rotation([pt], chirp=ch, velocity=velocity, pad=h, effects=RigEffects(beamwidth_deg=100.0))
    return beamform(rot, ch, p, neighbours=(bef, aft), velocity=velocity if compensate else None,
                    static_refl=_zero(ch))


def _cut(hm):
    """Azimuth profile of the peak's row, each column's maximum over range (a sidelobe counts at
    whatever range it falls)."""
    k, i, j = _peak(hm)
    return hm[:, i, :].max(axis=0), j


def test_motion_compensation_restores_the_static_image():
    """0.5 m/s at 46° to beam 0 (0.24 mm per chirp, 6 cm over a 90° aperture), a point at 4.5 m:
    uncompensated its image smears into a shoulder on one side (peak-to-sidelobe ratio down by more
    than 3 dB), compensated the ratio is within 1 dB of the platform at rest. The main lobe is
    twice the static image's −3 dB width either side of the peak (a Hann aperture's first null)."""
    v = (0.5 * np.cos(0.8), 0.5 * np.sin(0.8))
    still_hm = _moving_case((0.0, 0.0))
    cut, j = _cut(still_hm)
    half = int(np.ceil(2 * _width(cut, j, 1.0, circular=True)))
    still = _pslr_db(cut, j, half)
    moving = _pslr_db(*_cut(_moving_case(v, compensate=False)), half)
    comp_hm = _moving_case(v)
    comp = _pslr_db(*_cut(comp_hm), half)
    assert moving < still - 3, (still, moving)
    print(f"PSLR at rest {still:.1f} dB, moving uncompensated {moving:.1f} dB, compensated {comp:.1f} dB")
    assert abs(comp - still) <= 1.0, (still, moving, comp)
    # on the scatterer's range bin as seen from the centre where it was at that beam (heading 46°,
    # target at 114°: moving away from it; 0.17 s in → 8 cm → 2.2 bins further) and within 2.5° of
    # its azimuth: the lateral part of the platform's motion adds to the antennas' tangential
    # speed during the aperture and turns the focus by ~2° at 0.5 m/s (PanoRadar's algorithm as written)
    k, i, j = _peak(comp_hm)
    travel = 0.5 * 700 / 1024 * 0.5 * np.cos(-2 * np.pi * 700 / 1024 - 0.8)
    assert abs(k - (120 - travel / ChirpConfig().range_resolution_m)) <= 1 and abs(j - 700) <= 7, (k, j)


def test_motion_reference_rotation_start_measures_from_the_start_centre():
    """PanoRadar's (b+m) motion term: ranges from the centre at chirp 0; the default (m only): from
    the centre when the beam was formed. A target ahead of a platform moving towards it is closer by
    the travel up to its beam in the second."""
    ch = SMALL
    dr = ch.range_resolution_m
    j0 = 64                                           # beam 128 of 256: half a rotation in, 0.25 s
    az = -2 * np.pi * j0 / 128
    speed = 1.2
    v = (speed * np.cos(az), speed * np.sin(az))      # moving straight at the target
    pt = point_at(40.5 * dr, az, 0.0)
    p0 = BeamformParams(grid=Grid(16, 128), motion_reference="rotation_start")
    p1 = BeamformParams(grid=Grid(16, 128), motion_reference="beam")
    h = p0.syn_count(256) // 2
    rot, bef, aft = simulate_rotation([pt], chirp=ch, velocity=v, pad=h)
    travel = speed * 128 * ch.chirp_period_s          # 0.3 m = 2 bins of 15 cm
    hs = beamform(rot, ch, p0, neighbours=(bef, aft), velocity=v, static_refl=_zero(ch))
    hb = beamform(rot, ch, p1, neighbours=(bef, aft), velocity=v, static_refl=_zero(ch))
    ks = _subbin(hs[:, 8, j0], int(np.argmax(hs[:, 8, j0])))
    kb = _subbin(hb[:, 8, j0], int(np.argmax(hb[:, 8, j0])))
    assert abs(ks - 40) <= 0.25
    assert abs(kb - (40.5 - travel / dr - 0.5)) <= 0.25


# -- against the direct sums -------------------------------------------------------------------------------
TINY = ChirpConfig(n_samples=32, rotation_radius_m=0.008, chirps_per_rotation=64)


def _tiny_case(seed=1):
    rng = np.random.default_rng(seed)
    pts = [point_at(r, a, e) for r, a, e in zip(rng.uniform(1, 8, 3), rng.uniform(-np.pi, np.pi, 3),
                                               rng.uniform(-0.5, 0.5, 3))]
    v = (0.8, -0.5)
    rot, bef, aft = simulate_rotation(pts, rng.standard_normal(3) + 1j, chirp=TINY, velocity=v, pad=8,
                                      effects=RigEffects(noise_std=0.05, leakage=rng.standard_normal((8, 32)), rng=seed))
    refl = (rot.mean(axis=0) * 0.9).astype(np.complex64)
    return rot, bef, aft, v, refl


@pytest.mark.parametrize("focus", ["far", "near"])
@pytest.mark.parametrize("case", ["static-circular", "static-padded", "moving-beam", "moving-start",
                                  "moving-circular-triangle"])
def test_fast_beamformer_equals_the_direct_sums(case, focus):
    rot, bef, aft, v, refl = _tiny_case()
    dec = "triangle" if "triangle" in case else "pick"
    ref = "rotation_start" if case == "moving-start" else "beam"
    p = BeamformParams(grid=Grid(6, 32), n_syn=17, azimuth_decimation=dec, motion_reference=ref,
                       n_range=24, focus=focus)
    kw = dict(static_refl=refl)
    if "padded" in case or case in ("moving-beam", "moving-start"):
        kw.update(neighbours=(bef, aft))
    if "moving" in case:
        kw.update(velocity=v)
    fast = beamform(rot, TINY, p, **kw)
    direct = columns_direct((beamform_direct_near if focus == "near" else beamform_direct)(rot, TINY, p, **kw), p)
    assert fast.shape == direct.shape == (24, 6, 32)
    err = np.abs(fast - direct).max() / np.abs(direct).max()
    assert err < 1e-4, err


def test_torch_path_equals_numpy_path_on_cpu():
    pytest.importorskip("torch")
    rot, bef, aft, v, refl = _tiny_case(2)
    p = BeamformParams(grid=Grid(6, 32), n_syn=17)
    for kw in (dict(), dict(neighbours=(bef, aft)), dict(neighbours=(bef, aft), velocity=v), dict(velocity=v)):
        a = beamform(rot, TINY, p, static_refl=refl, **kw)
        b = beamform(rot, TINY, p, static_refl=refl, device="cpu-torch", **kw)
        assert np.abs(a - b).max() / np.abs(a).max() < 1e-5, kw


def test_bad_arguments_are_one_line_errors():
    ch = TINY
    rot = np.zeros((64, 8, 32), np.complex64)
    with pytest.raises(ValueError, match="rotation must be"):
        beamform(rot[:, :4], ch)
    with pytest.raises(ValueError, match="before must be"):
        beamform(rot, ch, BeamformParams(grid=Grid(4, 16), n_syn=17), neighbours=(rot[:3], rot))
    with pytest.raises(ValueError, match="odd"):
        BeamformParams(n_syn=16)
    with pytest.raises(ValueError, match="exceeds"):
        beamform(rot, ch, BeamformParams(grid=Grid(4, 16), n_syn=65))


def test_params_and_chirp_round_trip_through_attrs():
    import json

    ch = ChirpConfig(rotation_radius_m=0.077, chirps_per_rotation=1204)
    p = BeamformParams(grid=Grid(32, 256), n_syn=301, chirp_window="hamming")
    a = json.loads(json.dumps(beamform_attrs(ch, p)))
    assert ChirpConfig.from_attrs(a["chirp"]) == ch
    assert BeamformParams.from_attrs(a["params"]) == p
    assert a["n_syn"] == 301 and a["range_origin"] == "rotation_centre"
    assert ch.range_resolution_m == pytest.approx(0.0375, rel=1e-3)
    assert list(beam_indices(1024, 512)[:3]) == [0, 2, 4]
