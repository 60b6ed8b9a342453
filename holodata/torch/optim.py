"""The optimiser settings stage one (:class:`~holodata.torch.train.TrainConfig`) and stage two
(:class:`~holodata.torch.stage2_train.Stage2Config`) share: AdamW with a cosine decay of the learning
rate over a phase's epochs, and the key order their config files and checkpoints are written in."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch


@dataclass
class OptimiserSettings:
    """AdamW with a cosine learning-rate decay: ``lr`` the peak learning rate, ``lr_floor`` the share of
    it the decay ends at (``lr · lr_floor``), ``weight_decay`` AdamW's. The base of both stages'
    settings, whose config files and checkpoints keep these as top-level fields."""

    lr: float = 2e-3
    lr_floor: float = 0.05
    weight_decay: float = 1e-4

    def optimizer(self, params) -> torch.optim.AdamW:
        """AdamW over ``params`` at ``lr`` (each epoch then sets its own rate: :meth:`lr_at`)."""
        return torch.optim.AdamW(params, lr=self.lr, weight_decay=self.weight_decay)

    def lr_at(self, epoch: int, epochs: int) -> float:
        """The learning rate of epoch ``epoch`` (0-based) of a phase of ``epochs`` epochs: half a cosine
        from ``lr`` down towards ``lr · lr_floor``."""
        return self.lr * (self.lr_floor + (1 - self.lr_floor) * 0.5 * (1 + math.cos(math.pi * epoch / epochs)))


def set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    """Every parameter group of ``opt`` at learning rate ``lr``."""
    for g in opt.param_groups:
        g["lr"] = lr


def settings_dict(cfg, leading: tuple[str, ...]) -> dict:
    """``asdict(cfg)`` with the fields ``leading`` first, then the rest in field order: the optimiser
    fields (inherited, so first among the fields) after the ones that led each stage's settings before
    they were shared, so that config.json and checkpoints keep their key order."""
    d = asdict(cfg)
    return {**{k: d[k] for k in leading}, **d}
