"""Training losses for the multi-return model.

The paper's eq. 1 combines per-pixel L1 on range with LPIPS. LPIPS needs pretrained backbone
weights (AlexNet/VGG) that holodata cannot download, so the structure-aware term here is a
masked gradient-difference loss (L1 between the horizontal/vertical range gradients of prediction
and ground truth, over pixel pairs where both GT pixels have returns), which like LPIPS rewards
sharp edges (humans, corner edges) that plain L1 blurs.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F

from holodata.conventions import DEFAULT_MAX_RANGE_M, is_human

RANGE_LOSSES = ("l1", "ce")


@dataclass
class LossWeights:
    """Weights of :func:`multi_return_loss`'s terms; ``range_loss`` picks the range term: "l1" (L1 on
    the soft-argmax mean) or "ce" (:func:`range_bin_nll`, a per-bin likelihood); ``human_hard``: the
    share of return pixels the human term averages over, the hardest (largest loss) ones: 1 = all,
    PanoRadar's segmentation keeps 0.2 (online hard example mining)."""

    range: float = 1.0
    gradient: float = 0.5
    valid: float = 0.2
    human: float = 0.2
    human_pos_weight: float = 10.0
    range_loss: str = "l1"
    human_hard: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)


def masked_l1(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean |pred − gt| over pixels where gt is finite (NaN = ignore); 0 when none."""
    m = torch.isfinite(gt)
    if not m.any():
        return pred.sum() * 0.0
    return (pred[m] - gt[m]).abs().mean()


def masked_gradient_loss(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """L1 between finite differences of pred and gt along the last two axes, over neighbour pairs
    where both gt pixels are finite."""
    total, count = pred.sum() * 0.0, 0
    for dim in (-1, -2):
        gp = torch.diff(pred, dim=dim)
        gg = torch.diff(gt, dim=dim)
        m = torch.isfinite(gg)
        if m.any():
            total = total + (gp[m] - gg[m]).abs().sum()
            count += int(m.sum())
    return total / max(count, 1)


def two_hot(gt_range: torch.Tensor, n_bins: int, max_range: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Sub-bin targets of ranges ``gt_range`` (any shape, m, finite) on ``n_bins`` bins of width
    ``max_range / n_bins`` centred at ``(k + ½)·dr``: the lower neighbouring bin (long) and the weight
    of the upper one (the range's fractional position between the two centres, in [0, 1]). The
    distribution ``(1 − f)·δ_lo + f·δ_(lo+1)`` has exactly the range as its mean, so a perfect
    prediction loses nothing to the bins (MuZero's / DreamerV3's two-hot encoding)."""
    t = (gt_range / (max_range / n_bins) - 0.5).clamp(0.0, n_bins - 1.0)
    lo = t.floor().clamp(max=n_bins - 2).long()
    return lo, t - lo


def range_bin_nll(bin_logits: torch.Tensor, gt_range: torch.Tensor, max_range: float) -> torch.Tensor:
    """Mean cross-entropy of each beam's range-bin distribution (softmax of ``bin_logits``
    (B, 3, n_bins, H, W)) against the two-hot target of its finite GT range (:func:`two_hot`); 0 when
    none. Unlike L1 on the mean, a beam whose heatmap shows two plausible peaks is not pushed to
    put its estimate between them: the likelihood rewards mass on the right peak, and the mode
    (``MultiReturnUNet.predict(estimator="mode")``) reads it out."""
    m = torch.isfinite(gt_range)
    if not m.any():
        return bin_logits.sum() * 0.0
    logp = torch.log_softmax(bin_logits, dim=2).movedim(2, -1)[m]      # (N, n_bins)
    lo, f = two_hot(gt_range[m], logp.shape[-1], max_range)
    lp_lo = logp.gather(1, lo[:, None])[:, 0]
    lp_hi = logp.gather(1, (lo + 1)[:, None])[:, 0]
    return -((1 - f) * lp_lo + f * lp_hi).mean()


def multi_return_loss(out: dict, gt_range: torch.Tensor, gt_label: torch.Tensor | None = None,
                      w: LossWeights = LossWeights(), max_range: float = DEFAULT_MAX_RANGE_M) -> tuple[torch.Tensor, dict]:
    """Total loss and its parts. out: model dict (range, valid_logit, human_logit, each (B,3,H,W);
    ``bin_logits`` (B,3,n_bins,H,W) for ``w.range_loss == "ce"``); gt_range (B,3,H,W) metres NaN =
    none; gt_label (B,3,H,W) uint8 (3/4 = human) or None; ``max_range`` m, the bins' extent.

    The human term is BCE over the pixels with a return, human pixels weighted by
    ``w.human_pos_weight``: a hidden person is a few dozen of ~10⁴ returns, so unweighted BCE is
    minimised by never saying "human" (its probability then stays far below 0.5 everywhere).
    With weight w the head says human (p ≥ 0.5) where the odds of a human are ≥ 1/w. With
    ``w.human_hard`` < 1 only that share of the pixels, those with the largest loss, is averaged:
    the many easy structure pixels stop diluting the few human ones."""
    if w.range_loss not in RANGE_LOSSES:
        raise ValueError(f"range loss must be one of {', '.join(RANGE_LOSSES)}, got {w.range_loss!r}")
    parts = {
        "l1": masked_l1(out["range"], gt_range),
        "grad": masked_gradient_loss(out["range"], gt_range),
        "valid": F.binary_cross_entropy_with_logits(out["valid_logit"], torch.isfinite(gt_range).float()),
    }
    rng_term = parts["l1"]
    if w.range_loss == "ce":
        if "bin_logits" not in out:
            raise ValueError("range loss 'ce' needs a model with range-bin logits (head 'softargmax')")
        parts["nll"] = rng_term = range_bin_nll(out["bin_logits"], gt_range, max_range)
    total = w.range * rng_term + w.gradient * parts["grad"] + w.valid * parts["valid"]
    if gt_label is not None and w.human > 0:
        m = torch.isfinite(gt_range)
        if m.any():
            human = is_human(gt_label).float()
            pw = torch.tensor(float(w.human_pos_weight), device=human.device)
            per = F.binary_cross_entropy_with_logits(out["human_logit"][m], human[m], pos_weight=pw, reduction="none")
            if w.human_hard < 1.0:   # the hardest share of the pixels (at least one)
                per = torch.topk(per, max(1, int(round(w.human_hard * per.numel())))).values
            parts["human"] = per.mean()
            total = total + w.human * parts["human"]
    return total, {k: float(v.detach()) for k, v in parts.items()}
