"""HeatmapDataset read throughput vs np.load of the same frames as .npy files, and training
samples/s on CPU at the paper grid (256 range bins x 64 x 512), in the same run.

    .venv/bin/python benchmarks/loader.py [--frames 16] [--dtype float16] [--train-steps 3]

1. Writes --frames frames of (256,64,512) heatmaps + (3,64,512) GT ranges into a holodata dataset
   (one scene, Blosc-zstd shards) and the same arrays as one .npy file per frame.
2. Reads every frame through HeatmapDataset.read (raw, what the model's transform consumes) and
   through np.load; prints frames/s of each and the ratio (≥ 1 means the dataset is as fast).
3. Full samples (read + log10 normalisation) via HeatmapDataset[i], for reference.
4. Training: forward+backward+AdamW steps of the default TrainConfig model (depth 7) at batch 1
   on CPU; samples/s.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from holodata.conventions import Grid, RangeBins  # noqa: E402
from holodata.dataset import create_dataset  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--dtype", default="float16")
    ap.add_argument("--train-steps", type=int, default=3)
    a = ap.parse_args()
    grid, bins = Grid(), RangeBins()
    rng = np.random.default_rng(0)
    T = a.frames
    tmp = Path(tempfile.mkdtemp(prefix="holodata-loader-"))
    url = str(tmp / "ds.zarr")
    w = create_dataset(url, grid=grid, range_bins=bins, created_by="benchmarks/loader.py", shard_frames=8)
    sc = w.scene("bench", n_frames=T, attrs={"corner_type": "L", "width_m": 2.0})
    hm_arr = sc.frame_array("radar/heatmap", (bins.n, grid.H, grid.W), a.dtype, ["frame", "range", "elevation", "azimuth"], "1",
                            0.0)
    r_arr = sc.frame_array("gt/range", (3, grid.H, grid.W), "float32", ["frame", "bounce", "elevation", "azimuth"], "m",
                           float("nan"))
    npy = tmp / "npy"
    npy.mkdir()
    # realistic-ish content: noise floor + a few peaks per beam (compresses like real heatmaps)
    for k in range(hm_arr.n_shards):
        fr = range(T)[hm_arr.frames(k)]
        hms, rs = [], []
        for t in fr:
            hm = (0.01 * rng.random((bins.n, grid.H, grid.W))).astype(a.dtype)
            R = rng.uniform(0.5, 9.0, (3, grid.H, grid.W)).astype(np.float32)
            idx = bins.index(R)
            for b in range(3):
                np.put_along_axis(hm, idx[b][None], np.asarray(1.0 / (b + 1), a.dtype), axis=0)
            hms.append(hm)
            rs.append(R)
            np.save(npy / f"{t:06d}_heatmap.npy", hm)
            np.save(npy / f"{t:06d}_range.npy", R)
        hm_arr.write_shard(k, np.stack(hms))
        r_arr.write_shard(k, np.stack(rs))
    w.set_splits(train=["bench"], test=[])

    from holodata.torch import HeatmapDataset, HeatmapNorm

    ds = HeatmapDataset(url, split="train", norm=HeatmapNorm(), with_label=False)

    def read_ds():
        for i in range(len(ds)):
            ds.read(i)

    def read_npy():
        for t in range(T):
            np.load(npy / f"{t:06d}_heatmap.npy")
            np.load(npy / f"{t:06d}_range.npy")

    def best(fn, n=3):
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return min(ts)

    t_ds, t_np = best(read_ds), best(read_npy)
    t_full = best(lambda: [ds[i] for i in range(len(ds))], 1)
    size_ds = sum(p.stat().st_size for p in Path(url).rglob("*") if p.is_file())
    size_np = sum(p.stat().st_size for p in npy.iterdir())
    print(f"{T} frames of {bins.n}x{grid.H}x{grid.W} {a.dtype}: HeatmapDataset.read {T / t_ds:.1f} frames/s, "
          f"np.load {T / t_np:.1f} frames/s; ratio {t_np / t_ds:.2f} (dataset {size_ds / 2**20:.0f} MiB, npy "
          f"{size_np / 2**20:.0f} MiB)")
    print(f"full samples (read + normalise): {T / t_full:.1f} frames/s")

    import torch

    from holodata.torch import TrainConfig
    from holodata.torch.losses import multi_return_loss
    from holodata.torch.model import ModelConfig, MultiReturnUNet

    cfg = TrainConfig()
    model = MultiReturnUNet(ModelConfig(in_channels=bins.n, depth=cfg.depth, base_channels=cfg.base_channels,
                                        max_channels=cfg.max_channels, blocks=cfg.blocks))
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr)
    s = ds[0]
    x, y = s["heatmap"][None], s["range"][None]
    ts = []
    for _ in range(a.train_steps + 1):
        t0 = time.perf_counter()
        loss, _ = multi_return_loss(model(x), y, None, cfg.loss_weights())
        opt.zero_grad()
        loss.backward()
        opt.step()
        ts.append(time.perf_counter() - t0)
    n_par = sum(p.numel() for p in model.parameters()) / 1e6
    print(f"training on CPU ({torch.get_num_threads()} threads), default model ({n_par:.1f} M params, depth {cfg.depth}), "
          f"batch 1 at 256x64x512: {1 / np.median(ts[1:]):.2f} samples/s")


if __name__ == "__main__":
    main()
