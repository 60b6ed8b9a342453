"""Torch datasets over radar heatmaps and multi-return ground truth.

Samples are dicts: ``heatmap`` (N_r', H', W') float32 (or float16, when asked) normalised to
[−1, 1], ``range`` (3, H', W') float32 metres (NaN = none), ``label`` (3, H', W') uint8, ``scene``
(str), ``frame`` (int). The normalisation is a recorded transform (:class:`HeatmapNorm`) of the
linear amplitude, whatever the storage (:mod:`holodata.dataset.heatmap`); the parameters travel in
the checkpoint.
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from holodata.dataset.heatmap import heatmap_code, read_heatmap
from holodata.dataset.layout import GT_LABEL, GT_RANGE, RADAR_HEATMAP
from holodata.dataset.splits import split_scenes
from holodata.errors import DatasetError


@dataclass
class HeatmapNorm:
    """``x = 2·(log10(a + eps) − lo)/(hi − lo) − 1``, clipped to [−1, 1]; a: linear amplitude."""

    eps: float = 1e-3
    lo: float = -3.0
    hi: float = 0.0

    def __call__(self, a: np.ndarray) -> np.ndarray:
        x = np.array(a, dtype=np.float32)  # one copy, then in place
        np.maximum(x, 0, out=x)
        x += np.float32(self.eps)
        np.log10(x, out=x)
        x -= np.float32(self.lo)
        x *= np.float32(2.0 / (self.hi - self.lo))
        x -= np.float32(1.0)
        return np.clip(x, -1.0, 1.0, out=x)

    @classmethod
    def fit(cls, samples: np.ndarray, eps: float = 1e-3, q: tuple[float, float] = (1.0, 99.9)) -> HeatmapNorm:
        """Bounds from percentiles of log10(a + eps) over ``samples`` (any shape)."""
        la = np.log10(np.maximum(np.asarray(samples, np.float64), 0) + eps).ravel()
        lo, hi = np.percentile(la, q)
        if not hi > lo:
            hi = lo + 1.0
        return cls(eps=float(eps), lo=float(lo), hi=float(hi))

    def to_dict(self) -> dict:
        return {"kind": "log10_minmax", **asdict(self)}

    @classmethod
    def from_dict(cls, d: dict) -> HeatmapNorm:
        return cls(eps=float(d["eps"]), lo=float(d["lo"]), hi=float(d["hi"]))


@dataclass
class SampleTransform:
    """Optional reductions applied to every sample: ``downsample`` strides (H, W) by this factor
    (GT is strided too, never averaged across NaN); ``range_pool`` max-pools range bins by this
    factor; ``crop_w`` takes an azimuth window of this width (random offset, wrapping) when
    ``random_crop`` else the first columns; ``roll`` shifts columns circularly by a random amount
    (training augmentation; needs ``gen``)."""

    downsample: int = 1
    range_pool: int = 1
    crop_w: int | None = None
    random_crop: bool = False
    roll: bool = False  # random circular azimuth shift (a rotation of the scene about z)

    def to_dict(self) -> dict:
        return asdict(self)


def apply_transform(hm: np.ndarray, rng: np.ndarray, lab: np.ndarray, t: SampleTransform,
                    gen: np.random.Generator | None = None):
    if t.range_pool > 1:
        n = hm.shape[0] // t.range_pool * t.range_pool
        hm = hm[:n].reshape(n // t.range_pool, t.range_pool, *hm.shape[1:]).max(1)
    if t.downsample > 1:
        f = t.downsample
        hm, rng, lab = hm[:, ::f, ::f], rng[:, ::f, ::f], lab[:, ::f, ::f]
    if t.crop_w is not None and t.crop_w < hm.shape[-1]:
        W = hm.shape[-1]
        j0 = int(gen.integers(W)) if (t.random_crop and gen is not None) else 0
        cols = (j0 + np.arange(t.crop_w)) % W
        hm, rng, lab = hm[..., cols], rng[..., cols], lab[..., cols]
    elif t.roll and gen is not None:
        s = int(gen.integers(hm.shape[-1]))
        hm, rng, lab = (np.roll(a, s, axis=-1) for a in (hm, rng, lab))
    return hm, rng, lab


class EpochAugment:
    """Per-sample augmentation draws keyed by (seed, epoch, sample index): the crop/roll of sample i
    in epoch e is the same whichever process, DataLoader worker or data-parallel rank reads it, so
    a run is reproducible and N training processes see the batches one process would
    (:func:`holodata.torch.train.fit` calls :meth:`set_epoch` before each epoch)."""

    _aug_key: tuple[int, int] = (0, 0)

    def set_epoch(self, seed: int, epoch: int) -> None:
        self._aug_key = (int(seed) % 2**32, int(epoch))

    def sample_gen(self, i: int) -> np.random.Generator:
        return np.random.default_rng([*self._aug_key, int(i)])


class ArrayFrames(EpochAugment, Dataset):
    """In-memory frames: heatmap (T,N_r,H,W) linear amplitude, range (T,3,H,W), label (T,3,H,W)."""

    def __init__(self, heatmap, gt_range, gt_label=None, norm: HeatmapNorm | None = None,
                 transform: SampleTransform | None = None, scene: str = "memory"):
        self.hm = np.asarray(heatmap)
        self.rng = np.asarray(gt_range, dtype=np.float32)
        self.lab = np.zeros(self.rng.shape, np.uint8) if gt_label is None else np.asarray(gt_label, np.uint8)
        self.norm = norm or HeatmapNorm.fit(self.hm[: min(len(self.hm), 8)])
        self.transform = transform or SampleTransform()
        self.scene = scene

    def __len__(self) -> int:
        return len(self.hm)

    def __getitem__(self, i: int) -> dict:
        hm, rng, lab = apply_transform(self.hm[i], self.rng[i], self.lab[i], self.transform, self.sample_gen(i))
        return _sample(self.norm(hm), rng, lab, self.scene, i)


def _sample(hm, rng, lab, scene, frame) -> dict:
    hm = np.ascontiguousarray(hm, dtype=hm.dtype if hm.dtype in (np.float16, np.float32) else np.float32)
    return {"heatmap": torch.from_numpy(hm),
            "range": torch.from_numpy(np.ascontiguousarray(rng, dtype=np.float32)),
            "label": torch.from_numpy(np.ascontiguousarray(lab, dtype=np.uint8)),
            "scene": scene, "frame": int(frame)}


class HeatmapDataset(EpochAugment, Dataset):
    """Frames of a holodata dataset's ``split`` (by scene). ``ds``: an opened dataset or its URL.

    Safe with multi-process DataLoader workers: the Zarr store is (re)opened lazily in each
    process (handles are dropped when pickled). ``norm`` defaults to one fitted on a few training
    frames; pass the checkpoint's norm at evaluation time. ``dtype`` of the samples' heatmap:
    float16 halves what DataLoader workers hand over (the trainer casts on its device; a 64×512
    code's normalised value is exact in float16's 11 bits).
    """

    def __init__(self, ds, split: str = "train", norm: HeatmapNorm | None = None,
                 transform: SampleTransform | None = None, scenes: list[str] | None = None,
                 frames_per_scene: int | None = None, with_label: bool = True, dtype=np.float32):
        from holodata.dataset import open_dataset

        if isinstance(ds, (str, os.PathLike)):
            self.url = str(ds)
            ds = open_dataset(self.url)
        else:
            self.url = getattr(ds, "url", None)
            if self.url is not None:
                self.url = str(self.url)
        self._ds, self._pid = ds, os.getpid()
        self._scenes: dict = {}
        self._scenes_of = None
        self._tables: dict = {}
        self.split = split
        self.scenes = list(scenes) if scenes is not None else split_scenes(ds, split)
        self.index: list[tuple[str, int]] = []
        for sid in self.scenes:
            sc = ds.scene(sid)
            sc.require_complete("training or evaluation")
            names = set(sc.arrays())
            for need in (RADAR_HEATMAP, GT_RANGE):
                if need not in names:
                    raise DatasetError(f"scene {sid}: no {need} array (run raytrace-gt / ingest a radar topic first)")
            n = int(sc[GT_RANGE].shape[0])
            if frames_per_scene is not None:
                n = min(n, frames_per_scene)
            self.index += [(sid, k) for k in range(n)]
        if not self.index:
            raise DatasetError(f"split {split!r} of {self.url or 'dataset'} has no frames")
        self.with_label = with_label
        self.dtype = np.dtype(dtype)
        self.transform = transform or SampleTransform()
        self.norm = norm or self._fit_norm()
        self.grid = ds.grid
        self.range_bins = ds.range_bins

    def _dataset(self):
        if self._ds is None or self._pid != os.getpid():
            from holodata.dataset import open_dataset

            if self.url is None:
                raise DatasetError("HeatmapDataset was built from an in-memory dataset without a URL")
            self._ds, self._pid = open_dataset(self.url), os.getpid()
        return self._ds

    def __getstate__(self):
        state = dict(self.__dict__)
        if self.url is not None:
            state["_ds"] = state["_scenes_of"] = None
            state["_scenes"] = {}
        return state

    def _scene(self, sid: str):
        """Scene ``sid`` of this process's dataset handle, opened once (its array listing and shard
        indexes are reused by every read)."""
        ds = self._dataset()
        if self._scenes_of is not ds:
            self._scenes, self._scenes_of = {}, ds
        if sid not in self._scenes:
            self._scenes[sid] = ds.scene(sid)
        return self._scenes[sid]

    def _fit_norm(self) -> HeatmapNorm:
        picks = self.index[:: max(len(self.index) // 4, 1)][:4]
        hm = [read_heatmap(self._scene(s), k) for s, k in picks]
        return HeatmapNorm.fit(np.stack(hm))

    def __len__(self) -> int:
        return len(self.index)

    def _gt(self, sc, k: int) -> tuple[np.ndarray, np.ndarray]:
        rng = sc.frame(GT_RANGE, k).astype(np.float32, copy=False)
        if self.with_label and GT_LABEL in sc.nodes():
            lab = sc.frame(GT_LABEL, k).astype(np.uint8, copy=False)
        else:
            lab = np.zeros(rng.shape, np.uint8)
        return rng, lab

    def read(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw (heatmap linear amplitude float32, range, label) of item i, before transform and
        normalisation."""
        sid, k = self.index[i]
        sc = self._scene(sid)
        return (read_heatmap(sc, k), *self._gt(sc, k))

    def __getitem__(self, i: int) -> dict:
        """The training sample of item i. Stored uint8 codes and float16 values are cropped as
        stored, then range-pooled and normalised in one table-lookup pass
        (:func:`holodata.torch._lut_kernel.pool_lookup`: the values :class:`HeatmapNorm` gives the
        decoded amplitude); float32 goes through the norm."""
        from dataclasses import replace

        from ._lut_kernel import pool_lookup

        sid, k = self.index[i]
        sc = self._scene(sid)
        raw = sc.frame(RADAR_HEATMAP, k)
        rng, lab = self._gt(sc, k)
        gen = self.sample_gen(i)
        if raw.dtype in (np.uint8, np.float16):
            codes = raw if raw.dtype == np.uint8 else raw.view(np.uint16)
            codes, rng, lab = apply_transform(codes, rng, lab, replace(self.transform, range_pool=1), gen)
            x = pool_lookup(codes, self._values(sc), max(self.transform.range_pool, 1), self.dtype)
        else:
            hm, rng, lab = apply_transform(raw, rng, lab, self.transform, gen)
            x = self.norm(hm).astype(self.dtype, copy=False)
        return _sample(x, rng, lab, sid, k)

    def _values(self, sc) -> np.ndarray:
        """The normalised input of every stored code (float32): (256,) for uint8 log codes (their
        LogCode), (65536,) for float16 bit patterns (NaN and negative patterns where the norm
        puts them); one per code and norm, kept."""
        code = heatmap_code(sc)
        key = (code, self.norm.eps, self.norm.lo, self.norm.hi)
        if key not in self._tables:
            if code is None:
                with np.errstate(invalid="ignore"):   # the NaN and -inf patterns map as the norm maps them
                    self._tables[key] = self.norm(np.arange(65536, dtype=np.uint32).astype(np.uint16).view(np.float16))
            else:
                self._tables[key] = self.norm(code.table())
        return self._tables[key]
