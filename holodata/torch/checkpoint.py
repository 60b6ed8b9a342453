"""Stage-one checkpoints from elsewhere, loaded as tensors and plain data only.

``torch.load(..., weights_only=True)`` through :func:`holodata.safe_io.load_torch`: a checkpoint
that pickles any other Python object is refused (one :class:`~holodata.errors.InputError` line)
before anything in it runs. The checkpoints holodata writes (``RUN/checkpoint.pt``, ``RUN/stage2.pt``)
hold only tensors, numbers, strings, lists, tuples and dicts, so they load so.
"""
from __future__ import annotations

from pathlib import Path

from holodata.errors import InputError
from holodata.safe_io import load_torch

CHECKPOINT = "checkpoint.pt"   # the stage-one file of a run directory


def checkpoint_file(path) -> Path:
    """The stage-one checkpoint file ``path`` names (``RUN/checkpoint.pt`` for a run directory)."""
    p = Path(path)
    return p / CHECKPOINT if p.is_dir() else p


def load_checkpoint(path) -> dict:
    """Load a stage-one checkpoint file, or ``RUN/checkpoint.pt`` when given a run directory
    (tensors and plain data only; InputError otherwise)."""
    p = checkpoint_file(path)
    if not p.exists():
        raise InputError(f"{p}: no such checkpoint")
    return load_torch(p, "checkpoint")


def inference_transform(ck: dict):
    """(SampleTransform, window) stage one is run with on whole frames: the run's strides and range
    pooling (no crop, no augmentation), and the azimuth crop width it was trained on (None: whole
    rings), which :meth:`holodata.torch.model.MultiReturnUNet.ring_forward` tiles the ring with."""
    from .data import SampleTransform

    tf = ck.get("transform") or {}
    crop = tf.get("crop_w")
    return (SampleTransform(downsample=int(tf.get("downsample", 1)), range_pool=int(tf.get("range_pool", 1))),
            int(crop) if crop else None)
