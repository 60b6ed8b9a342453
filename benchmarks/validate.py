"""Validate throughput vs plain zarr decompression of the same arrays, in the same run.

Builds one scene of realistic size (default 64 frames of gt/* at 64x512 and radar/heatmap with a
reduced range axis), then times (a) reading every frame array shard by shard with zarr (decode only)
and (b) ``validate_dataset`` (checksums + decode + all value rules). Prints MB/s of decompressed
data for both and the ratio validate/decompress (target <= 2).

    .venv/bin/python benchmarks/validate.py [--frames 64] [--grid 64x512] [--range-bins 64] [--out DIR]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--grid", default="64x512")
    ap.add_argument("--range-bins", type=int, default=64)
    ap.add_argument("--shard-frames", type=int, default=32)
    ap.add_argument("--codec", default="zstd")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", help="keep the dataset here (default: a temp dir)")
    a = ap.parse_args()

    from holodata.conventions import Grid
    from holodata.dataset import open_dataset
    from holodata.dataset.synthetic import write_toy_dataset
    from holodata.dataset.validate import validate_dataset

    tmp = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="holodata-bench-"))
    url = str(tmp / "bench.zarr")
    if Path(url).exists():
        shutil.rmtree(url)
    t0 = time.perf_counter()
    write_toy_dataset(url, n_frames=a.frames, grid=Grid.parse(a.grid), n_range=a.range_bins,
                      shard_frames=a.shard_frames, scenes=("bench",), codec=a.codec, lidar=False)
    print(f"wrote {url} ({a.frames} frames, grid {a.grid}, {a.range_bins} range bins) in {time.perf_counter() - t0:.1f} s")

    s = open_dataset(url).scene("bench")
    names = [n for n in s.arrays() if s.nodes()[n][0] == "frame"]

    def decompress() -> int:
        n = 0
        for name in names:
            z = s[name]
            S = z.shards[0]
            for i in range(0, z.shape[0], S):
                n += np.asarray(z[i:i + S]).nbytes
        return n

    best_d = best_v = float("inf")
    nbytes = vbytes = 0
    for _ in range(a.repeat):
        t = time.perf_counter()
        nbytes = decompress()
        best_d = min(best_d, time.perf_counter() - t)
        t = time.perf_counter()
        rep = validate_dataset(url)
        best_v = min(best_v, time.perf_counter() - t)
        assert rep["ok"], rep["problems"][:3]
        vbytes = rep["bytes_decoded"]
    mb = nbytes / 1e6
    print(f"arrays: {', '.join(names)}; {mb:.1f} MB decompressed, {rep['bytes_stored'] / 1e6:.1f} MB stored")
    print(f"zarr decompress only : {best_d:.3f} s  {mb / best_d:8.1f} MB/s")
    print(f"holodata validate    : {best_v:.3f} s  {vbytes / 1e6 / best_v:8.1f} MB/s  "
          f"(checksums + decode + value rules)")
    print(f"ratio validate/decompress: {best_v / best_d:.2f}  (target <= 2)")
    if not a.out:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
