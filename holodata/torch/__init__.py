"""PyTorch side of holodata (the only package that imports torch; install the ``train`` extra).

HeatmapDataset over a holodata dataset, the multi-return UNet, losses and the training loop;
stage two (learned ray tracer + volumetric refiner) in ``stage2`` / ``stage2_train`` / ``stage2_infer``.
``train(dataset_url, out_dir, config) -> RunResult`` is the library entry point of ``holodata train``.
"""
from .checkpoint import load_checkpoint
from .data import ArrayFrames, HeatmapDataset, HeatmapNorm, SampleTransform, split_scenes
from .losses import LossWeights, masked_gradient_loss, masked_l1, multi_return_loss
from .model import ModelConfig, MultiReturnUNet
from .optim import OptimiserSettings
from .stage2_infer import load_stage2
from .stage2_train import Stage2Config, train_stage2
from .train import RunOptions, RunResult, TrainConfig, fit, model_from_checkpoint, train

__all__ = [
    "ArrayFrames", "HeatmapDataset", "HeatmapNorm", "SampleTransform", "split_scenes",
    "LossWeights", "masked_gradient_loss", "masked_l1", "multi_return_loss",
    "ModelConfig", "MultiReturnUNet", "OptimiserSettings", "RunOptions", "RunResult", "TrainConfig", "fit",
    "load_checkpoint", "model_from_checkpoint", "train", "Stage2Config", "load_stage2", "train_stage2",
]
