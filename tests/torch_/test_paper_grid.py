"""Stage one trained on azimuth crops and run on whole rings (issue 51 point 3), and the paper's human
protocol beside every Table-2 row (issue 52 point 2)."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from holodata.torch.checkpoint import inference_transform  # noqa: E402
from holodata.torch.model import ModelConfig, MultiReturnUNet  # noqa: E402


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    m = MultiReturnUNet(ModelConfig(in_channels=8, depth=3, base_channels=4, max_channels=8)).eval()
    for p in m.parameters():
        torch.nn.init.normal_(p, std=0.2)
    return m


def test_ring_forward_is_each_columns_central_window(model):
    """Every output column is the plain forward of the window it sits in the middle half of, the
    windows wrapping around the ring (column 0's window starts at column W - window/4)."""
    x = torch.randn(2, 8, 4, 32)
    W, window = 32, 16
    step, q = window // 2, window // 4
    with torch.no_grad():
        ring = model.ring_forward(x, window)
        assert {k: tuple(v.shape[-2:]) for k, v in ring.items()} == {k: (4, W) for k in ring}
        for c in range(W):
            start = (c // step) * step - q
            cols = [(start + i) % W for i in range(window)]
            plain = model.forward(x[..., cols])
            for k in ring:
                torch.testing.assert_close(ring[k][..., c], plain[k][..., cols.index(c)], rtol=1e-5, atol=1e-5)


def test_ring_forward_turns_with_the_ring(model):
    """Rolling the ring by a multiple of the window step rolls the prediction (no seam at column 0)."""
    x = torch.randn(1, 8, 4, 32)
    with torch.no_grad():
        a = model.ring_forward(x, 16)["range"]
        b = model.ring_forward(torch.roll(x, 8, -1), 16)["range"]
    torch.testing.assert_close(torch.roll(a, 8, -1), b, rtol=1e-5, atol=1e-5)


def test_no_window_or_one_that_does_not_tile_is_the_plain_forward(model):
    x = torch.randn(1, 8, 4, 30)
    with torch.no_grad():
        plain = model.forward(x)["range"]
        for window in (None, 16, 30, 64):   # 16: 30 is not a multiple of 8; 30, 64: not narrower than the ring
            torch.testing.assert_close(model.ring_forward(x, window)["range"], plain)


def test_inference_transform_reads_the_run():
    tf, window = inference_transform({"transform": {"downsample": 2, "range_pool": 2, "crop_w": 128,
                                                    "random_crop": True, "roll": True}})
    assert (tf.downsample, tf.range_pool, tf.crop_w, tf.random_crop, tf.roll, window) == (2, 2, None, False, False, 128)
    tf, window = inference_transform({})
    assert (tf.downsample, tf.range_pool, window) == (1, 1, None)


def test_tables_show_the_human_protocol_for_all_and_hidden_frames():
    from holodata.evaluate.report import format_tables

    rng = {f"bounce_{b}": {"mean_cm": 1.0, "median_cm": 1.0, "p90_cm": 1.0} for b in (1, 2, 3)}
    cloud = {"cd": 0.1, "mhd": 0.1, "f_score": 0.5}
    hum = {"precision": 0.9, "recall": 0.973, "f_score": 0.935, "loc_mean_cm": 13.8, "loc_median_cm": 12.6,
           "n_pred": 10, "n_gt": 10}
    hidden = {"precision": 0.5, "recall": 0.25, "f_score": 1 / 3, "loc_mean_cm": 21.0, "loc_median_cm": 19.5,
              "n_pred": 2, "n_gt": 4}
    doc = {"split": "test", "n_frames": 2, "scenes": ["a"], "settings": {},
           "methods": {"model": {"range": rng, "points": {"los": cloud, "nlos": cloud}, "human": hum,
                                 "human_hidden": hidden},
                       "baseline": {"range": rng, "points": {"los": cloud, "nlos": cloud}, "human": hum,
                                    "human_hidden": {**hidden, "f_score": float("nan")}}}}
    text = format_tables(doc)
    row = next(ln for ln in text.splitlines()[text.splitlines().index(
        next(ln for ln in text.splitlines() if ln.startswith("human detection"))):] if ln.strip().startswith("model"))
    nums = [float(v) for v in row.split()[1:]]
    np.testing.assert_allclose(nums, [90.0, 97.3, 93.5, 13.8, 12.6, 50.0, 25.0, 33.3, 21.0, 19.5], atol=0.06)
    assert "nan" not in text


def test_stage_two_batches_crop_the_beams_but_not_the_los_image():
    from holodata.torch.stage2_infer import Frames
    from holodata.torch.stage2_train import Stage2Config, make_batch

    T, H, W, cw = 3, 4, 16, 6
    col = np.broadcast_to(np.arange(W, dtype=np.float32), (T, 3, H, W)) + 100 * np.arange(T)[:, None, None, None]
    pts = np.repeat(col[..., None], 3, -1).copy()
    geo = np.repeat(col[:, 0, ..., None], 3, -1).copy()
    fr = Frames(range=col.copy(), label=np.zeros((T, 3, H, W), np.uint8), gt_point=pts, gt_normal=pts.copy(),
                origins=geo, directions=geo.copy(), keys=[("s", k) for k in range(T)])
    cfg = Stage2Config(crop_w=cw, flip=False, p_clean=1.0)
    b = make_batch(fr, np.array([2, 0]), cfg, np.random.default_rng(0), "cpu")
    assert tuple(b["range"].shape) == (2, 3, H, cw) and tuple(b["gt_point"].shape) == (2, 3, H, cw, 3)
    assert tuple(b["origins"].shape) == (2, H, cw, 3) and tuple(b["los_range"].shape) == (2, H, W)
    for j, t in enumerate((2, 0)):
        c = b["range"][j].numpy() - 100 * t                 # the stored column numbers
        assert np.all((c - c[..., :1]) % W == np.arange(cw))   # one window of consecutive columns, wrapping
        np.testing.assert_array_equal(b["range_in"][j].numpy(), b["range"][j].numpy())
        for k in ("gt_point", "gt_normal"):       # the same columns of every array
            np.testing.assert_array_equal(b[k][j].numpy()[..., 0], b["range"][j].numpy())
        np.testing.assert_array_equal(b["origins"][j].numpy()[..., 0], b["range"][j].numpy()[0])
        np.testing.assert_array_equal(b["los_range"][j].numpy(), fr.range[t, 0])
    full = make_batch(fr, np.array([1]), Stage2Config(flip=False, p_clean=1.0), np.random.default_rng(0), "cpu")
    assert tuple(full["range"].shape) == (1, 3, H, W)


def test_calibrate_human_picks_the_threshold_that_finds_the_person():
    from holodata.conventions import Grid, Label
    from holodata.torch.stage2_infer import Frames, calibrate_human

    H, W = 2, 8
    rng = np.random.default_rng(0)
    person = np.array([3.0, 0.0, 0.0]) + rng.normal(0, 0.05, (10, 3))
    ghost = np.array([0.0, 3.0, 0.0]) + rng.normal(0, 0.05, (10, 3))
    wall = np.stack([np.full(20, 5.0), np.linspace(-2, 2, 20), np.zeros(20)], 1)

    class FakeStage2:   # the refined cloud of every frame: a faint person, a fainter ghost, a wall
        keep_threshold, human_threshold = 0.8, 0.5

        def predict(self, R, human, directions, origins, grid, all_voxels=False):
            P = np.concatenate([person, ghost, wall])
            score = np.concatenate([np.full(10, 0.3), np.full(10, 0.12), np.full(20, 0.02)])
            return {"refined": {"point": P, "p_empty": np.zeros(len(P)), "human_score": score}}

    def frames(with_person: bool):
        gp = np.full((3, 3, H, W, 3), np.nan)
        lab = np.zeros((3, 3, H, W), np.uint8)
        if with_person:
            gp[:, 1, 0, :, :] = person[:W]
            lab[:, 1, 0, :] = Label.NLOS_HUMAN
        z = np.zeros((3, H, W, 3), np.float32)
        return Frames(range=np.full((3, 3, H, W), np.nan, np.float32), label=lab, gt_point=gp, gt_normal=gp.copy(),
                      origins=z, directions=z.copy(), keys=[("s", k) for k in range(3)])

    got = calibrate_human(FakeStage2(), frames(True), Grid(H, W))
    assert got["scores"][0.1] == pytest.approx(2 / 3) and got["scores"][0.4] == 0.0
    assert got["threshold"] == 0.3 and got["scores"][0.3] == 1.0   # the highest of the best
    assert calibrate_human(FakeStage2(), frames(False), Grid(H, W)) == {"threshold": 0.5, "scores": {}}


def test_the_human_term_can_keep_only_its_hardest_pixels():
    import torch.nn.functional as F

    from holodata.conventions import Label
    from holodata.errors import InputError
    from holodata.torch import TrainConfig
    from holodata.torch.losses import LossWeights, multi_return_loss

    g = torch.Generator().manual_seed(0)
    B, H, W = 2, 4, 8
    out = {"range": torch.rand(B, 3, H, W, generator=g) * 5, "valid_logit": torch.randn(B, 3, H, W, generator=g),
           "human_logit": torch.randn(B, 3, H, W, generator=g)}
    gt = torch.rand(B, 3, H, W, generator=g) * 5
    gt[:, 2, :, :4] = float("nan")
    lab = torch.full((B, 3, H, W), int(Label.NLOS_STRUCTURE), dtype=torch.uint8)
    lab[:, 1, :2, :3] = int(Label.NLOS_HUMAN)
    m = torch.isfinite(gt)
    per = F.binary_cross_entropy_with_logits(out["human_logit"][m], (lab[m] == int(Label.NLOS_HUMAN)).float(),
                                             pos_weight=torch.tensor(10.0), reduction="none")
    _, parts = multi_return_loss(out, gt, lab, LossWeights())
    assert parts["human"] == pytest.approx(float(per.mean()), rel=1e-6)
    _, parts = multi_return_loss(out, gt, lab, LossWeights(human_hard=0.25))
    k = round(0.25 * per.numel())
    assert parts["human"] == pytest.approx(float(per.sort(descending=True).values[:k].mean()), rel=1e-6)
    with pytest.raises(InputError, match="human_hard"):
        TrainConfig(human_hard=0.0)
