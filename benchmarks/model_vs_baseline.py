"""Trained model vs the strongest-peaks baseline on synthetic corners (holodata.synth radar model,
ray-traced multi-bounce GT), end to end through a holodata dataset, train and evaluate.

    .venv/bin/python benchmarks/model_vs_baseline.py [--grid 32x128] [--frames 12] [--epochs 30] [--out DIR]

Scenes: one per corner type (T, L, cross, oblique), different seeds; the last one is the test
split. Heatmaps come from holodata.synth.scenario.Sensors.radar_frame (per-column poses of the
moving robot); GT is traced along exactly those beams (world frame, with the walking human).
Prints both tables of holodata evaluate.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from _run import header

from holodata.conventions import Grid, RangeBins
from holodata.dataset import create_dataset

CORNERS = [("T", 11), ("L", 12), ("cross", 13), ("oblique", 14), ("T", 15), ("L", 16)]


def trace_with_human(sc, O, D, B, max_range, t_ns):
    """Trace through world + human merged into one static scene (RayScene's dynamic= path raised
    IndexError when the human had more faces than the world), relabelling human hits 1→3, 2→4."""
    from holodata.raytrace import RayScene

    wv, wf = sc.world.vertices, sc.world.faces
    hm = sc.human_mesh(t_ns)
    if hm is None:
        return RayScene(wv, wf).trace(O, D, max_bounces=B, max_range=max_range)
    hv, hf = hm
    res = RayScene(np.concatenate([wv, hv]), np.concatenate([wf, np.asarray(hf) + len(wv)])).trace(
        O, D, max_bounces=B, max_range=max_range)
    human = res.face >= len(wf)
    res.label = np.where(human & (res.label > 0), res.label + 2, res.label).astype(np.uint8)
    return res


def build(url: str, grid: Grid, bins: RangeBins, frames: int, corners) -> list[str]:
    from holodata.synth.scenario import SceneSpec, Sensors, build_scenario

    w = create_dataset(url, grid=grid, range_bins=bins, created_by="benchmarks/model_vs_baseline.py", shard_frames=frames)
    ids = []
    B, H, W = 3, grid.H, grid.W
    for corner, seed in corners:
        sc = build_scenario(SceneSpec(corner, frames=frames, seed=seed, grid=grid, range_bins=bins, lidar_shape=(8, 64),
                                      camera_shape=(24, 32)))
        sens = Sensors(sc)
        sid = f"{corner}_{seed}"
        ids.append(sid)
        scene = w.scene(sid, n_frames=frames, attrs=sc.world.describe())
        out = {k: [] for k in ("radar/heatmap", "gt/range", "gt/normal", "gt/point", "gt/label", "pose/T_world_radar")}
        for k in range(frames):
            hm, _ = sens.radar_frame(k)
            start, end = sc.radar_cycle(k)
            t_cols = start + np.round((np.arange(W) + 0.5) / W * (end - start)).astype(np.int64)
            T_cols = sc.truth.interpolate(t_cols) @ sc.T_base_radar
            D = np.einsum("wij,hwj->hwi", T_cols[:, :3, :3], grid.directions()).reshape(-1, 3)
            O = np.broadcast_to(T_cols[None, :, :3, 3], (H, W, 3)).reshape(-1, 3)
            res = trace_with_human(sc, O, D, B, bins.max_range, (start + end) // 2)
            out["radar/heatmap"].append(hm.astype(np.float16))
            out["gt/range"].append(res.range.T.reshape(B, H, W))
            out["gt/normal"].append(res.normal.transpose(1, 0, 2).reshape(B, H, W, 3))
            out["gt/point"].append(res.point.transpose(1, 0, 2).reshape(B, H, W, 3))
            out["gt/label"].append(res.label.T.reshape(B, H, W))
            out["pose/T_world_radar"].append(T_cols[W // 2])
        specs = {
            "radar/heatmap": ((bins.n, H, W), "float16", ["frame", "range", "elevation", "azimuth"], "1", 0.0),
            "gt/range": ((B, H, W), "float32", ["frame", "bounce", "elevation", "azimuth"], "m", float("nan")),
            "gt/normal": ((B, H, W, 3), "float32", ["frame", "bounce", "elevation", "azimuth", "xyz"], "1", float("nan")),
            "gt/point": ((B, H, W, 3), "float32", ["frame", "bounce", "elevation", "azimuth", "xyz"], "m", float("nan")),
            "gt/label": ((B, H, W), "uint8", ["frame", "bounce", "elevation", "azimuth"], "1", 0),
            "pose/T_world_radar": ((4, 4), "float64", ["frame", "row", "col"], "1", float("nan")),
        }
        for name, (shape, dt, dims, units, fill) in specs.items():
            arr = scene.frame_array(name, shape, dt, dims, units, fill)
            for s in range(arr.n_shards):
                arr.write_shard(s, np.stack(out[name][arr.frames(s)]).astype(dt))
    w.set_splits(train=ids[:-1], test=ids[-1:])
    return ids


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--grid", default="32x128")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--scenes", type=int, default=5)
    ap.add_argument("--out", default=None)
    ap.add_argument("--head", default="softargmax", choices=["softargmax", "regress"])
    a = ap.parse_args()
    header()
    grid = Grid.parse(a.grid)
    bins = RangeBins()
    out = Path(a.out or tempfile.mkdtemp(prefix="holodata-mvb-"))
    url = str(out / "dataset.zarr")
    t0 = time.perf_counter()
    if not Path(url).exists():
        build(url, grid, bins, a.frames, CORNERS[: a.scenes])
    t1 = time.perf_counter()
    from holodata.evaluate import Evaluation, format_tables
    from holodata.torch import TrainConfig, train

    depth = min(7, int(np.log2(min(grid.H, grid.W))) + 1)
    run = out / f"run_{a.head}"
    res = train(url, run, TrainConfig(epochs=a.epochs, depth=depth, batch_size=4, head=a.head), quiet=True)
    t2 = time.perf_counter()
    doc = Evaluation(url, run, out / f"report_{a.head}", quiet=True).run()
    t3 = time.perf_counter()
    print(f"dataset {t1 - t0:.0f} s, train {t2 - t1:.0f} s ({a.epochs} epochs, loss {res.history[0]['loss']:.3f} → "
          f"{res.final_loss:.3f}), evaluate {t3 - t2:.0f} s; report {out / f'report_{a.head}' / 'report.html'}")
    print(format_tables(doc))


if __name__ == "__main__":
    main()
