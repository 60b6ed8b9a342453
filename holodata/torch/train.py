"""Training loop: config dataclass (file + flags), seeds, atomic checkpoints, resume after
interruption, progress bar, CPU by default / CUDA on request, per-epoch metrics log (JSON lines).

Run directory layout: ``checkpoint.pt`` (latest epoch; everything needed to resume or evaluate),
``config.json`` (the effective TrainConfig), ``metrics.jsonl`` (one JSON object per epoch).
"""
from __future__ import annotations

import json
import os
import random
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from holodata.conventions import DEFAULT_MAX_RANGE_M
from holodata.errors import InputError
from holodata.ownership import claim_folder
from holodata.progress import track

from . import ddp
from .checkpoint import CHECKPOINT, load_checkpoint
from .data import HeatmapNorm, SampleTransform
from .losses import LossWeights, multi_return_loss
from .model import ModelConfig, MultiReturnUNet
from .optim import OptimiserSettings, set_lr, settings_dict

METRICS_LOG = "metrics.jsonl"


def check_fields(cls, data: dict, source: str, what: str) -> None:
    """InputError naming ``source`` when ``data`` has keys that are not fields of dataclass ``cls``."""
    unknown = sorted(set(data) - {f.name for f in fields(cls)})
    if unknown:
        raise InputError(f"{source}: unknown {what} option(s): {', '.join(unknown)}")


@dataclass
class TrainConfig(OptimiserSettings):
    """Training settings. Model: depth (UNet levels; paper 7), base_channels, max_channels, blocks.
    Data: downsample (H,W stride), range_pool (range-bin max-pool), crop_w (random azimuth
    window), frames_per_scene (cap). Optimiser (:class:`~holodata.torch.optim.OptimiserSettings`):
    AdamW lr / weight_decay, cosine decay to lr·lr_floor over ``epochs``. Loss weights: w_range,
    w_gradient, w_valid, w_human (and human_pos_weight, the weight of human pixels in that term, and
    human_hard, the share of hardest pixels it averages; :func:`multi_return_loss`).
    range_loss: "l1" (L1 on the soft-argmax mean) or "ce" (per-bin cross-entropy against two-hot
    sub-bin targets, :func:`holodata.torch.losses.range_bin_nll`); estimator: the point estimate the
    model predicts with (None: "mode" for "ce", "mean" for "l1"), recorded in the checkpoint."""

    epochs: int = 20
    batch_size: int = 4
    seed: int = 0
    device: str = "cpu"
    num_workers: int = 0
    depth: int = 7
    base_channels: int = 16
    max_channels: int = 128
    blocks: int = 2
    head: str = "softargmax"
    input_skip: bool = True
    augment_roll: bool = True
    downsample: int = 1
    range_pool: int = 1
    crop_w: int | None = None
    frames_per_scene: int | None = None
    w_range: float = 1.0
    w_gradient: float | None = None   # None: 0.5 with range_loss "l1", 0 with "ce" (what each was measured with)
    w_valid: float = 0.2
    w_human: float = 0.2
    human_pos_weight: float = 10.0
    human_hard: float = 1.0
    range_loss: str = "l1"
    estimator: str | None = None

    def __post_init__(self) -> None:
        from .losses import RANGE_LOSSES
        from .model import ESTIMATORS

        if not 0 < self.human_hard <= 1:
            raise InputError(f"human_hard is the share of pixels the human term keeps, in (0, 1]; got {self.human_hard}")
        if self.range_loss not in RANGE_LOSSES:
            raise InputError(f"range_loss must be one of {', '.join(RANGE_LOSSES)}, got {self.range_loss!r}")
        if self.estimator is not None and self.estimator not in ESTIMATORS:
            raise InputError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}")
        if self.range_loss == "ce" and self.head != "softargmax":
            raise InputError("range_loss 'ce' needs head 'softargmax' (a distribution over range bins)")

    @classmethod
    def from_file(cls, path, **overrides) -> TrainConfig:
        """Read a YAML or JSON mapping of TrainConfig fields, or the ``train`` section of a stage-settings
        file (:mod:`holodata.config_file`, e.g. ``examples/holodata.yaml``); ``overrides`` (non-None) win."""
        import yaml

        p = Path(path)
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except (OSError, yaml.YAMLError) as err:
            raise InputError(f"{p}: cannot read training config ({' '.join(str(err).split())})") from err
        if not isinstance(data, dict):
            raise InputError(f"{p}: training config must be a mapping of field: value")
        from ..config_file import SECTIONS, read

        if data and set(data) <= set(SECTIONS) and not set(data) & {f.name for f in fields(cls)}:
            data = read(p).get("train", {})        # a stage-settings file: its train section
        return cls.from_dict({**data, **{k: v for k, v in overrides.items() if v is not None}}, source=str(p))

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> TrainConfig:
        check_fields(cls, data, source, "training")
        return cls(**data)

    def to_dict(self) -> dict:
        return settings_dict(self, ("epochs", "batch_size"))

    def loss_weights(self) -> LossWeights:
        grad = self.w_gradient if self.w_gradient is not None else (0.0 if self.range_loss == "ce" else 0.5)
        return LossWeights(self.w_range, grad, self.w_valid, self.w_human, self.human_pos_weight, self.range_loss,
                           self.human_hard)

    def point_estimator(self) -> str:
        """The estimator the model predicts with (:attr:`estimator`, else the one ``range_loss`` suits)."""
        return self.estimator or ("mode" if self.range_loss == "ce" else "mean")

    def sample_transform(self, train: bool = True) -> SampleTransform:
        return SampleTransform(self.downsample, self.range_pool, self.crop_w, random_crop=train,
                                roll=train and self.augment_roll)


