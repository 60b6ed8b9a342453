"""How well could any labelling of a model's point cloud detect a person seen only via walls?
An upper bound: each point of the model's cloud is labelled human exactly when it lies
within ``--radius`` of a ground-truth human point (oracle labels), then the clouds are scored as
evaluate scores human detection (:func:`holodata.metrics.human_centroids`: clusters of >= 5 points;
:func:`~holodata.metrics.human_detection_metrics`: matched within 0.5 m) on the frames whose person is
hidden (:func:`holodata.evaluate.pipeline.person_hidden`). Rows: the refined cloud, the un-refined
ray-traced cloud, and the model's own labels (what evaluate's ``human_hidden`` row scores).

    .venv/bin/python benchmarks/hidden_person.py DATASET [--checkpoint pretrained] [--radius 0.15,0.3]

When the oracle rows stay below a target, no human head or detector on that cloud can reach it: the
model's bounce-2/3 points do not fall on the hidden person. Measured numbers go to
benchmarks/results/nlos.md, not here.
"""
from __future__ import annotations

import argparse

import numpy as np
from _run import header


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--checkpoint", default="pretrained")
    ap.add_argument("--split", default="test")
    ap.add_argument("--radius", default="0.15,0.3", help="comma list of oracle radii (m)")
    a = ap.parse_args(argv)
    header()
    from scipy.spatial import cKDTree

    from holodata import metrics as M
    from holodata.conventions import is_human, reduced_grid
    from holodata.dataset import open_dataset
    from holodata.evaluate.pipeline import person_hidden
    from holodata.evaluate.predict import Predictor
    from holodata.scene_beams import SceneBeams
    from holodata.torch.data import HeatmapDataset, apply_transform
    from holodata.torch.pretrained import resolve

    ds = open_dataset(a.dataset)
    run = Predictor.load(resolve(a.checkpoint, ds.grid))
    if run.stage2 is None:
        raise SystemExit(f"{a.checkpoint}: no stage two next to the stage-one checkpoint")
    model_tf, base_tf = run.transforms()
    data = HeatmapDataset(a.dataset, split=a.split, norm=run.norm, transform=model_tf)
    grid = reduced_grid(ds.grid, run.downsample)
    radii = [float(r) for r in a.radius.split(",")]
    rows: dict = {}
    beams: dict = {}
    n_hidden = 0
    for i, (sid, k) in enumerate(data.index):
        raw = data.read(i)
        _, g_rng, g_lab = apply_transform(*raw, base_tf)
        if not person_hidden(g_lab):
            continue
        n_hidden += 1
        _, p_hum, p_cloud = run.ranges([raw[0]])
        if sid not in beams:
            beams[sid] = SceneBeams(ds.scene(sid), ds.grid)
        geo = beams[sid].frame(k, run.downsample)
        G = geo.gt_point
        Gh = G[np.isfinite(G).all(-1) & is_human(g_lab)]
        gc = M.human_centroids(Gh)
        s2 = run.stage2.predict(p_cloud[0], p_hum[0], geo.directions, geo.origins, grid)
        clouds = {"refined": s2["refined"] or s2["no_refine"], "no_refine": s2["no_refine"]}
        for name, cloud in clouds.items():
            P = np.asarray(cloud["point"]).reshape(-1, 3)
            P = P[np.isfinite(P).all(-1)]
            for r in radii:
                lab = cKDTree(Gh).query(P)[0] <= r if len(Gh) and len(P) else np.zeros(len(P), bool)
                rows.setdefault(f"{name}, oracle labels within {r * 100:.0f} cm", []).append((M.human_centroids(P[lab]), gc))
        own = clouds["refined"]
        pts, hum = np.asarray(own["point"]).reshape(-1, 3), np.asarray(own["human"]).reshape(-1)
        rows.setdefault("refined, the model's own labels", []).append((M.human_centroids(pts[hum]), gc))
    print(f"{a.dataset} split {a.split}: {n_hidden} frames with a hidden person; checkpoint {a.checkpoint}")
    print(f"  {'cloud and labels':40s} {'P':>5s} {'R':>5s} {'F':>6s}  tp / pred / GT centres")
    for name, pairs in rows.items():
        m = M.human_detection_metrics([p for p, _ in pairs], [g for _, g in pairs])
        print(f"  {name:40s} {m['precision']:5.2f} {m['recall']:5.2f} {m['f_score']:6.3f}  "
              f"{m['tp']} / {m['n_pred']} / {m['n_gt']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
