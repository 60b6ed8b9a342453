"""Stage one's per-bin likelihood (issue 42 point 2): two-hot sub-bin targets, the cross-entropy over
range bins, the mode that reads it out, and training with it."""
import pytest

torch = pytest.importorskip("torch")

from _torch_synth import synth_frames  # noqa: E402

from holodata.errors import InputError  # noqa: E402
from holodata.torch import ArrayFrames, ModelConfig, MultiReturnUNet, RunOptions, TrainConfig, fit  # noqa: E402
from holodata.torch.losses import LossWeights, multi_return_loss, range_bin_nll, two_hot  # noqa: E402
from holodata.torch.train import load_checkpoint, model_from_checkpoint  # noqa: E402


def test_two_hot_mean_is_the_range_exactly():
    n, max_range = 32, 9.6
    dr = max_range / n
    r = torch.tensor([0.0, dr / 2, 1.234, 5.0, max_range - dr / 2, 9.59])
    lo, f = two_hot(r, n, max_range)
    assert ((f >= 0) & (f <= 1)).all() and (lo >= 0).all() and (lo <= n - 2).all()
    mean = ((lo + 0.5) * (1 - f) + (lo + 1.5) * f) * dr
    inside = (r >= dr / 2) & (r <= max_range - dr / 2)   # between the first and the last bin centre
    torch.testing.assert_close(mean[inside], r[inside])


def test_nll_is_least_for_the_two_hot_distribution_and_mode_recovers_the_range():
    n, max_range = 64, 9.6
    gt = torch.tensor([1.234, 3.333, 7.07, float("nan")]).view(1, 1, 4, 1)
    lo, f = two_hot(torch.nan_to_num(gt, nan=1.0), n, max_range)
    p = torch.full((1, 1, n, 4, 1), 1e-9)
    p.scatter_(2, lo.unsqueeze(2), (1 - f).unsqueeze(2) + 1e-9)
    p.scatter_(2, (lo + 1).unsqueeze(2), f.unsqueeze(2) + 1e-9)
    exact = torch.log(p)
    best = float(range_bin_nll(exact, gt, max_range))
    for shift in (1, 3):   # the same shape one and three bins off costs more
        assert float(range_bin_nll(torch.roll(exact, shift, dims=2), gt, max_range)) > best + 0.5
    blurred = torch.log(torch.softmax(exact, 2) * 0.5 + 0.5 / n)
    assert float(range_bin_nll(blurred, gt, max_range)) > best
    assert float(range_bin_nll(exact, torch.full_like(gt, float("nan")), max_range)) == 0.0
    # a perfect distribution read by its mode is the range itself (a perfect prediction scores perfectly)
    m = MultiReturnUNet(ModelConfig(in_channels=n, depth=1, base_channels=4, max_channels=4, blocks=1,
                                    max_range=max_range, estimator="mode"))
    logits = exact.expand(1, 3, n, 4, 1)
    m.forward = lambda x: {"range": (torch.softmax(logits, 2) * m.centres).sum(2), "bin_logits": logits,
                           "valid_logit": torch.ones(1, 3, 4, 1), "human_logit": torch.zeros(1, 3, 4, 1)}
    out = m.predict(torch.zeros(1, n, 4, 1))["range"][0, 0, :3, 0]
    torch.testing.assert_close(out, gt[0, 0, :3, 0], atol=1e-5, rtol=0)


def test_two_peaks_l1_sits_between_them_ce_on_the_likelier():
    """Beams whose GT is 2 m in 60 % of the samples and 5 m in 40 %: the mean-L1 optimum is a range
    between (the median, 2 m, or anywhere between for the mean's slack), the likelihood puts its
    mode on 2 m. One free logit vector, fitted by gradient descent on each loss."""
    n, max_range = 64, 9.6
    gt = torch.tensor([2.0] * 6 + [5.0] * 4).view(1, 1, 10, 1)
    centres = ((torch.arange(n) + 0.5) * max_range / n).view(1, 1, n, 1, 1)
    fits = {}
    for loss in ("l1", "ce"):
        z = torch.zeros(1, 1, n, 1, 1, requires_grad=True)
        opt = torch.optim.Adam([z], lr=0.1)
        for _ in range(400):
            lg = z.expand(1, 1, n, 10, 1)
            rng = (torch.softmax(lg, 2) * centres).sum(2)
            out = {"range": rng, "bin_logits": lg, "valid_logit": torch.zeros_like(rng), "human_logit": torch.zeros_like(rng)}
            total, _ = multi_return_loss(out, gt, None, LossWeights(gradient=0, valid=0, human=0, range_loss=loss),
                                         max_range=max_range)
            opt.zero_grad()
            total.backward()
            opt.step()
        p = torch.softmax(z.detach().view(-1), 0)
        fits[loss] = (float((p * centres.view(-1)).sum()), float(centres.view(-1)[p.argmax()]))
    assert abs(fits["ce"][1] - 2.0) < 0.1                  # the mode is on the likelier peak
    assert 2.3 < fits["ce"][0] < 4.7                        # its mean would sit between the peaks


def test_config_checks_loss_and_estimator():
    assert TrainConfig(range_loss="ce").point_estimator() == "mode"
    assert TrainConfig().point_estimator() == "mean"
    assert TrainConfig().loss_weights().gradient == 0.5 and TrainConfig(range_loss="ce").loss_weights().gradient == 0.0
    assert TrainConfig(range_loss="ce", w_gradient=0.3).loss_weights().gradient == 0.3
    with pytest.raises(InputError, match="range_loss"):
        TrainConfig(range_loss="l2")
    with pytest.raises(InputError, match="estimator"):
        TrainConfig(estimator="max")
    with pytest.raises(InputError, match="softargmax"):
        TrainConfig(range_loss="ce", head="regress")


def test_training_with_ce_records_the_mode_and_lowers_the_loss(tmp_path):
    torch.set_num_threads(2)
    hm, R, L = synth_frames(T=4, n=32, dr=0.3)
    ds = ArrayFrames(hm, R, L)
    cfg = TrainConfig(epochs=15, lr=3e-3, depth=3, base_channels=8, max_channels=16, blocks=1, batch_size=2,
                      range_loss="ce")
    res = fit(ds, tmp_path / "run", cfg, ds.norm, in_channels=hm.shape[1], max_range=9.6,
              options=RunOptions(quiet=True))
    assert "nll" in res.history[0] and res.history[-1]["nll"] < 0.85 * res.history[0]["nll"]
    ck = load_checkpoint(tmp_path / "run")
    assert ck["model_config"]["estimator"] == "mode"
    assert model_from_checkpoint(ck).cfg.estimator == "mode"
