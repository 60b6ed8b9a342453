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