@dataclass
class RunResult:
    """Outcome of :func:`train` / :func:`fit`: run directory, checkpoint path, epochs completed
    in total, the epoch this call resumed from (0 = fresh), per-epoch history (dicts)."""

    out_dir: Path
    checkpoint: Path
    epochs: int
    resumed_from: int
    history: list = field(default_factory=list)

    @property
    def final_loss(self) -> float:
        return float(self.history[-1]["loss"]) if self.history else float("nan")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def resolve_device(device: str) -> torch.device:
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("--device cuda requested but torch sees no CUDA device (this torch build: "
                         f"{torch.__version__})")
    return torch.device(device)


def _collate(batch: list[dict]) -> dict:
    """Stack a batch's tensors (torch's default_collate: in a DataLoader worker it stacks straight
    into shared memory, one copy instead of two); scene ids and frame numbers stay lists."""
    from torch.utils.data import default_collate

    return {**{k: default_collate([b[k] for b in batch]) for k in ("heatmap", "range", "label")},
            "scene": [b["scene"] for b in batch], "frame": [b["frame"] for b in batch]}


def _atomic_save(obj, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def check_stage1(ck: dict, ds, where) -> None:
    """InputError unless the stage-one checkpoint's grid and range bins are the dataset's."""
    meta = ck.get("meta") or {}
    if meta.get("grid") != ds.grid.to_attrs() or meta.get("range_bins") != ds.range_bins.to_attrs():
        name = "the pretrained weights holodata ships" if ck.get("pretrained") else where   # (install's record)
        raise InputError(f"{name} were trained on {_grid_text(meta.get('grid'), meta.get('range_bins'))}, the dataset "
                         f"has {_grid_text(ds.grid.to_attrs(), ds.range_bins.to_attrs())}: train a model on this "
                         f"grid (holodata train) or use a dataset of that grid")


def _grid_text(grid: dict | None, bins: dict | None) -> str:
    """``32x128 beams (+45..-45 deg), 256 range bins of 3.75 cm`` from grid / range-bin attributes."""
    try:
        g = f"{grid['H']}x{grid['W']} beams ({grid['elev_deg'][0]:+g}..{grid['elev_deg'][1]:+g} deg)"
    except (TypeError, KeyError, IndexError):
        g = "an unrecorded beam grid"
    try:
        b = f"{bins['n']} range bins of {bins['dr'] * 100:g} cm"
    except (TypeError, KeyError):
        b = "unrecorded range bins"
    return f"{g}, {b}"


def model_from_checkpoint(ck: dict, device: str = "cpu") -> MultiReturnUNet:
    model = MultiReturnUNet(ModelConfig(**ck["model_config"]))
    model.load_state_dict(ck["model_state"])
    return model.to(device).eval()


@dataclass
class RunOptions:
    """How a training call runs, beside its settings (:func:`fit`, :func:`~holodata.torch.stage2_train.fit_stage2`):
    ``quiet`` (no progress bars), ``resume`` (continue from the run directory's checkpoint when there is
    one), ``init`` (a checkpoint, as a dict, whose weights a fresh run starts from: fine-tuning) and
    ``meta`` (recorded in the checkpoint; ``meta["init"]`` names ``init`` in errors)."""

    quiet: bool = False
    resume: bool = True
    init: dict | None = None
    meta: dict | None = None


def fit(train_set, out_dir, config: TrainConfig, norm: HeatmapNorm, in_channels: int,
        max_range: float = DEFAULT_MAX_RANGE_M, options: RunOptions | None = None) -> RunResult:
    """Train on a torch Dataset of sample dicts (see holodata.torch.data) into ``out_dir``.

    Resumes from ``out_dir/checkpoint.pt`` when present and ``options.resume`` (same model config
    required): epochs continue from the last completed one up to ``config.epochs``. Each epoch shuffles
    with a generator seeded by (seed, epoch) and augments each sample with draws keyed by (seed, epoch,
    sample), so a resumed run sees the same batches as an uninterrupted one. ``options.init``: a
    checkpoint (dict) whose weights a fresh run starts from (fine-tuning; its model config must be this
    one's). Under ``torchrun`` the global batch is split over the processes (:mod:`holodata.torch.ddp`);
    rank 0 writes.
    """
    opts = options or RunOptions()
    out = Path(out_dir)
    ctx, dev_name = ddp.setup(config.device, config.batch_size)
    if ctx.main:   # a new or empty folder, or a run holodata wrote (holodata.ownership)
        claim_folder(out, "holodata train")
    device = resolve_device(dev_name)
    run = _Stage1Run.start(config, _model_config(config, in_channels, max_range), device, ctx, opts.quiet)
    ck_path = out / CHECKPOINT
    start, history, norm = _resume_or_init(run, ck_path, norm, opts)
    run.model = ddp.wrap(run.net, ctx, dev_name)
    if ctx.main:
        (out / "config.json").write_text(json.dumps(config.to_dict(), indent=2) + "\n")
        _truncate_log(out / METRICS_LOG, start)
    if start >= config.epochs:
        return RunResult(out, ck_path, start, start, history)
    for epoch in range(start, config.epochs):
        history.append(run.epoch(train_set, epoch))
        if ctx.main:
            run.save(out, history, norm, opts.meta)
        ddp.barrier(ctx)
    return RunResult(out, ck_path, config.epochs, start, history)


def _model_config(config: TrainConfig, in_channels: int, max_range: float) -> ModelConfig:
    """The model :func:`fit` trains: ``config``'s architecture on ``in_channels`` range bins reaching ``max_range`` m."""
    return ModelConfig(in_channels=in_channels, depth=config.depth, base_channels=config.base_channels,
                       max_channels=config.max_channels, blocks=config.blocks, max_range=float(max_range),
                       head=config.head, input_skip=config.input_skip, estimator=config.point_estimator())


def _resume_or_init(run: _Stage1Run, ck_path: Path, norm: HeatmapNorm,
                    opts: RunOptions) -> tuple[int, list, HeatmapNorm]:
    """Load the run's own checkpoint (resume: weights, optimiser, history, normalisation, torch RNG) or,
    on a fresh run, ``opts.init``'s weights; (epochs done, history, heatmap normalisation)."""
    mcfg = run.mcfg
    if opts.resume and ck_path.exists():
        ck = load_checkpoint(ck_path)
        if ck["model_config"] != mcfg.to_dict():
            raise InputError(f"{ck_path}: checkpoint model config {ck['model_config']} differs from the "
                             f"requested {mcfg.to_dict()}; use a new --out directory")
        run.net.load_state_dict(ck["model_state"])
        run.opt.load_state_dict(ck["optimizer_state"])
        torch.set_rng_state(ck["torch_rng"])
        return int(ck["epoch"]), list(ck["history"]), HeatmapNorm.from_dict(ck["norm"])
    init = opts.init
    if init is not None:
        if init["model_config"] != mcfg.to_dict():
            raise InputError(f"{(opts.meta or {}).get('init', 'init checkpoint')}: its model config "
                             f"{init['model_config']} differs from the requested {mcfg.to_dict()}")
        run.net.load_state_dict(init["model_state"])
    return 0, [], norm


@dataclass
class _Stage1Run:
    """What every epoch of :func:`fit` works with: settings, model config, the model (``net``; ``model``
    its DDP wrapper, ``net`` itself until :func:`fit` wraps it), optimiser, process context, device,
    loss weights."""

    config: TrainConfig
    mcfg: ModelConfig
    net: MultiReturnUNet
    model: torch.nn.Module
    opt: torch.optim.Optimizer
    ctx: ddp.Ddp
    device: torch.device
    weights: LossWeights
    quiet: bool

    @classmethod
    def start(cls, config: TrainConfig, mcfg: ModelConfig, device: torch.device, ctx: ddp.Ddp,
              quiet: bool) -> _Stage1Run:
        """Seeded, then the model and its optimiser (in that order: the model's initial weights are
        the first draws after the seed)."""
        seed_everything(config.seed)
        net = MultiReturnUNet(mcfg).to(device)
        return cls(config, mcfg, net, net, config.optimizer(net.parameters()), ctx, device, config.loss_weights(),
                   quiet)

    def epoch(self, train_set, epoch: int) -> dict:
        """Train one epoch (0-based ``epoch``); its metrics row, summed over the processes."""
        config, ctx = self.config, self.ctx
        lr = config.lr_at(epoch, config.epochs)
        set_lr(self.opt, lr)
        loader = self._loader(train_set, epoch)
        self.model.train()
        sums: dict = {}
        n_seen, t0 = 0, time.perf_counter()
        for batch in track(loader, total=len(loader), description=f"epoch {epoch + 1}/{config.epochs}",
                           quiet=self.quiet or not ctx.main):
            bs, loss, parts = self._step(batch)
            n_seen += bs
            sums["loss"] = sums.get("loss", 0.0) + loss * bs
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v * bs
        sums = ddp.sum_over_ranks({**sums, "_n": n_seen}, ctx)
        n_seen = int(sums.pop("_n"))
        dt = time.perf_counter() - t0
        return {"epoch": epoch + 1, **{k: v / max(n_seen, 1) for k, v in sums.items()}, "lr": lr,
                "samples": n_seen, "seconds": round(dt, 3), "samples_per_s": n_seen / dt if dt > 0 else None}

    def _loader(self, train_set, epoch: int) -> DataLoader:
        """This process's batches of epoch ``epoch``: the permutation torch's RandomSampler draws from a
        generator seeded by (seed, epoch), split over the ranks; augmentation keyed the same way."""
        config = self.config
        if hasattr(train_set, "set_epoch"):
            train_set.set_epoch(config.seed, epoch)
        order = torch.randperm(len(train_set), generator=torch.Generator().manual_seed(config.seed * 100003 + epoch))
        return DataLoader(train_set, batch_sampler=ddp.local_batches(order.tolist(), config.batch_size, self.ctx),
                          num_workers=config.num_workers, collate_fn=_collate, persistent_workers=False)

    def _step(self, batch: dict) -> tuple[int, float, dict]:
        """One optimiser step on ``batch``: (batch size, loss, the loss's parts)."""
        dev = self.device
        x = batch["heatmap"].to(dev, non_blocking=True).float()   # float16 from the loader
        y = batch["range"].to(dev, non_blocking=True)
        lab = batch["label"].to(dev, non_blocking=True)
        loss, parts = multi_return_loss(self.model(x), y, lab, self.weights, max_range=self.mcfg.max_range)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.net.parameters(), 5.0)
        self.opt.step()
        return x.shape[0], float(loss.detach()), parts

    def save(self, out: Path, history: list, norm: HeatmapNorm, meta: dict | None) -> None:
        """The checkpoint after the last epoch of ``history`` (atomic) and its metrics line."""
        config = self.config
        _atomic_save({
            "format": "holodata-checkpoint-1", "epoch": history[-1]["epoch"], "model_config": self.mcfg.to_dict(),
            "model_state": self.net.state_dict(), "optimizer_state": self.opt.state_dict(),
            "train_config": config.to_dict(), "norm": norm.to_dict(),
            "transform": config.sample_transform(train=False).to_dict(), "history": history,
            "torch_rng": torch.get_rng_state(), "meta": {**(meta or {}), "processes": self.ctx.world},
        }, out / CHECKPOINT)
        with open(out / METRICS_LOG, "a") as fh:
            fh.write(json.dumps(history[-1]) + "\n")


