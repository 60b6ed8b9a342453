"""CPU cost of one training step of the stage-two refiner: the sparse (scatter/gather) voxel UNet
of holodata.torch.stage2 against a dense 3-D convolution UNet of the same channels on a grid that
covers the radar's reach, batch 1. Prints ms per forward+backward step (median of --repeat).

    .venv/bin/python benchmarks/stage2_refiner.py [--voxels 8000] [--threads 2] [--repeat 3]

spconv (CPU wheel: backward needs CUDA) and MinkowskiEngine (no torch 2 build) cannot train here
(/work/shared/FIELD-NOTES.md); results go to docs/design/stage2.md.
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch
import torch.nn as nn
import torch.nn.functional as F
from _run import header

from holodata.torch.stage2 import RefinerConfig, VoxelRefiner, voxelize


class DenseUNet(nn.Module):
    def __init__(self, ch=(16, 32, 48, 64), cin=12):
        super().__init__()
        self.inp = nn.Conv3d(cin, ch[0], 1)
        self.enc = nn.ModuleList([nn.Sequential(nn.Conv3d(c if i == 0 else ch[i - 1], c, 3, padding=1, stride=1 if i == 0 else 2),
                                                nn.ReLU(), nn.Conv3d(c, c, 3, padding=1), nn.ReLU()) for i, c in enumerate(ch)])
        self.dec = nn.ModuleList([nn.Sequential(nn.Conv3d(ch[i] + ch[i + 1], ch[i], 3, padding=1), nn.ReLU(),
                                                nn.Conv3d(ch[i], ch[i], 3, padding=1), nn.ReLU()) for i in range(len(ch) - 1)])
        self.head = nn.Conv3d(ch[0], 6, 1)

    def forward(self, x):
        x = self.inp(x)
        skips = []
        for e in self.enc:
            x = e(x)
            skips.append(x)
        for i in range(len(self.dec) - 1, -1, -1):
            s = skips[i]
            x = self.dec[i](torch.cat([s, F.interpolate(x, size=s.shape[2:])], 1))
        return self.head(x)


def step_ms(fn, repeat):
    ts = []
    for _ in range(repeat + 1):
        t = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t) * 1000)
    return statistics.median(ts[1:])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--voxels", type=int, default=8000, help="occupied voxels (a 32x128 frame: ~8k at 10 cm)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    header()
    torch.set_num_threads(a.threads)
    g = torch.Generator().manual_seed(0)
    # points on walls of a corridor within the radar's reach
    n = a.voxels
    t = torch.rand(n, generator=g) * 9.0
    side = torch.randint(0, 4, (n,), generator=g)
    z = torch.rand(n, generator=g) * 3.0 - 1.2
    x = torch.where(side < 2, t - 4.5, torch.where(side == 2, torch.full_like(t, 1.2), torch.full_like(t, -1.2)))
    y = torch.where(side < 2, torch.where(side == 0, torch.full_like(t, 1.2), torch.full_like(t, -1.2)), t - 4.5)
    pts = torch.stack([x, y, z], 1)
    ref = VoxelRefiner(RefinerConfig())
    vox = voxelize(pts, torch.zeros(n, dtype=torch.long), torch.zeros(n, dtype=torch.long), torch.zeros(n), 0.1, 9.6)

    def sparse():
        o = ref(vox)
        (o["cls_logit"].sum() + o["offset"].sum()).backward()

    print(f"sparse voxel UNet, {len(vox.coords)} occupied 10 cm voxels: {step_ms(sparse, a.repeat):8.0f} ms/step")
    for vs, shape in ((0.2, (96, 96, 20)), (0.1, (192, 192, 40))):
        net = DenseUNet()
        xin = torch.zeros(1, 12, *shape)

        def dense(net=net, xin=xin):
            net(xin).sum().backward()

        print(f"dense 3-D UNet, {vs * 100:.0f} cm voxels, grid {shape[0]}x{shape[1]}x{shape[2]} "
              f"(19.2 x 19.2 x {shape[2] * vs:.0f} m): {step_ms(dense, a.repeat):8.0f} ms/step")


if __name__ == "__main__":
    main()
