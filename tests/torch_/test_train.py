import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from _torch_synth import synth_frames  # noqa: E402

from holodata.errors import InputError  # noqa: E402
from holodata.torch import (  # noqa: E402
    ArrayFrames,
    HeatmapNorm,
    ModelConfig,
    MultiReturnUNet,
    RunOptions,
    SampleTransform,
    TrainConfig,
    fit,
    load_checkpoint,
    masked_gradient_loss,
    masked_l1,
    model_from_checkpoint,
    split_scenes,
)

TINY = dict(depth=3, base_channels=8, max_channels=16, blocks=1, batch_size=4)


@pytest.mark.parametrize("depth,H,W", [(1, 8, 8), (3, 16, 64), (7, 15, 33)])
def test_model_shapes(depth, H, W):
    m = MultiReturnUNet(ModelConfig(in_channels=5, depth=depth, base_channels=4, max_channels=8, blocks=1))
    out = m(torch.randn(2, 5, H, W))
    for k in ("range", "valid_logit", "human_logit"):
        assert out[k].shape == (2, 3, H, W)
    assert (out["range"] >= 0).all() and (out["range"] <= 9.6).all()
    assert len(m.decoders) == 3  # one decoder per bounce
    pred = m.predict(torch.randn(1, 5, H, W), valid_threshold=1.01)
    assert torch.isnan(pred["range"]).all()


def test_predict_estimators_on_known_distribution():
    n = 10
    m = MultiReturnUNet(ModelConfig(in_channels=n, depth=1, base_channels=4, max_channels=4, blocks=1, max_range=10.0))
    # bins of 1 m (centres 0.5..9.5); probability 0.4 in bin 0 and 0.6 in bin 9 on every beam
    p = torch.full((n,), 1e-12)
    p[0], p[-1] = 0.4, 0.6
    logits = torch.log(p).view(1, 1, n, 1, 1).expand(1, 3, n, 2, 2)
    m.forward = lambda x: {"range": (torch.softmax(logits, 2) * m.centres).sum(2), "bin_logits": logits,
                           "valid_logit": torch.ones(1, 3, 2, 2), "human_logit": torch.zeros(1, 3, 2, 2)}
    x = torch.zeros(1, n, 2, 2)
    assert float(m.predict(x, estimator="mean")["range"][0, 0, 0, 0]) == pytest.approx(0.4 * 0.5 + 0.6 * 9.5, abs=1e-4)
    assert float(m.predict(x, estimator="mode")["range"][0, 0, 0, 0]) == pytest.approx(9.5, abs=1e-4)
    # the cdf reaches 0.5 inside the last bin: 9 + (0.5 - 0.4) / 0.6
    assert float(m.predict(x, estimator="median")["range"][0, 0, 0, 0]) == pytest.approx(9 + 0.1 / 0.6, abs=1e-4)
    with pytest.raises(ValueError):
        m.predict(x, estimator="nope")


def test_losses_mask_nan():
    gt = torch.tensor([[1.0, float("nan"), 3.0]])
    pred = torch.tensor([[1.5, 100.0, 2.0]])
    assert float(masked_l1(pred, gt)) == pytest.approx(0.75)
    assert float(masked_l1(pred, torch.full_like(gt, float("nan")))) == 0.0
    g = torch.rand(2, 3, 6, 7) * 5
    assert float(masked_gradient_loss(g, g)) == 0.0
    assert float(masked_gradient_loss(g + 1.0, g)) == pytest.approx(0.0, abs=1e-6)  # offset-invariant
    assert float(masked_gradient_loss(2 * g, g)) > 0.1
    g2 = g.clone()
    g2[..., 3] = float("nan")
    assert torch.isfinite(masked_gradient_loss(2 * g, g2))


def test_heatmap_norm_and_transform():
    hm, R, L = synth_frames(T=2)
    norm = HeatmapNorm.fit(hm)
    x = norm(hm)
    assert x.dtype == np.float32 and x.min() >= -1 and x.max() <= 1 and x.std() > 0.1
    assert HeatmapNorm.from_dict(json.loads(json.dumps(norm.to_dict()))) == norm
    ds = ArrayFrames(hm, R, L, transform=SampleTransform(downsample=2, range_pool=4, crop_w=8))
    s = ds[0]
    assert s["heatmap"].shape == (8, 8, 8) and s["range"].shape == (3, 8, 8)
    np.testing.assert_array_equal(s["range"].numpy(), R[0][:, ::2, ::2][..., :8])