def _truncate_log(path: Path, epochs_done: int) -> None:
    """Keep only log lines of epochs already in the checkpoint (an interrupted epoch may have
    logged without checkpointing)."""
    if not path.exists():
        return
    keep = []
    for line in path.read_text().splitlines():
        try:
            if json.loads(line)["epoch"] <= epochs_done:
                keep.append(line)
        except (ValueError, KeyError, TypeError):
            pass
    path.write_text("".join(k + "\n" for k in keep))


def train(dataset_url, out_dir, config: TrainConfig | dict | None = None, quiet: bool = False,
          init=None) -> RunResult:
    """Train the multi-return model on the ``train`` split of the dataset at ``dataset_url`` into
    ``out_dir`` (resuming when ``out_dir/checkpoint.pt`` exists). ``init``: a stage-one checkpoint
    (file or run directory; :func:`holodata.torch.pretrained.resolve` names the shipped one) a fresh
    run fine-tunes from, with its heatmap normalisation; it must match the dataset's grid and range
    bins. Returns a :class:`RunResult`."""
    from holodata.dataset import open_dataset

    from .data import HeatmapDataset

    cfg = config if isinstance(config, TrainConfig) else TrainConfig.from_dict(config or {})
    ds = open_dataset(str(dataset_url))
    norm = None
    ck_path = Path(out_dir) / CHECKPOINT
    init_ck, init_path = None, None
    if init is not None:
        init_path = Path(init)
        init_ck = load_checkpoint(init_path)
        check_stage1(init_ck, ds, init_path)
        norm = HeatmapNorm.from_dict(init_ck["norm"])
    if ck_path.exists():
        norm = HeatmapNorm.from_dict(load_checkpoint(ck_path)["norm"])
    train_set = HeatmapDataset(ds if getattr(ds, "url", None) else str(dataset_url), split="train", norm=norm,
                               transform=cfg.sample_transform(train=True), frames_per_scene=cfg.frames_per_scene,
                               dtype=np.float16)
    if train_set.url is None:
        train_set.url = str(dataset_url)
    n_in = int(ds.range_bins.n) // max(cfg.range_pool, 1)
    meta = {"dataset": str(dataset_url), "train_scenes": train_set.scenes, "grid": ds.grid.to_attrs(),
            "range_bins": ds.range_bins.to_attrs(), **({"init": str(init_path)} if init_path else {})}
    return fit(train_set, out_dir, cfg, train_set.norm, in_channels=n_in, max_range=float(ds.range_bins.max_range),
               options=RunOptions(quiet=quiet, init=init_ck, meta=meta))
