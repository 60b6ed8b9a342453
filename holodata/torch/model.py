"""Multi-return range-image UNet (paper §4.3): range bins as input channels, 2-D convolutions over
(elevation, azimuth), one shared encoder, one decoder per bounce, skip connections.

Each bounce decoder ends in per-beam maps: the range, a "return exists" logit and a
human-vs-structure logit (the per-beam human/structure head). ``head="softargmax"`` (default)
predicts logits over ``range_bins_out`` range bins and returns their soft-argmax (expected bin
centre, metres) — the range stays tied to the radar's bins and edges stay sharp; with
``input_skip`` the bin logits also get a learned multiple of the input heatmap's own bins;
``head="regress"`` regresses ``max_range·sigmoid(x)`` directly.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from holodata.conventions import DEFAULT_MAX_RANGE_M

ESTIMATORS = ("mean", "median", "mode")
# the "mode" estimate's window about the most likely bin: a two-hot target (losses.two_hot) puts its
# mass on two neighbouring bins, which ±1 bin always holds; ±2 tolerates a little spread
MODE_HALF_BINS = 2


@dataclass
class ModelConfig:
    """in_channels: range bins; depth: encoder levels (paper: 7), each after the first halves H and
    W (while both stay ≥ 2); base_channels doubles per level up to max_channels; blocks: residual
    blocks per encoder level (paper: 4; decoders use half, at least 1)."""

    in_channels: int = 256
    bounces: int = 3
    depth: int = 7
    base_channels: int = 32
    max_channels: int = 256
    blocks: int = 2
    max_range: float = DEFAULT_MAX_RANGE_M
    head: str = "softargmax"
    range_bins_out: int = 0  # soft-argmax bins; 0 = in_channels
    input_skip: bool = True  # soft-argmax logits += scale_b · input heatmap (same bins)
    estimator: str = "mean"  # predict()'s default point estimate: the one its training loss suits

    def to_dict(self) -> dict:
        return asdict(self)


def _norm(c: int) -> nn.Module:
    return nn.GroupNorm(min(8, c), c)


class ResBlock(nn.Module):
    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)
        self.n1 = _norm(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1, bias=False)
        self.n2 = _norm(c_out)
        self.skip = nn.Identity() if c_in == c_out else nn.Conv2d(c_in, c_out, 1, bias=False)

    def forward(self, x):
        y = F.silu(self.n1(self.conv1(x)))
        y = self.n2(self.conv2(y))
        return F.silu(y + self.skip(x))


def _stack(c_in: int, c_out: int, n: int) -> nn.Sequential:
    return nn.Sequential(*[ResBlock(c_in if i == 0 else c_out, c_out) for i in range(max(n, 1))])


class Decoder(nn.Module):
    def __init__(self, chans: list[int], blocks: int, n_out: int = 3):
        super().__init__()
        self.ups = nn.ModuleList()
        for i in range(len(chans) - 1, 0, -1):
            self.ups.append(_stack(chans[i] + chans[i - 1], chans[i - 1], blocks))
        self.head = nn.Conv2d(chans[0], n_out, 1)

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        x = feats[-1]
        for k, block in enumerate(self.ups):
            skip = feats[-2 - k]
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], 1))
        return self.head(x)


class MultiReturnUNet(nn.Module):
    """(B, N_r, H, W) normalised heatmap → dict range (B,3,H,W) metres, valid_logit (B,3,H,W),
    human_logit (B,3,H,W)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        chans = [min(cfg.base_channels * 2**i, cfg.max_channels) for i in range(cfg.depth)]
        self.chans = chans
        self.stem = nn.Sequential(nn.Conv2d(cfg.in_channels, chans[0], 3, padding=1), _norm(chans[0]), nn.SiLU())
        self.enc = nn.ModuleList(
            [_stack(chans[0], chans[0], cfg.blocks)]
            + [_stack(chans[i - 1], chans[i], cfg.blocks) for i in range(1, cfg.depth)]
        )
        if cfg.head not in ("softargmax", "regress"):
            raise ValueError(f"model head must be 'softargmax' or 'regress', got {cfg.head!r}")
        self.n_bins = (cfg.range_bins_out or cfg.in_channels) if cfg.head == "softargmax" else 1
        n_out = self.n_bins + 2
        self.decoders = nn.ModuleList([Decoder(chans, max(cfg.blocks // 2, 1), n_out) for _ in range(cfg.bounces)])
        for dec in self.decoders:  # start from a uniform / mid-range guess
            nn.init.zeros_(dec.head.weight)
            nn.init.zeros_(dec.head.bias)
        centres = (torch.arange(self.n_bins, dtype=torch.float32) + 0.5) * (cfg.max_range / self.n_bins)
        self.register_buffer("centres", centres.view(1, 1, -1, 1, 1), persistent=False)
        # range-bin skip: each bounce's bin logits start from the input's own range profile, so the
        # decoder learns corrections to "where the energy is" rather than re-deriving it
        self.use_skip = cfg.head == "softargmax" and cfg.input_skip and self.n_bins == cfg.in_channels
        self.skip_scale = nn.Parameter(torch.full((1, cfg.bounces, 1, 1, 1), 4.0)) if self.use_skip else None

    def forward(self, x: torch.Tensor) -> dict:
        feats = []
        h = self.stem(x)
        for i, block in enumerate(self.enc):
            if i > 0 and min(h.shape[-2:]) >= 2:
                h = F.avg_pool2d(h, 2, ceil_mode=True)
            h = block(h)
            feats.append(h)
        outs = torch.stack([dec(feats) for dec in self.decoders], 1)  # (B, bounces, n_bins + 2, H, W)
        if self.cfg.head == "softargmax":
            logits = outs[:, :, : self.n_bins]
            if self.use_skip:
                logits = logits + self.skip_scale * x.unsqueeze(1)
            rng = (torch.softmax(logits, dim=2) * self.centres).sum(2)
            return {"range": rng, "valid_logit": outs[:, :, -2], "human_logit": outs[:, :, -1], "bin_logits": logits}
        rng = self.cfg.max_range * torch.sigmoid(outs[:, :, 0])
        return {"range": rng, "valid_logit": outs[:, :, -2], "human_logit": outs[:, :, -1]}

    def ring_forward(self, x: torch.Tensor, window: int | None = None) -> dict:
        """:meth:`forward` on whole azimuth rings (B, N_r, H, W) by a model trained on ``window``-column
        azimuth crops: the ring is cut into windows of that width every ``window // 2`` columns,
        wrapping around (the ring has no edge), all run as one batch, and each output column is
        taken from the window it sits in the middle half of. So every column is predicted with
        at least ``window // 4`` real columns either side, as in training, and the convolutions'
        padding and the per-window group-norm statistics are those of the crops the model learnt
        on. ``window`` None, or one that does not tile the ring: the plain forward."""
        W = x.shape[-1]
        if not window or window >= W or W % (window // 2) or window % 4:
            return self.forward(x)
        step, q = window // 2, window // 4
        starts = torch.arange(0, W, step, device=x.device) - q                   # (n,) window starts
        cols = (starts[:, None] + torch.arange(window, device=x.device)) % W     # (n, window)
        B, n = x.shape[0], len(starts)
        xs = x[..., cols].permute(0, 3, 1, 2, 4).reshape(B * n, *x.shape[1:3], window)
        out = self.forward(xs)
        res = {}
        for k, v in out.items():   # keep columns q .. q+step of each window: they tile the ring in order
            v = v[..., q:q + step].reshape(B, n, *v.shape[1:-1], step)
            res[k] = torch.movedim(v, 1, -2).reshape(B, *v.shape[2:-1], n * step)
        return res

    @torch.no_grad()
    def predict(self, x: torch.Tensor, valid_threshold: float = 0.5, estimator: str | None = None,
                window: int | None = None) -> dict:
        """Inference: range with NaN where P(return) < threshold; human probability.

        With the soft-argmax head, ``estimator`` picks the point estimate of each beam's range-bin
        distribution (None: ``cfg.estimator``, the one the model was trained for): "mean" (the
        soft-argmax L1 training uses), "median" (minimises the
        expected absolute error) or "mode" (soft-argmax within ±``MODE_HALF_BINS`` bins of the most likely bin:
        sharpest where the model is confident, but a wrong peak where it is not).

        ``confidence`` (B,3,H,W), with the soft-argmax head: :func:`mode_confidence` (what stage two's
        gate reads, :func:`holodata.torch.stage2_infer.apply_gate`). ``window``: the azimuth crop
        width the model was trained on (:meth:`ring_forward`)."""
        estimator = estimator or self.cfg.estimator
        out = self.ring_forward(x, window)
        rng = out["range"]
        if "bin_logits" in out and estimator == "median":
            p = torch.softmax(out["bin_logits"], dim=2)
            cdf = torch.cumsum(p, dim=2)
            k = (cdf < 0.5).sum(2, keepdim=True).clamp(max=p.shape[2] - 1)  # first bin with cdf >= 0.5
            c_hi = torch.gather(cdf, 2, k)
            p_k = torch.gather(p, 2, k).clamp_min(1e-12)
            frac = ((0.5 - (c_hi - p_k)) / p_k).clamp(0, 1)  # linear within the bin
            dr = self.cfg.max_range / p.shape[2]
            rng = ((k.float() + frac) * dr).squeeze(2)
        elif "bin_logits" in out and estimator == "mode":
            lg = out["bin_logits"].masked_fill(~mode_window(out["bin_logits"]), float("-inf"))
            rng = (torch.softmax(lg, dim=2) * self.centres).sum(2)
        elif estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be 'mean', 'median' or 'mode', got {estimator!r}")
        valid = torch.sigmoid(out["valid_logit"]) >= valid_threshold
        res = {"confidence": mode_confidence(out["bin_logits"])} if "bin_logits" in out else {}
        rng = torch.where(valid, rng, torch.full_like(rng, float("nan")))
        return {"range": rng, "human_prob": torch.sigmoid(out["human_logit"]), "valid": valid, **res}


def mode_confidence(bin_logits: torch.Tensor) -> torch.Tensor:
    """(B,3,H,W) probability mass of each beam's range-bin distribution (softmax of ``bin_logits``
    (B,3,n_bins,H,W)) within ±``MODE_HALF_BINS`` bins of its most likely bin: the model's own
    probability that the mode estimate is the return's bin; trained with the per-bin likelihood
    (loss "ce") it tracks how often the return is right (measured in docs/design/stage2.md)."""
    return (torch.softmax(bin_logits, dim=2) * mode_window(bin_logits)).sum(2)


def mode_window(bin_logits: torch.Tensor) -> torch.Tensor:
    """(B,3,n_bins,H,W) bool: the bins within ±``MODE_HALF_BINS`` of each beam's most likely bin."""
    idx = torch.arange(bin_logits.shape[2], device=bin_logits.device).view(1, 1, -1, 1, 1)
    return (idx - bin_logits.argmax(2, keepdim=True)).abs() <= MODE_HALF_BINS
