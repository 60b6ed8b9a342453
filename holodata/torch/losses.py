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

from holodata.conventions import is_human


@dataclass
class LossWeights:
    range: float = 1.0
    gradient: float = 0.5
    valid: float = 0.2
    human: float = 0.2
    human_pos_weight: float = 10.0

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


def multi_return_loss(out: dict, gt_range: torch.Tensor, gt_label: torch.Tensor | None = None,
                      w: LossWeights = LossWeights()) -> tuple[torch.Tensor, dict]:
    """Total loss and its parts. out: model dict (range, valid_logit, human_logit, each (B,3,H,W));
    gt_range (B,3,H,W) metres NaN = none; gt_label (B,3,H,W) uint8 (3/4 = human) or None.

    The human term is BCE over the pixels with a return, human pixels weighted by
    ``w.human_pos_weight``: a hidden person is a few dozen of ~10⁴ returns, so unweighted BCE is
    minimised by never saying "human" (its probability then stays far below 0.5 everywhere).
    With weight w the head says human (p ≥ 0.5) where the odds of a human are ≥ 1/w."""
    parts = {
        "l1": masked_l1(out["range"], gt_range),
        "grad": masked_gradient_loss(out["range"], gt_range),
        "valid": F.binary_cross_entropy_with_logits(out["valid_logit"], torch.isfinite(gt_range).float()),
    }
    total = w.range * parts["l1"] + w.gradient * parts["grad"] + w.valid * parts["valid"]
    if gt_label is not None and w.human > 0:
        m = torch.isfinite(gt_range)
        if m.any():
            human = is_human(gt_label).float()
            pw = torch.tensor(float(w.human_pos_weight), device=human.device)
            parts["human"] = F.binary_cross_entropy_with_logits(out["human_logit"][m], human[m], pos_weight=pw)
            total = total + w.human * parts["human"]
    return total, {k: float(v.detach()) for k, v in parts.items()}
