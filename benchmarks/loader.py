"""Training-sample throughput at the paper grid (256 range bins × 64 × 512): holodata's loader against
np.load of the same stored frames as .npy files, in the same run (issue 51 point 2).

    .venv/bin/python benchmarks/loader.py [--corners 4] [--frames 4] [--dtype uint8] [--range-pool 2]
        [--workers 0,2] [--train-steps 0]

1. Writes ``--corners`` × ``--frames`` frames with ``holodata synth --corners`` at 64×512 (real
   simulated heatmaps, so the compression is a corpus's), heatmaps stored as ``--dtype`` (uint8:
   log-amplitude codes, :class:`holodata.conventions.LogCode`; float16: linear amplitude), and
   the same stored arrays (heatmap + ground-truth range) as one .npy file each.
2. Reads every frame: ``Scene.frame`` (straight from the shard) and zarr's own read against
   ``np.load`` of the .npy; frames/s and the ratio (≥ 1: holodata is as fast as np.load).
3. Full training samples (read, range pool ``--range-pool``, normalise: ``HeatmapDataset[i]``)
   against the same work on the .npy (np.load, pool, :class:`HeatmapNorm` on the decoded
   amplitude), one process; then as ``holodata train`` loads them (float16 samples, its collate)
   through a torch DataLoader (batch 4) with each of ``--workers`` worker processes: the rate a
   training loop sees.
4. ``--train-steps N``: forward + backward + AdamW of the default model on one full ring, for scale.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from _run import best_of, header

from holodata.conventions import Grid, LogCode, RangeBins
from holodata.dataset import open_dataset
from holodata.dataset.layout import GT_RANGE, RADAR_HEATMAP
from holodata.synth.corpus import CorpusConfig, synth_corpus


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--corners", type=int, default=4)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--dtype", default="uint8", choices=("uint8", "float16", "float32"))
    ap.add_argument("--range-pool", type=int, default=2)
    ap.add_argument("--workers", default="0,2")
    ap.add_argument("--train-steps", type=int, default=0)
    ap.add_argument("--out", default=None, help="corpus folder (kept; reused when it exists)")
    a = ap.parse_args()
    header()
    grid, bins = Grid(), RangeBins()
    tmp = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="holodata-loader-"))
    url = str(tmp / "corpus.zarr")
    if not Path(url).exists():
        t0 = time.perf_counter()
        synth_corpus(url, CorpusConfig(corners=a.corners, frames=a.frames, grid=grid, range_bins=bins,
                                       heatmap_dtype=a.dtype), quiet=True)
        print(f"corpus: {a.corners} corners x {a.frames} frames at {grid.H}x{grid.W}x{bins.n}, {a.dtype}, "
              f"{time.perf_counter() - t0:.1f} s")
    ds = open_dataset(url)
    frames = [(sid, k) for sid in ds.scenes for k in range(ds.scene(sid).n_frames)]
    scenes = {sid: ds.scene(sid) for sid in ds.scenes}
    npy = tmp / "npy"
    npy.mkdir(exist_ok=True)
    for j, (sid, k) in enumerate(frames):
        np.save(npy / f"{j:05d}_heatmap.npy", scenes[sid].frame(RADAR_HEATMAP, k))
        np.save(npy / f"{j:05d}_range.npy", scenes[sid].frame(GT_RANGE, k))
    T = len(frames)
    hm_bytes = sum(p.stat().st_size for p in Path(url).rglob("*") if p.is_file() and "/radar/heatmap/c/" in str(p))
    print(f"{T} frames; heatmap stored {hm_bytes / T / 2**20:.1f} MiB per frame in the dataset, "
          f"{(npy / '00000_heatmap.npy').stat().st_size / 2**20:.1f} MiB as .npy")

    def read_frames():
        for sid, k in frames:
            scenes[sid].frame(RADAR_HEATMAP, k)
            scenes[sid].frame(GT_RANGE, k)

    def read_zarr():
        for sid, k in frames:
            np.asarray(scenes[sid][RADAR_HEATMAP][k])
            np.asarray(scenes[sid][GT_RANGE][k])

    def read_npy():
        for j in range(T):
            np.load(npy / f"{j:05d}_heatmap.npy")
            np.load(npy / f"{j:05d}_range.npy")

    t_fr, t_z, t_np = best_of(read_frames), best_of(read_zarr), best_of(read_npy)
    print(f"read: Scene.frame {T / t_fr:.1f} frames/s, zarr {T / t_z:.1f}, np.load {T / t_np:.1f}; "
          f"ratio Scene.frame/np.load {t_np / t_fr:.2f} (zarr {t_np / t_z:.2f})")

    from holodata.torch import HeatmapDataset
    from holodata.torch.data import SampleTransform, apply_transform

    tf = SampleTransform(range_pool=a.range_pool)
    hds = HeatmapDataset(url, split="train", scenes=ds.scenes, transform=tf, with_label=False)
    norm, code = hds.norm, LogCode() if a.dtype == "uint8" else None

    def samples():
        for i in range(len(hds)):
            hds[i]

    def samples_npy():   # the same work on the .npy: load, decode, pool, normalise
        for j in range(T):
            hm = np.load(npy / f"{j:05d}_heatmap.npy")
            hm = code.decode(hm) if code is not None else hm
            r = np.load(npy / f"{j:05d}_range.npy")
            hm, r, _ = apply_transform(hm, r, np.zeros(r.shape, np.uint8), tf)
            norm(hm)

    t_s, t_snp = best_of(samples), best_of(samples_npy)
    c = hds[0]["heatmap"].shape
    print(f"full samples ({tuple(c)} float32, range pooled x{a.range_pool}), one process: HeatmapDataset "
          f"{T / t_s:.1f} samples/s, np.load + numpy {T / t_snp:.1f}; ratio {t_snp / t_s:.2f}")

    import torch
    from torch.utils.data import DataLoader

    from holodata.torch.train import _collate

    train_set = HeatmapDataset(url, split="train", scenes=ds.scenes, transform=tf, with_label=False, norm=norm,
                               dtype=np.float16)   # as holodata train builds it
    for w in (int(x) for x in a.workers.split(",")):
        dl = DataLoader(train_set, batch_size=4, shuffle=True, num_workers=w, persistent_workers=w > 0,
                        collate_fn=_collate)
        epochs = max(1, 64 // T)
        next(iter(dl))   # workers started
        t0 = time.perf_counter()
        n = 0
        for _ in range(epochs):
            for b in dl:
                n += len(b["heatmap"])
        print(f"training DataLoader (float16 samples, holodata train's collate), {w} worker process(es), batch 4: "
              f"{n / (time.perf_counter() - t0):.1f} samples/s")

    if a.train_steps:
        from holodata.torch import TrainConfig
        from holodata.torch.losses import multi_return_loss
        from holodata.torch.model import ModelConfig, MultiReturnUNet

        cfg = TrainConfig()
        model = MultiReturnUNet(ModelConfig(in_channels=c[0], depth=cfg.depth, base_channels=cfg.base_channels,
                                            max_channels=cfg.max_channels, blocks=cfg.blocks))
        opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr)
        s = hds[0]
        x, y = s["heatmap"][None], s["range"][None]
        ts = []
        for _ in range(a.train_steps + 1):
            t0 = time.perf_counter()
            loss, _ = multi_return_loss(model(x), y, None, cfg.loss_weights())
            opt.zero_grad()
            loss.backward()
            opt.step()
            ts.append(time.perf_counter() - t0)
        print(f"training on CPU, default model, batch 1 full ring {tuple(c)}: {1 / np.median(ts[1:]):.2f} samples/s")


if __name__ == "__main__":
    main()
