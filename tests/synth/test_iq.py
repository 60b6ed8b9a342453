"""synth's raw I/Q path: the gridded beat-sample kernel against the direct sum, RadarModel.iq against
the point-scatterer simulator and against the direct heatmap path through the beamformer (same cell,
same amplitude scale, noise floor), a moving platform refocused by the recorded motion, and a whole
``synthesize(SynthSpec(radar_output="iq"))`` → ``ingest`` round trip that validates."""
from __future__ import annotations

import importlib

import numpy as np
import pytest

from holodata.conventions import Grid, RangeBins
from holodata.radar import BeamformParams
from holodata.radar._iq_kernel import ChirpSites, beat_samples
from holodata.radar.chirp import SPEED_OF_LIGHT, ChirpConfig
from holodata.radar.simulate import antenna_positions, simulate_chirps
from holodata.synth.radar import RadarConfig, RadarModel
from holodata.synth.worlds import MATERIAL_ID, MATERIALS

bf = importlib.import_module("holodata.radar.beamform")
G = Grid(32, 128)


@pytest.mark.parametrize("where", ["far", "near"])
def test_gridded_beat_samples_equal_the_direct_sum(where):
    ch = ChirpConfig()
    rng = np.random.default_rng(0)
    if where == "far":
        P = rng.uniform(-6, 6, (40, 3)) * [1, 1, 0.3]
    else:   # 0.4-0.9 m from the rotation centre, up to 65 degrees up or down: the antennas' distances curve most
        P = np.c_[rng.uniform(0.3, 0.6, (40, 2)), rng.uniform(-1.0, 1.0, 40)]
    a = rng.standard_normal(40) + 1j * rng.standard_normal(40)
    idx = np.arange(0, 1024, 41)
    ref = simulate_chirps(P, a, ch, chirp_index=idx)
    phi = -2 * np.pi * idx / 1024
    ant = antenna_positions(ch, idx, 1024)
    got = beat_samples(ChirpSites(ant, np.zeros((idx.size, 3)), np.stack([np.cos(phi), np.sin(phi)], 1)), P, a, ch)
    assert np.abs(got - ref).max() <= 3e-5 * np.abs(ref).max()
    # the kernel spreads a scatterer onto one window for all of a chirp's antennas: among these are
    # scatterers whose antennas straddle a cell boundary (about 1 in 10 here)
    u = np.linalg.norm(P[None, None] - ant[:, :, None], axis=-1) * (
        2 * ch.slope_hz_per_s / (SPEED_OF_LIGHT * ch.sample_rate_hz) * 2 * ch.n_samples)
    straddle = np.floor(u).min(1) != np.floor(u).max(1)
    assert 0 < straddle.sum() < straddle.size


def _model(grid=G, **kw):
    kw = {"noise_amplitude": 0.0, "leakage_amplitude": 0.0, **kw}
    cfg = RadarConfig(grid=grid, range_bins=RangeBins(256, 0.0375), chirps_per_rotation=512, **kw)
    return RadarModel(cfg, MATERIALS, np.zeros(1, np.uint8), MATERIAL_ID["human"])


def _rotation(model, paths, velocity=(0.0, 0.0)):
    """Raw samples of one rotation (+ neighbours) from a platform at the origin moving at ``velocity``."""
    cfg = model.cfg
    chirp, n_syn = cfg.imaging()
    N, pad = cfg.chirps_per_rotation, n_syn // 2
    n = np.arange(-pad, N + pad)
    poses = np.broadcast_to(np.eye(4), (n.size, 4, 4)).copy()
    poses[:, 0, 3] = n * chirp.chirp_period_s * velocity[0]
    poses[:, 1, 3] = n * chirp.chirp_period_s * velocity[1]
    d = cfg.grid.directions().reshape(-1, 3)
    return model.iq(paths, np.zeros_like(d), d, poses, n, None), chirp, pad


def _paths(cells, grid=G):
    """One first-bounce path per (row, column, range m, amplitude)."""
    c = np.array(cells, dtype=object)
    return {"pix": np.array([r * grid.W + j for r, j, _, _ in cells]), "bounce": np.ones(len(cells), int),
            "range": c[:, 2].astype(float), "amp": c[:, 3].astype(complex), "human": np.zeros(len(cells), bool)}


