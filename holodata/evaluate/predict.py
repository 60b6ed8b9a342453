"""A trained run as a predictor: heatmaps → multi-return range images → 3-D points.

One place loads a run (``RUN/checkpoint.pt``, plus ``RUN/stage2.pt`` when the run trained the
learned stage two) and knows its sample transform and normalisation, so ``holodata evaluate``
(which batches frames and scores them) and ``holodata view`` (which draws one frame at a time) run
the model the same way. Stage one is the multi-return U-Net (paper §4.3); stage two is the
learned ray tracer + voxel refiner when the run has one (§4.4), else the analytic un-mirroring of
:mod:`holodata.geometry.unmirror` (eq. 2–5) with the free-space LOS test.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from holodata.conventions import Grid, is_human, is_los
from holodata.geometry.unmirror import los_mask, unmirror
from holodata.scene_beams import FrameGeometry


@dataclass
class Predictor:
    """A loaded run. ``model`` None = the oracle (the ground truth is the prediction);
    ``downsample``/``range_pool``: the run's sample transform; ``stage2``: the learned stage two or
    None; ``estimator``: the per-beam point estimate (see ``MultiReturnUNet.predict``)."""

    model: object
    stage2: object
    stage2_checkpoint: dict | None
    checkpoint: dict
    device: object
    estimator: str | None = None

    @property
    def point_estimator(self) -> str:
        """The estimate used: the one asked for, else the model's own (``ModelConfig.estimator``)."""
        return self.estimator or (self.model.cfg.estimator if self.model is not None else "mean")

    @classmethod
    def load(cls, checkpoint, device: str = "cpu", estimator: str | None = None, oracle: bool = False) -> Predictor:
        """Load ``checkpoint`` (a run directory or its checkpoint file); ``oracle``: no model."""
        from holodata.torch.checkpoint import load_checkpoint
        from holodata.torch.data import HeatmapNorm
        from holodata.torch.train import model_from_checkpoint, resolve_device

        dev = resolve_device(device)
        if oracle:
            return cls(None, None, None, {"norm": HeatmapNorm().to_dict(), "transform": {}, "epoch": 0}, dev, estimator)
        from holodata.torch.pretrained import resolve

        checkpoint = resolve(checkpoint)
        ck = load_checkpoint(checkpoint)
        model = model_from_checkpoint(ck, device=str(dev))
        from holodata.torch.stage2_infer import STAGE2_CHECKPOINT, load_stage2

        s2_path = (Path(checkpoint) if Path(checkpoint).is_dir() else Path(checkpoint).parent) / STAGE2_CHECKPOINT
        stage2, ck2 = load_stage2(s2_path, device=str(dev)) if s2_path.exists() else (None, None)
        return cls(model, stage2, ck2, ck, dev, estimator)

    @property
    def norm(self):
        from holodata.torch.data import HeatmapNorm

        return HeatmapNorm.from_dict(self.checkpoint["norm"])

    @property
    def downsample(self) -> int:
        return int((self.checkpoint.get("transform") or {}).get("downsample", 1))

    def transforms(self):
        """(model transform, baseline transform): the run's strides and range pooling, and the same
        strides without pooling (what the scores and the baseline read)."""
        from dataclasses import replace

        from holodata.torch.checkpoint import inference_transform

        tf = inference_transform(self.checkpoint)[0]
        return tf, replace(tf, range_pool=1)

    @property
    def window(self) -> int | None:
        """The azimuth crop width stage one was trained on (None: whole rings)."""
        from holodata.torch.checkpoint import inference_transform

        return inference_transform(self.checkpoint)[1]

    def ranges(self, heatmaps: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stage one on linear heatmaps (n_range, H, W) each → (range (B,3,H',W') m NaN = none,
        human probability (B,3,H',W'), cloud range (B,3,H',W')) on the run's strided grid. The range
        images are stage one's (what Table 1 scores: a dropped return counts as a miss); the cloud
        ranges are what stage two un-mirrors: the same without the returns below the confidence gate
        the run's stage two was calibrated with (``Stage2.min_confidence``; the range images when none)."""
        import torch

        from holodata.torch.data import apply_transform

        model_tf, norm = self.transforms()[0], self.norm
        z = np.zeros((3,) + heatmaps[0].shape[1:], np.float32)
        x = np.stack([norm(apply_transform(hm, z, z.astype(np.uint8), model_tf)[0]) for hm in heatmaps])
        with torch.no_grad():
            pred = self.model.predict(torch.from_numpy(x).to(self.device), estimator=self.estimator, window=self.window)
        from holodata.torch.stage2_infer import apply_gate

        rng = pred["range"].float().cpu().numpy()
        gate = getattr(self.stage2, "min_confidence", None) if "confidence" in pred else None
        cloud = apply_gate(rng, pred["confidence"].float().cpu().numpy() if gate else None, gate)
        return rng, pred["human_prob"].float().cpu().numpy(), cloud

    def points(self, rng: np.ndarray, human: np.ndarray | None, geo: FrameGeometry, grid: Grid) -> dict:
        """Stage two of the "model" row for one frame: {point (…,3) radar frame, los (…) bool,
        human (…) bool} — the refined cloud (or the learned ray tracer's points) when the run
        has a learned stage two, else the analytic un-mirroring with the free-space LOS test.
        ``grid``: the run's strided grid (:func:`holodata.conventions.reduced_grid`)."""
        if self.stage2 is not None:
            s2 = self.stage2.predict(rng, human, geo.directions, geo.origins, grid)
            return s2["refined"] or s2["no_refine"]
        P = unmirror(rng, geo.directions, grid=grid, origins=geo.origins)["point"]
        hum = np.zeros(P.shape[:-1], bool) if human is None else (np.asarray(human) >= 0.5)
        return {"point": P, "los": los_mask(P, rng[0], grid, origins=geo.origins), "human": hum}


def oracle_points(gt_range: np.ndarray, gt_label: np.ndarray, geo: FrameGeometry, grid: Grid) -> dict:
    """The ground truth as a prediction: GT ranges un-mirrored with the GT normals, GT labels."""
    P = unmirror(gt_range, geo.directions, normals=geo.gt_normal, grid=grid, origins=geo.origins)["point"]
    return {"point": P, "los": is_los(gt_label), "human": is_human(gt_label)}


def label_of(los: np.ndarray, human: np.ndarray) -> np.ndarray:
    """Per-point class ids (:class:`holodata.conventions.Label`) from LOS and human flags."""
    from holodata.conventions import Label

    lab = np.where(los, int(Label.LOS_STRUCTURE), int(Label.NLOS_STRUCTURE))
    return np.where(human, lab + 2, lab).astype(np.uint8)


__all__ = ["Predictor", "label_of", "oracle_points"]