def test_split_by_scene(tmp_path):
    """Splits are the dataset's, set explicitly; a missing or empty split is an error (issue 55)."""
    from holodata.dataset import create_dataset, open_dataset
    from holodata.errors import DatasetError

    url = str(tmp_path / "d.zarr")
    w = create_dataset(url)
    for i in range(3):
        w.scene(f"c{i}", n_frames=1)
    with pytest.raises(DatasetError, match="split 'train' is empty.*holodata split"):
        split_scenes(open_dataset(url), "train")
    w.set_splits(train=["c0", "c1"], test=["c2"])
    ds = open_dataset(url)
    assert split_scenes(ds, "test") == ["c2"] and split_scenes(ds, "train") == ["c0", "c1"]
    assert split_scenes(ds, "all") == ["c0", "c1", "c2"]


def test_config_file_and_flags(tmp_path):
    f = tmp_path / "cfg.yaml"
    f.write_text("epochs: 3\nlr: 0.01\n")
    c = TrainConfig.from_file(f, epochs=5, device=None)
    assert c.epochs == 5 and c.lr == 0.01 and c.device == "cpu"
    f.write_text("epochz: 3\n")
    with pytest.raises(InputError, match="epochz"):
        TrainConfig.from_file(f)


@pytest.mark.slow
def test_overfits_tiny_dataset(tmp_path):
    torch.set_num_threads(2)
    hm, R, L = synth_frames(T=8)
    ds = ArrayFrames(hm, R, L)
    cfg = TrainConfig(epochs=60, lr=3e-3, **TINY)
    res = fit(ds, tmp_path / "run", cfg, ds.norm, in_channels=hm.shape[1], options=RunOptions(quiet=True))
    h = res.history
    assert h[0]["loss"] / h[-1]["loss"] > 10
    assert h[0]["l1"] / h[-1]["l1"] > 10
    log = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in log] == list(range(1, 61))
    # the trained model's range error on its training frames is a few cm, not metres
    model = model_from_checkpoint(load_checkpoint(tmp_path / "run"))
    with torch.no_grad():
        out = model(torch.stack([ds[i]["heatmap"] for i in range(8)]))["range"].numpy()
    m = np.isfinite(R)
    assert np.mean(np.abs(out[m] - R[m])) < 0.1


class Crashing(torch.utils.data.Dataset):
    """Wraps a dataset and raises after ``limit`` items: an interruption in the middle of an epoch."""

    def __init__(self, ds, limit):
        self.ds, self.limit, self.n = ds, limit, 0

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, i):
        self.n += 1
        if self.n > self.limit:
            raise KeyboardInterrupt("simulated interruption")
        return self.ds[i]


def test_resume_continues_from_checkpoint(tmp_path):
    torch.set_num_threads(2)
    hm, R, L = synth_frames(T=6, seed=3)
    ds = ArrayFrames(hm, R, L)
    cfg = TrainConfig(epochs=4, **TINY)
    full = fit(ds, tmp_path / "a", cfg, ds.norm, hm.shape[1], options=RunOptions(quiet=True))
    with pytest.raises(KeyboardInterrupt):  # dies in the middle of epoch 3
        fit(Crashing(ds, limit=2 * len(ds) + 3), tmp_path / "b", cfg, ds.norm, hm.shape[1], options=RunOptions(quiet=True))
    assert load_checkpoint(tmp_path / "b")["epoch"] == 2
    # simulate an epoch that logged but died before its checkpoint
    with open(tmp_path / "b" / "metrics.jsonl", "a") as fh:
        fh.write(json.dumps({"epoch": 3, "loss": 0}) + "\n")
    cont = fit(ds, tmp_path / "b", cfg, ds.norm, hm.shape[1], options=RunOptions(quiet=True))
    assert cont.resumed_from == 2 and [r["epoch"] for r in cont.history] == [1, 2, 3, 4]
    log = [json.loads(x)["epoch"] for x in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert log == [1, 2, 3, 4]
    # the resumed run ends where the uninterrupted one does
    a = load_checkpoint(tmp_path / "a")["model_state"]
    b = load_checkpoint(tmp_path / "b")["model_state"]
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-4, atol=1e-5)
    assert cont.history[-1]["loss"] == pytest.approx(full.history[-1]["loss"], rel=1e-4)
    # finished run: nothing more to do
    again = fit(ds, tmp_path / "b", cfg, ds.norm, hm.shape[1], options=RunOptions(quiet=True))
    assert again.resumed_from == 4
    with pytest.raises(InputError, match="model config"):
        fit(ds, tmp_path / "b", TrainConfig(epochs=5, **{**TINY, "depth": 2}), ds.norm, hm.shape[1],
            options=RunOptions(quiet=True))
