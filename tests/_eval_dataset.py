"""A tiny traced dataset for the evaluate / HeatmapDataset tests (not a test module).

Box rooms of different sizes (one scene each) with a box "human"; ground truth from
holodata.raytrace; heatmaps = a Gaussian bump at each GT range bin (weaker per bounce) + noise.
"""
import numpy as np

from holodata.beams import OriginModel
from holodata.conventions import Grid, RangeBins
from holodata.dataset import create_dataset
from holodata.raytrace import RayScene

GRID = Grid(16, 64)
BINS = RangeBins(32, 0.3)


def box(lo, hi):
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    V = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    return V, F


def heatmap_from_gt(R, rng, noise=0.02):
    """(B,H,W) ranges → (N_r,H,W) linear amplitude."""
    c = BINS.centres()[:, None, None]
    hm = noise * rng.random((BINS.n,) + R.shape[1:])
    for b, a in enumerate((1.0, 0.3, 0.1)):
        r = np.nan_to_num(R[b], nan=-100.0)
        hm += a * np.exp(-0.5 * ((c - r[None]) / BINS.dr) ** 2)
    return hm.astype(np.float32)


SCENES = [("room_a", "T", 1.2, 2.0), ("room_b", "L", 2.0, 2.6), ("room_c", "cross", 3.5, 3.0)]


def build(url, frames=4, seed=0):
    rng = np.random.default_rng(seed)
    w = create_dataset(url, grid=GRID, range_bins=BINS, created_by="holodata tests", shard_frames=2)
    d = GRID.directions().reshape(-1, 3)
    B, H, W = 3, GRID.H, GRID.W
    for sid, corner, width, half in SCENES:
        V, F = box((-half, -width, -1.0), (half + 1.0, width, 1.5))
        scene = RayScene(V, F)
        sc = w.scene(sid, n_frames=frames, attrs={"corner_type": corner, "width_m": width,
                                                  "gt": {"origin_model": OriginModel(column_time=False).to_attrs()}})
        arrs = {
            "gt/range": sc.frame_array("gt/range", (B, H, W), "float32", ["frame", "bounce", "elevation", "azimuth"], "m",
                                       float("nan")),
            "gt/normal": sc.frame_array("gt/normal", (B, H, W, 3), "float32",
                                        ["frame", "bounce", "elevation", "azimuth", "xyz"], "1", float("nan")),
            "gt/point": sc.frame_array("gt/point", (B, H, W, 3), "float32", ["frame", "bounce", "elevation", "azimuth", "xyz"],
                                       "m", float("nan")),
            "gt/label": sc.frame_array("gt/label", (B, H, W), "uint8", ["frame", "bounce", "elevation", "azimuth"], "1", 0),
            "pose/T_world_radar": sc.frame_array("pose/T_world_radar", (4, 4), "float64", ["frame", "row", "col"], "1",
                                                 float("nan")),
            "radar/heatmap": sc.frame_array("radar/heatmap", (BINS.n, H, W), "float32",
                                            ["frame", "range", "elevation", "azimuth"], "1", 0.0),
        }
        out = {k: [] for k in arrs}
        for t in range(frames):
            c = np.array([half * 0.5, width * 0.5 * (1 - 2 * (t % 2)), 0.0]) + rng.uniform(-0.2, 0.2, 3)
            hv, hf = box(c - [0.2, 0.2, 1.0], c + [0.2, 0.2, 0.8])
            # the radar sits at o with a yaw: GT normals/points are in the world frame (docs/format.md §3)
            yaw, o = 0.3 * t, np.array([0.1 * t, -0.05 * t, 0.0])
            T = np.eye(4)
            T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
            T[:3, 3] = o
            out["pose/T_world_radar"].append(T)
            dw = d @ T[:3, :3].T
            res = scene.trace(np.broadcast_to(o, dw.shape), dw, max_bounces=B, max_range=BINS.max_range, dynamic=(hv, hf))
            R = res.range.T.reshape(B, H, W).astype(np.float32)
            out["gt/range"].append(R)
            out["gt/normal"].append(res.normal.transpose(1, 0, 2).reshape(B, H, W, 3).astype(np.float32))
            out["gt/point"].append(res.point.transpose(1, 0, 2).reshape(B, H, W, 3).astype(np.float32))
            out["gt/label"].append(res.label.T.reshape(B, H, W).astype(np.uint8))
            out["radar/heatmap"].append(heatmap_from_gt(R, rng))
        for name, arr in arrs.items():
            for k in range(arr.n_shards):
                arr.write_shard(k, np.stack(out[name][arr.frames(k)]))
    w.set_splits(train=["room_a", "room_b"], test=["room_c"])
    return url