def test_raw_rotation_is_the_point_simulator_on_the_chirps_that_see_it():
    """Isotropic antennas: the point simulator's samples on every chirp facing the scatterer's
    half-space, nothing on the others; with the antennas' pattern each chirp's samples scale by
    cos(off)^q, half at ±beamwidth/2."""
    model = _model(element_beamwidth_deg=None)
    paths = _paths([(12, 40, 3.0, 1.0)])
    iq, chirp, pad = _rotation(model, paths)
    d = G.directions()[12, 40]
    N = model.cfg.chirps_per_rotation
    n = np.arange(-pad, N + pad)
    ref = simulate_chirps((3.0 * d)[None], [model.raw_scale()[0]], chirp, chirp_index=n, n_chirps=N)
    off = np.abs(np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) + 2 * np.pi * n / N))))
    seen, behind = off < np.pi / 2 - 1e-6, off > np.pi / 2 + 1e-6
    assert 150 < seen.sum() < n.size
    assert np.abs(iq[seen] - ref[seen]).max() <= 1e-4 * np.abs(ref).max()
    assert np.abs(iq[behind]).max() == 0          # behind the board: not seen
    bw = 100.0
    patterned, _, _ = _rotation(_model(element_beamwidth_deg=bw), paths)
    gain = np.abs(patterned[seen]).max(axis=(1, 2)) / np.abs(iq[seen]).max(axis=(1, 2))
    q = np.log(0.5) / np.log(np.cos(np.deg2rad(bw / 2)))
    np.testing.assert_allclose(gain, np.cos(off[seen]) ** q, rtol=1e-3, atol=1e-6)


def test_beamformed_raw_samples_match_the_direct_heatmap_path():
    """The same paths → the same cells, amplitudes within 1.5 dB (the direct path leaves out the
    beamformer's defocus loss), and the thermal noise floor the direct path has."""
    model = _model()
    paths = _paths([(12, 40, 3.0, 1.0), (20, 100, 5.0, 0.3j), (15, 70, 7.5, 0.1)])
    direct = model.cube(paths, None)
    iq, chirp, pad = _rotation(model, paths)
    N = model.cfg.chirps_per_rotation
    p = BeamformParams(grid=G, static_removal="none")
    hm = bf.beamform(iq[pad:N + pad], chirp, p, neighbours=(iq[:pad], iq[N + pad:]))
    for r, j, rm in ((12, 40, 3.0), (20, 100, 5.0), (15, 70, 7.5)):
        k = int(rm / 0.0375)
        win = np.s_[k - 2:k + 3, max(r - 2, 0):r + 3, j - 2:j + 3]
        pd = np.unravel_index(np.argmax(direct[win]), direct[win].shape)
        pr = np.unravel_index(np.argmax(hm[win]), hm[win].shape)
        assert abs(pd[0] - pr[0]) <= 1 and abs(pd[1] - pr[1]) <= 1 and pd[2] == pr[2] == 2, (pd, pr)
        ratio_db = 20 * np.log10(hm[win].max() / direct[win].max())
        assert -1.5 <= ratio_db <= 0.5, (r, j, ratio_db)
    noisy = _model(noise_amplitude=2e-3)
    iq = noisy.iq(_paths([(0, 0, 9.0, 0.0)]), np.zeros((G.H * G.W, 3)), G.directions().reshape(-1, 3),
                  np.broadcast_to(np.eye(4), (N + 2 * pad, 4, 4)), np.arange(-pad, N + pad), np.random.default_rng(1))
    floor = bf.beamform(iq[pad:N + pad], chirp, p, neighbours=(iq[:pad], iq[N + pad:]))
    rms = np.sqrt(np.mean(floor[20:200] ** 2))
    assert rms == pytest.approx(2e-3, rel=0.1)


def test_a_moving_platform_is_refocused_by_its_motion():
    """0.5 m/s, 20° off the line to a point at 4 m: beamformed without motion compensation its peak
    drops; with the velocity the rotation's messages carry it is back within 1 dB of the platform at
    rest. One beam per chirp (a 128-column grid samples the lobe every 2.8°, and a moving image's
    peak falls between columns)."""
    g = Grid(3, 512, 2.0, -2.0)
    model = _model(g)
    paths = _paths([(1, 320, 4.0, 1.0)], g)
    N = model.cfg.chirps_per_rotation
    p = BeamformParams(grid=g, static_removal="none")

    def image(v, compensate):
        iq, chirp, pad = _rotation(model, paths, v)
        return bf.beamform(iq[pad:N + pad], chirp, p, neighbours=(iq[:pad], iq[N + pad:]),
                           velocity=v if compensate else None, chirp_period_s=chirp.chirp_period_s)

    still = image((0.0, 0.0), False).max()
    az = -2 * np.pi * 320 / 512
    v = (0.5 * np.cos(az + 0.35), 0.5 * np.sin(az + 0.35))
    smeared, focused = image(v, False).max(), image(v, True).max()
    assert 20 * np.log10(smeared / still) < -1.0
    assert abs(20 * np.log10(focused / still)) <= 1.0


