"""Stage two fine-tunes from a given stage2.pt (``init`` of holodata.torch.stage2_train.fit_stage2 /
train_stage2): after 0 epochs the run's weights are the checkpoint's, a refiner-only epoch keeps its
ray tracer and recalibrates the operating points, and a configuration of other model shapes is one
InputError line (before any frame is read); the quick demo's settings fit the shipped weights."""
import copy
import json

import pytest

torch = pytest.importorskip("torch")

import _eval_dataset as E  # noqa: E402

from holodata.errors import InputError  # noqa: E402
from holodata.torch.stage2_infer import KEEP_CANDIDATES, STAGE2_CHECKPOINT, load_stage2  # noqa: E402
from holodata.torch.stage2_train import Stage2Config, check_init, fit_stage2, load_frames, train_stage2  # noqa: E402
from holodata.torch.train import RunOptions  # noqa: E402

TINY2 = dict(channels=8, res_blocks=1, fusion_blocks=1, refine_channels=[8, 8], batch_size=2, p_stage1=0.0, lr=3e-3,
             p_clean=1.0, flip=False)


def _same(a: dict, b: dict) -> bool:
    return set(a) == set(b) and all(torch.equal(a[k], b[k]) for k in a)


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A tiny dataset, its train frames, and a stage-two run trained on them (seed 1: not the weights a
    fresh run of seed 0 starts with)."""
    url = E.build(str(tmp_path_factory.mktemp("ds") / "tiny.zarr"), frames=2)
    frames, grid = load_frames(url, "train", 1)
    run = tmp_path_factory.mktemp("src")
    fit_stage2(frames, run, Stage2Config(epochs_rt=1, epochs_refine=1, seed=1, **TINY2), 9.6, grid, RunOptions(quiet=True))
    return url, frames, grid, run, torch.load(run / STAGE2_CHECKPOINT, weights_only=False)


def test_zero_epochs_keep_the_init_weights(source, tmp_path):
    _, frames, grid, run, init = source
    res = fit_stage2(frames, tmp_path / "ft", Stage2Config(epochs_rt=0, epochs_refine=0, **TINY2), 9.6, grid,
                     RunOptions(quiet=True, init=init, meta={"init": str(run / STAGE2_CHECKPOINT)}))
    ck = torch.load(res["checkpoint"], weights_only=False)
    assert ck["epoch"] == 0 and ck["meta"]["init"].endswith(STAGE2_CHECKPOINT)
    assert _same(ck["rt_state"], init["rt_state"]) and _same(ck["refiner_state"], init["refiner_state"])
    s2, _ = load_stage2(tmp_path / "ft")
    assert _same(s2.rt.state_dict(), init["rt_state"])
    # the same configuration from scratch starts elsewhere (the equality above is the init's doing)
    fresh = fit_stage2(frames, tmp_path / "fresh", Stage2Config(epochs_rt=1, epochs_refine=0, lr=0.0,
                                                                **{k: v for k, v in TINY2.items() if k != "lr"}),
                       9.6, grid, RunOptions(quiet=True))
    assert not _same(torch.load(fresh["checkpoint"], weights_only=False)["rt_state"], init["rt_state"])


def test_refiner_epoch_keeps_the_ray_tracer_and_recalibrates(source, tmp_path):
    _, frames, grid, _, init = source
    init = copy.deepcopy(init)
    init["keep"], init["human"] = {"threshold": 0.123, "scores": {}}, {"threshold": 0.321, "scores": {}}
    res = fit_stage2(frames, tmp_path / "ft", Stage2Config(epochs_rt=0, epochs_refine=1, **TINY2), 9.6, grid,
                     RunOptions(quiet=True, init=init))
    ck = torch.load(res["checkpoint"], weights_only=False)
    assert res["resumed_from"] == 0 and [r["phase"] for r in res["history"]] == ["refine"]
    assert _same(ck["rt_state"], init["rt_state"])               # frozen in the refiner phase
    assert not _same(ck["refiner_state"], init["refiner_state"])  # trained on from the init's
    assert ck["keep"]["threshold"] in KEEP_CANDIDATES and ck["human"]["threshold"] != 0.321   # calibrated anew
    s2, _ = load_stage2(tmp_path / "ft")
    assert s2.refiner is not None and s2.keep_threshold == ck["keep"]["threshold"]
    # rerun: resumes from its own checkpoint (the init is not loaded again)
    again = fit_stage2(frames, tmp_path / "ft", Stage2Config(epochs_rt=0, epochs_refine=1, **TINY2), 9.6, grid,
                       RunOptions(quiet=True, init=None))
    assert again["resumed_from"] == 1 and _same(torch.load(again["checkpoint"], weights_only=False)["refiner_state"],
                                                ck["refiner_state"])


def test_other_model_shapes_are_one_line(source, tmp_path):
    url, frames, grid, run, init = source
    with pytest.raises(InputError) as err:
        fit_stage2(frames, tmp_path / "ft", Stage2Config(epochs_rt=0, epochs_refine=1, **{**TINY2, "channels": 16}),
                   9.6, grid, RunOptions(quiet=True, init=init, meta={"init": "src/stage2.pt"}))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("src/stage2.pt") and "channels 8 (requested 16)" in msg
    with pytest.raises(InputError, match="refiner channels"):
        fit_stage2(frames, tmp_path / "ft", Stage2Config(epochs_rt=0, epochs_refine=1,
                                                         **{**TINY2, "refine_channels": [8, 8, 8]}),
                   9.6, grid, RunOptions(quiet=True, init=init))
    # train_stage2 refuses before it reads a frame or writes its run directory
    from holodata.torch import TrainConfig, train

    s1 = tmp_path / "s1"
    train(url, s1, TrainConfig(epochs=1, depth=2, base_channels=4, max_channels=4, blocks=1), quiet=True)
    out = tmp_path / "s2"
    with pytest.raises(InputError) as err:
        train_stage2(url, out, Stage2Config(epochs_rt=0, epochs_refine=1, **{**TINY2, "res_blocks": 2}), stage1=s1,
                     quiet=True, init=run)
    assert "\n" not in str(err.value) and "res_blocks 1 (requested 2)" in str(err.value) and not out.exists()
    with pytest.raises(InputError, match="no such stage-two checkpoint"):
        train_stage2(url, out, Stage2Config(**TINY2), stage1=s1, quiet=True, init=tmp_path / "nowhere")
    # and with matching shapes it fine-tunes, recording where from
    res = train_stage2(url, out, Stage2Config(epochs_rt=0, epochs_refine=1, **TINY2), stage1=s1, quiet=True, init=run)
    ck = torch.load(res["checkpoint"], weights_only=False)
    assert ck["meta"]["init"] == str(run / STAGE2_CHECKPOINT) and _same(ck["rt_state"], init["rt_state"])
    assert json.loads((out / "stage2_config.json").read_text())["epochs_refine"] == 1


def test_quick_demo_settings_fit_the_shipped_weights():
    """demo --quick fine-tunes both stages from holodata's shipped weights: its stage-one model and
    stage-two shapes are theirs (else the demo would stop at its train stage)."""
    from holodata.demo import demo_config
    from holodata.torch.model import ModelConfig
    from holodata.torch.pretrained import resolve
    from holodata.torch.train import TrainConfig

    cfg = demo_config(True)
    weights = resolve(cfg.init)
    ck1 = torch.load(weights / "checkpoint.pt", weights_only=False)
    tc = TrainConfig(epochs=cfg.epochs, depth=cfg.depth, batch_size=cfg.batch_size, base_channels=cfg.base_channels,
                     max_channels=cfg.max_channels, range_pool=cfg.range_pool, range_loss=cfg.range_loss, lr=cfg.lr)
    mc = ModelConfig(in_channels=cfg.range_bins.n // cfg.range_pool, depth=tc.depth, base_channels=tc.base_channels,
                     max_channels=tc.max_channels, blocks=tc.blocks, max_range=float(cfg.range_bins.max_range),
                     head=tc.head, input_skip=tc.input_skip, estimator=tc.point_estimator())
    assert mc.to_dict() == ck1["model_config"]
    ck2 = torch.load(weights / STAGE2_CHECKPOINT, weights_only=False)
    s2 = Stage2Config.from_dict(cfg.stage2)
    mr = float(cfg.range_bins.max_range)
    check_init(ck2, s2.rt_config(mr), s2.refiner_config(mr), weights)
    assert s2.epochs_refine >= 1   # a refiner epoch: the fine-tuned run's refiner is used at inference
    with pytest.raises(InputError, match="channels 16 \\(requested 32\\)"):
        check_init(ck2, Stage2Config(channels=32).rt_config(mr), s2.refiner_config(mr), weights)
    assert demo_config(True, from_scratch=True).init is None and demo_config(False).init is None
