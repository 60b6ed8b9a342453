"""The learned stage two (holodata.torch.stage2 / stage2_train): analytic cores against numpy,
the ray-tracing blocks on a known mirror path, the sparse voxel network, a tiny training run and
the CLI's --stage 2 errors."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import _eval_dataset as E  # noqa: E402

from holodata.conventions import Grid  # noqa: E402
from holodata.geometry.unmirror import normals_from_range, unmirror  # noqa: E402
from holodata.torch.stage2 import (  # noqa: E402
    RayTracer,
    RayTracerConfig,
    RefinerConfig,
    SparseConv3,
    VoxelEncoder,
    VoxelRefiner,
    geometry_vector,
    local_frame,
    mirror_normals,
    neighbour_table,
    normals_from_range_t,
    ray_trace,
    refine_loss,
    reflect,
    to_local,
    voxel_point_mean,
    voxelize,
)
from holodata.torch.stage2_infer import KEEP_CANDIDATES, load_stage2  # noqa: E402
from holodata.torch.stage2_train import Stage2Config, fit_stage2, load_frames, refine_targets  # noqa: E402
from holodata.torch.train import RunOptions  # noqa: E402

G = Grid(16, 64)


def _scene_ranges(seed=0):
    rng = np.random.default_rng(seed)
    j, i = np.arange(G.W)[None, :], np.arange(G.H)[:, None]
    R = np.stack([2 + 0.3 * np.sin(j / 5 + b) + 0.05 * i + b + 0.01 * rng.standard_normal((G.H, G.W))
                  for b in range(3)])
    R[1, 3:5, 10:20] = np.nan
    return R


def test_torch_eq4_equals_numpy_on_plane_and_random_scene():
    d = G.directions()
    plane = 1.5 / np.maximum(-d[..., 2], 1e-3)  # floor z = -1.5 where the beam looks down
    plane = np.where(d[..., 2] < -0.1, plane, np.nan)[None]
    for R in (plane, _scene_ranges()):
        n_np = normals_from_range(R, G, method="difference")  # what eq. 4 in torch computes
        n_t = normals_from_range_t(torch.from_numpy(R), torch.from_numpy(d)).numpy()
        np.testing.assert_array_equal(np.isnan(n_np), np.isnan(n_t))
        np.testing.assert_allclose(n_t, n_np, atol=1e-12, equal_nan=True)
    ok = np.isfinite(normals_from_range(plane, G)).all(-1)
    np.testing.assert_allclose(normals_from_range(plane, G)[ok], np.broadcast_to([0, 0, 1.0], (ok.sum(), 3)), atol=1e-9)
    # with per-beam origins (a 10 cm circle), where the numpy version takes them
    import inspect

    if "origins" not in inspect.signature(normals_from_range).parameters:
        return
    o = 0.1 * np.stack([np.cos(G.azimuths()), np.sin(G.azimuths()), 0 * G.azimuths()], -1)[None].repeat(G.H, 0)
    R = _scene_ranges(1)
    n_t = normals_from_range_t(torch.from_numpy(R), torch.from_numpy(d), torch.from_numpy(o)).numpy()
    n_np = normals_from_range(R, G, origins=o, directions=d, method="difference")
    np.testing.assert_allclose(n_t, n_np, atol=1e-12, equal_nan=True)


def test_analytic_ray_tracer_equals_numpy_unmirror():
    R = _scene_ranges()
    d = G.directions()
    u = unmirror(R, d, grid=G)
    out = RayTracer(RayTracerConfig(hybrid=False)).double()(torch.from_numpy(R)[None], torch.from_numpy(d))
    P = out["point"][0].detach().numpy()
    np.testing.assert_array_equal(np.isnan(P), np.isnan(u["point"]))
    np.testing.assert_allclose(P, u["point"], atol=1e-9, equal_nan=True)


def test_ray_trace_reproduces_a_mirror_path():
    # a wall x = 2 (normal -x) seen from origin o; the mirror path continues to a point 1.5 m on
    o = np.array([0.1, -0.05, 0.0])
    d1 = np.array([1.0, 0.5, 0.2]) / np.linalg.norm([1.0, 0.5, 0.2])
    t = (2.0 - o[0]) / d1[0]
    p1 = o + t * d1
    d2 = d1 * np.array([-1, 1, 1])
    p2 = p1 + 1.5 * d2
    n2 = np.array([0.0, -1.0, 0.0])  # a second wall, seen in the mirror
    d3 = reflect(torch.from_numpy(d2), torch.from_numpy(n2)).numpy()
    p3 = p2 + 0.7 * d3
    R = torch.tensor([t, t + 1.5, t + 2.2], dtype=torch.float64).view(1, 3, 1, 1)
    true_n = torch.from_numpy(np.stack([[-1.0, 0, 0], n2, [0, 0, 1.0]])).view(1, 3, 1, 1, 3)
    mirrored = mirror_normals(true_n)  # what eq. 4 sees in the range images
    out = ray_trace(R, torch.from_numpy(d1).view(1, 1, 1, 3), torch.from_numpy(o).view(1, 1, 1, 3), mirrored)
    np.testing.assert_allclose(out["point"][0, :, 0, 0].numpy(), np.stack([p1, p2, p3]), atol=1e-12)
    np.testing.assert_allclose(out["normal"].numpy(), true_n.numpy(), atol=1e-12)  # eq. 5 un-mirrors them
    np.testing.assert_allclose(out["direction"][0, 2, 0, 0].numpy(), d3, atol=1e-12)
    # the geometry vector of eq. 4: b_0 = 1; a normal facing the beam head-on has b = (1, 0, 0)
    fr = local_frame(torch.from_numpy(d1).view(1, 1, 3))
    b = geometry_vector(to_local(-torch.from_numpy(d1).view(1, 1, 3), fr))
    np.testing.assert_allclose(b.numpy().ravel(), [1, 0, 0], atol=1e-12)


def test_hybrid_block_starts_close_to_analytic_and_has_gradients():
    R = torch.from_numpy(_scene_ranges()).float()[None]
    d = torch.from_numpy(G.directions()).float()
    rt = RayTracer(RayTracerConfig(channels=8, res_blocks=2, fusion_blocks=1))
    out = rt(R, d)
    ana = RayTracer(RayTracerConfig(hybrid=False))(R, d)
    ok = torch.isfinite(ana["mirrored"][:, 0]).all(-1)
    cos = (out["mirrored"][:, 0][ok] * ana["mirrored"][:, 0][ok]).sum(-1)
    assert float(cos.detach().min()) > 0.999
    loss = torch.nan_to_num(out["point"]).abs().mean()
    loss.backward()
    assert all(p.grad is not None for p in rt.blocks[0].parameters())


def test_voxel_encoder_averages_and_sparse_conv_equals_dense():
    pts = torch.tensor([[0.01, 0.02, 0.03], [0.05, 0.06, 0.07], [0.31, 0.0, 0.0]])
    vox = voxelize(pts, torch.zeros(3, dtype=torch.long), torch.tensor([0, 1, 2]), torch.zeros(3), 0.1, 9.6)
    assert len(vox.coords) == 2 and vox.point_voxel[0] == vox.point_voxel[1]
    assert float(vox.features[0, 9]) == pytest.approx(np.log1p(2))  # count feature
    enc = VoxelEncoder(vox.features.shape[1], 5)
    v = enc(vox.features, vox.point_voxel, len(vox.coords))
    e = enc.mlp(vox.features)
    torch.testing.assert_close(v[vox.point_voxel[0]], (e[0] + e[1]) / 2)
    torch.testing.assert_close(v[vox.point_voxel[2]], e[2])
    # submanifold conv == dense conv3d read at the occupied voxels
    g = torch.Generator().manual_seed(0)
    occ = torch.rand(6, 7, 5, generator=g) < 0.4
    ijk = torch.nonzero(occ)
    coords = torch.cat([torch.zeros(len(ijk), 1, dtype=torch.long), ijk], 1)
    x = torch.randn(len(ijk), 3, generator=g)
    conv = SparseConv3(3, 4)
    y = conv(x, neighbour_table(coords))
    dense = torch.zeros(1, 3, 6, 7, 5)
    dense[0, :, ijk[:, 0], ijk[:, 1], ijk[:, 2]] = x.T
    w = conv.weight.detach().view(3, 3, 3, 3, 4).permute(4, 3, 0, 1, 2)  # (out, in, kx, ky, kz)
    yd = torch.nn.functional.conv3d(dense, w, conv.bias.detach(), padding=1)[0, :, ijk[:, 0], ijk[:, 1], ijk[:, 2]].T
    torch.testing.assert_close(y.detach(), yd, atol=1e-5, rtol=1e-5)


def test_refine_targets_and_loss():
    gt = [np.array([[0.05, 0.05, 0.05], [0.07, 0.03, 0.05], [0.55, 0.05, 0.05]])]
    hum = [np.array([False, False, True])]
    coords = torch.tensor([[0, 0, 0, 0], [0, 5, 0, 0], [0, 3, 0, 0]])
    cls, reg, edt = refine_targets(coords, gt, hum, 0.1, 8.0)
    assert cls.tolist() == [2, 1, 0]
    torch.testing.assert_close(reg[0], torch.tensor([0.01, -0.01, 0.0]), atol=1e-6, rtol=0)
    assert edt.tolist() == [0.0, 0.0, 2.0]
    # the EDT term against scipy's distance transform of the GT occupancy
    from scipy.ndimage import distance_transform_edt

    rng = np.random.default_rng(1)
    occ = rng.random((20, 20, 6)) < 0.02
    gpts = (np.argwhere(occ) + 0.5) * 0.1
    q = np.argwhere(np.ones_like(occ))
    _, _, e = refine_targets(torch.from_numpy(np.c_[np.zeros(len(q), int), q]), [gpts], [np.zeros(len(gpts), bool)],
                             0.1, 3.0)
    want = np.minimum(distance_transform_edt(~occ), 3.0)[q[:, 0], q[:, 1], q[:, 2]]
    np.testing.assert_allclose(e.numpy(), want, atol=1e-5)
    ref = VoxelRefiner(RefinerConfig(channels=(8, 8), voxel=0.1))
    pts = torch.tensor(gt[0]).float()
    vox = voxelize(pts, torch.zeros(3, dtype=torch.long), torch.zeros(3, dtype=torch.long), torch.zeros(3), 0.1, 9.6)
    out = ref(vox)
    c, r, e = refine_targets(vox.coords, gt, hum, 0.1, 8.0)
    loss, parts = refine_loss(out, c, r, e)
    assert set(parts) == {"cls", "reg", "dist"} and torch.isfinite(loss)


def test_refined_voxels_inherit_los_and_human_from_their_points():
    """Two points share voxel 0 (one LOS, one not; human 0.9 / 0.3), one point alone in voxel 1:
    the voxel means are what Stage2.predict thresholds at 0.5."""
    pts = torch.tensor([[0.01, 0.01, 0.01], [0.02, 0.02, 0.02], [0.51, 0.01, 0.01]])
    z = torch.zeros(3, dtype=torch.long)
    los = torch.tensor([1.0, 0.0, 0.0])
    hum = torch.tensor([0.9, 0.3, 0.8])
    vox = voxelize(pts, z, z, hum, 0.1, 9.6, los=los)
    first = vox.point_voxel[0]
    torch.testing.assert_close(voxel_point_mean(vox, los)[first], torch.tensor(0.5))
    torch.testing.assert_close(voxel_point_mean(vox, hum)[vox.point_voxel[2]], torch.tensor(0.8))
    torch.testing.assert_close(voxel_point_mean(vox, hum)[first], torch.tensor(0.6))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return E.build(str(tmp_path_factory.mktemp("ds2") / "tiny.zarr"), frames=2)


TINY2 = dict(channels=8, res_blocks=1, fusion_blocks=1, refine_channels=[8, 8], batch_size=2, p_stage1=0.0, lr=3e-3,
             p_clean=1.0, flip=False)


def test_tiny_training_run_decreases_loss_and_resumes(dataset, tmp_path):
    frames, grid = load_frames(dataset, "train", 1)
    cfg = Stage2Config(epochs_rt=3, epochs_refine=2, **TINY2)
    res = fit_stage2(frames, tmp_path / "run", cfg, 9.6, grid, RunOptions(quiet=True))
    h = res["history"]
    rt_loss = [r["loss"] for r in h if r["phase"] == "rt"]
    ref_loss = [r["loss"] for r in h if r["phase"] == "refine"]
    assert rt_loss[-1] < rt_loss[0] and ref_loss[-1] < ref_loss[0]
    s2, ck = load_stage2(tmp_path / "run")
    assert s2.refiner is not None and ck["epoch"] == 5
    fr = frames
    p = s2.predict(fr.range[0], None, fr.directions[0], fr.origins[0], grid)
    assert p["no_refine"]["point"].shape == fr.gt_point[0].shape and p["refined"]["point"].shape[1] == 3
    # the keep threshold was calibrated on the training frames and is what predict applies
    keep = ck["keep"]
    assert set(keep["scores"]) == set(KEEP_CANDIDATES) and keep["scores"][keep["threshold"]] == max(keep["scores"].values())
    assert s2.keep_threshold == keep["threshold"]
    allv = s2.predict(fr.range[0], None, fr.directions[0], fr.origins[0], grid, all_voxels=True)["refined"]
    assert len(p["refined"]["point"]) == int((allv["p_empty"] < keep["threshold"]).sum())
    # the refined cloud is the ray-traced points the refiner keeps, where the ray tracer put them:
    # keeping every voxel gives the no_refine points (and their LOS flags) exactly
    nr = p["no_refine"]
    ok = np.isfinite(nr["point"]).all(-1)
    assert np.array_equal(allv["point"], nr["point"][ok]) and np.array_equal(allv["los"], nr["los"][ok])
    kept = allv["p_empty"] < keep["threshold"]
    assert np.array_equal(p["refined"]["point"], nr["point"][ok][kept])
    # resume: the same config with more refiner epochs continues after epoch 5
    res2 = fit_stage2(frames, tmp_path / "run", Stage2Config(epochs_rt=3, epochs_refine=3, **TINY2), 9.6, grid,
                      RunOptions(quiet=True))
    assert res2["resumed_from"] == 5 and len(res2["history"]) == 6 and res2["keep"] is not None
    lines = (tmp_path / "run" / "stage2_metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["epoch"] for x in lines] == list(range(1, 7))


def test_cli_stage2_errors_are_one_line(dataset, tmp_path):
    from click.testing import CliRunner

    from holodata.cli.main import cli
    from holodata.torch import TrainConfig, train

    r = CliRunner().invoke(cli, ["train", dataset, "--out", str(tmp_path / "r"), "--stage", "2",
                                 "--stage1", str(tmp_path / "nope.pt")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1 and "nope.pt" in r.output
    run = tmp_path / "s1"
    train(dataset, run, TrainConfig(epochs=1, depth=2, base_channels=4, max_channels=4, blocks=1), quiet=True)
    ck = torch.load(run / "checkpoint.pt", weights_only=False)
    ck["meta"]["grid"] = {"H": 8, "W": 32, "elev_deg": [45.0, -45.0]}
    torch.save(ck, tmp_path / "other.pt")
    r = CliRunner().invoke(cli, ["train", dataset, "--out", str(tmp_path / "r"), "--stage", "2",
                                 "--stage1", str(tmp_path / "other.pt")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1 and "grid" in r.output
    cfg = tmp_path / "s2.yaml"
    cfg.write_text(json.dumps({k: v for k, v in TINY2.items()}))
    r = CliRunner().invoke(cli, ["train", dataset, "--out", str(tmp_path / "r"), "--stage", "2", "--stage1", str(run),
                                 "--stage2-config", str(cfg), "--stage2-epochs", "1", "--quiet", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["stage2"]["epochs"] == 2 and (tmp_path / "r" / "stage2.pt").exists() and (tmp_path / "r" / "checkpoint.pt").exists()


def test_confidence_gate_drops_the_unsure_bounce(dataset):
    """Stage one right and sure on bounces 1-2, wrong and unsure on bounce 3: the gate calibrated on
    those frames drops bounce 3 (its best score beats keeping it) and keeps bounce 2."""
    from holodata.torch.stage2_infer import GATE_CANDIDATES, calibrate_gate

    frames, grid = load_frames(dataset, "train", 1)
    s1 = frames.range.astype(np.float64).copy()
    s1[:, 2] += np.random.default_rng(0).uniform(0.5, 1.5, s1[:, 2].shape)   # bounce 3 decimetres off
    conf = np.ones(s1.shape)
    conf[:, 2] = 0.3
    gate = calibrate_gate(s1, conf, frames, grid)
    assert gate["min_confidence"][0] == 0.0 and gate["min_confidence"][1] == 0.0
    assert gate["min_confidence"][2] > 0.3
    b3 = gate["scores"]["b3"]
    assert set(b3) == set(GATE_CANDIDATES) and b3[gate["min_confidence"][2]] > b3[0.0]


def test_model_confidence_and_the_gate():
    from holodata.torch.model import ModelConfig, MultiReturnUNet
    from holodata.torch.stage2_infer import apply_gate

    m = MultiReturnUNet(ModelConfig(in_channels=16, depth=2, base_channels=4, max_channels=4, blocks=1)).eval()
    pred = m.predict(torch.randn(1, 16, 8, 32), valid_threshold=0.0)
    conf, rng = pred["confidence"].numpy()[0], pred["range"].numpy()[0]
    assert conf.shape == (3, 8, 32) and bool(((conf > 0) & (conf <= 1 + 1e-6)).all())
    cut = float(np.median(conf[2]))
    gated = apply_gate(rng, conf, [0.0, 0.0, cut])
    np.testing.assert_array_equal(gated[:2], rng[:2])
    np.testing.assert_array_equal(np.isfinite(gated[2]), conf[2] >= cut)
    assert apply_gate(rng, conf, None) is rng