@pytest.mark.slow
def test_synth_iq_recording_ingests_into_a_dataset_that_validates(tmp_path):
    from holodata.dataset import open_dataset
    from holodata.dataset.validate import validate_dataset
    from holodata.ingest import IngestOptions, ingest
    from holodata.synth import RAW_TOPIC, SynthSpec, synthesize

    kw = dict(corner="L", frames=2, seed=3, grid=G, lidar_shape=(16, 256), camera_shape=(94, 168), radar_chirps=512)
    iq = synthesize(tmp_path / "iq", SynthSpec(radar_output="iq", **kw), quiet=True)
    hm = synthesize(tmp_path / "hm", SynthSpec(**kw), quiet=True)
    assert iq.counts[RAW_TOPIC] == 2 and "/radar/heatmap" not in iq.counts
    url = str(tmp_path / "d.zarr")
    ingest([str(iq.recording), str(hm.recording)], url, IngestOptions(beamform=BeamformParams(grid=G)),
           scene_ids=["iq", "hm"], quiet=True)
    assert validate_dataset(url, quiet=True)["ok"]
    ds = open_dataset(url)
    a, b = ds.scene("iq"), ds.scene("hm")
    assert a.attrs["source"]["beamform"]["params"]["n_azimuth"] == G.W
    A, B = (np.asarray(s["radar/heatmap"][...], np.float32)[:, 8:] for s in (a, b))
    assert A.shape == B.shape
    for f in range(2):   # the same scene: the two heatmaps agree in dB where either is strong
        la, lb = 20 * np.log10(A[f] + 1e-6), 20 * np.log10(B[f] + 1e-6)
        strong = lb > lb.max() - 40
        assert np.corrcoef(la[strong], lb[strong])[0, 1] > 0.5
        assert abs(np.median(la) - np.median(lb)) < 3.0      # the same noise floor


def test_rotations_share_their_neighbouring_chirps_and_keep_their_own():
    """The raw samples of consecutive rotations are one chirp stream, as a rig records it: the n_syn/2
    chirps before rotation k are rotation k−1's last ones and those after it rotation k+1's first ones,
    the same samples. A rotation's own chirps (and the first rotation's before, the last one's after)
    are what RadarModel.iq gives for its paths over its whole window with its noise stream."""
    import dataclasses

    from holodata.synth.scene import Sensors, _rng, build_scenario
    from holodata.synth.spec import SceneSpec

    sc = build_scenario(SceneSpec("L", frames=3, seed=5, grid=Grid(8, 32), lidar_shape=(8, 64), camera_shape=(12, 20),
                                  radar_chirps=64))
    s = Sensors(dataclasses.replace(sc, radar_output="iq"))
    msgs = [s.radar_rotation(k)[0] for k in range(3)]
    N, pad = msgs[0]["n_rotation"], msgs[0]["n_before"]
    assert N == 64 and pad == msgs[0]["n_after"] > 0
    c = [m["chirps"] for m in msgs]
    assert all(x.shape == (N + 2 * pad, 8, 256) for x in c)
    for k in (1, 2):
        assert np.array_equal(c[k][:pad], c[k - 1][N:N + pad])           # before = the previous one's last
        assert np.array_equal(c[k - 1][N + pad:], c[k][pad:2 * pad])     # after = the next one's first
    for k in range(3):      # the whole window from the rotation's own paths and noise stream
        paths, O, D = s._radar_paths(k)
        start, end = sc.radar_cycle(k)
        n = np.arange(-pad, N + pad)
        poses = sc.truth.interpolate(start + np.round((n + 0.5) / N * (end - start)).astype(np.int64)) @ sc.T_base_radar
        whole = s.radar.iq(paths, O, D, poses, n, _rng(sc.seed, "radar", k))
        own = slice(0 if k == 0 else pad, N + 2 * pad if k == 2 else N + pad)
        assert np.array_equal(c[k][own], whole[own])
