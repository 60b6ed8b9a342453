"""Who labels the hidden person? Human labellers of one stage-one model's analytic cloud, side by side.

Stage one's ranges of every frame of DATASET's ``--split`` (its range images, before the confidence gate
a calibrated stage two applies: the gate drops most of a hidden person's weak returns) are un-mirrored
analytically (:func:`holodata.geometry.unmirror.unmirror`, eq. 2-5) and each point is labelled human by:

- ``oracle r=R``: exactly when it lies within R m of a ground-truth human point (an upper bound: no
  labeller of this cloud does better; :mod:`benchmarks.hidden_person` computes it on stage two's cloud);
- ``stage one p_hum >= t``: the model's own per-beam human head;
- ``motion >= t dB``: a bounce-2/3 point whose heatmap bin (±1) changed by at least t dB from the
  neighbouring rotation of the same corner (the previous one; the next for a corner's first), where the
  bin stands > 15 dB above its beam's median (clutter removal across rotations, no ego-motion
  compensation; a person standing still gives no cue);
- ``motion cue``: ``holodata evaluate --motion-cue``'s moving person alone
  (:func:`holodata.evaluate.motion.moving_person`: the same returns clustered, the strongest cluster of
  changed and moved returns, at most one per frame; its settings, no threshold swept);
- ``3-D MLP >= t``: a small MLP over each point's 3-D neighbourhood (16 nearest: spacing, PCA
  planarity/linearity), its height, bounce, p_hum, amplitude, motion and persistence (distance to the
  neighbouring rotation's cloud in the world frame), trained on the first half of the
  corners (label: within 0.15 m of a GT human point) and scored on the second half;
- ``3-D MLP top-k`` (with ``--train-on CORPUS``): the same MLP trained on every frame of another
  corpus (its ``--train-split``; a seed neither stage one nor DATASET came from: no half is spent on
  training), read as a detector: the points at probability >= 0.95 clustered, the ``k`` clusters of
  largest summed probability kept when that sum reaches ``t``; also joined with the motion cue's
  centre (:func:`holodata.evaluate.motion.merge_centres`).

Each row is scored as ``holodata evaluate`` scores human detection (clusters of >= 5 points,
:func:`holodata.metrics.human_centroids`; matched within 0.5 m, :func:`holodata.metrics.human_detection_metrics`)
over all frames and over the frames whose person is hidden (:func:`holodata.evaluate.pipeline.person_hidden`),
at the threshold that scores best on the frames it is reported on (an optimistic choice for every
row but the oracle, which has none). A development tool: run it on a corpus you tune on
(e.g. ``holodata synth --corners 24 --frames 2 --grid 64x512 --test 24 --seed 500 --heatmap-dtype uint8``),
never on the held-out report set.

    .venv/bin/python benchmarks/hidden_person_labels.py DATASET --checkpoint RUN [--split test]
        [--train-on CORPUS --train-split train]

Measured numbers go to benchmarks/results/hidden-person.md, not here.
"""
from __future__ import annotations

import argparse

import numpy as np
from _run import header

NEIGHBOURS = 16            # the 3-D labeller's neighbourhood
ORACLE_RADII = (0.15, 0.3)


def frame_records(dataset: str, checkpoint: str, split: str) -> list[dict]:
    """Per frame: the analytic cloud of stage one's range images ``P`` (M,3) and in the world frame
    ``world``, each point's bounce, p_hum, amplitude (dB over its beam's median) and motion (dB change
    to the neighbouring rotation, :func:`holodata.evaluate.motion.change_at_returns`) at its range bin,
    the GT human points ``gh`` and centres ``gt``, and whether the person is hidden."""
    from holodata import metrics as M
    from holodata.conventions import is_human, reduced_grid
    from holodata.dataset import open_dataset
    from holodata.dataset.heatmap import read_heatmap
    from holodata.evaluate.motion import MotionCue, change_at_returns, heatmap_db
    from holodata.evaluate.pipeline import person_hidden
    from holodata.evaluate.predict import Predictor
    from holodata.geometry.unmirror import unmirror
    from holodata.scene_beams import SceneBeams
    from holodata.torch.data import HeatmapDataset, apply_transform

    run = Predictor.load(checkpoint)
    ds = open_dataset(dataset)
    rb = ds.range_bins
    model_tf, base_tf = run.transforms()
    data = HeatmapDataset(dataset, split=split, norm=run.norm, transform=model_tf)
    grid = reduced_grid(ds.grid, run.downsample)
    beams, out = {}, []
    for i, (sid, k) in enumerate(data.index):
        sc = ds.scene(sid)
        raw = data.read(i)
        _, _, g_lab = apply_transform(*raw, base_tf)
        p_cloud, p_hum, _ = (a[0] for a in run.ranges([raw[0]]))   # the range images: no confidence gate
        if sid not in beams:
            beams[sid] = SceneBeams(sc, ds.grid)
        geo = beams[sid].frame(k, run.downsample)
        G = geo.gt_point
        gh = G[is_human(g_lab) & np.isfinite(G).all(-1)]
        other = k - 1 if k > 0 else min(k + 1, sc.n_frames - 1)
        L0 = heatmap_db(read_heatmap(sc, k))
        change = change_at_returns(L0, heatmap_db(read_heatmap(sc, other)), p_cloud, rb.dr, MotionCue().min_snr_db)
        snr = L0 - np.median(L0, axis=0, keepdims=True)
        P = unmirror(p_cloud, geo.directions, grid=grid, origins=geo.origins)["point"]
        ok = np.isfinite(P).all(-1)
        b, e, a = np.nonzero(ok)
        ri = np.clip(rb.index(p_cloud[b, e, a]), 0, L0.shape[0] - 1)
        out.append({"corner": sid, "frame": k, "P": P[ok], "world": geo.to_world(P[ok]), "bounce": b,
                    "p_hum": p_hum[ok], "amp": snr[ri, e, a], "motion": change[ok],
                    "gh": gh, "gt": M.human_centroids(gh), "hidden": person_hidden(g_lab)})
    add_persistence(out)
    return out


def add_persistence(recs: list[dict]) -> None:
    """Each point's distance (m, capped at 1) to the nearest point of the neighbouring rotation's cloud of
    the same corner, both in the world frame (:func:`holodata.evaluate.motion.persistence`): walls
    persist, a walking person moves, a wrongly placed return rarely lands twice in the same place."""
    from holodata.evaluate.motion import persistence

    by = {(r["corner"], r["frame"]): r for r in recs}
    for (c, k), r in by.items():
        other = next((by[o] for o in ((c, k - 1), (c, k + 1)) if o in by), None)
        r["persist"] = persistence(r["world"], np.zeros((0, 3)) if other is None else other["world"], cap=1.0)


def detection(recs: list[dict], labels: list[np.ndarray], centres: list[np.ndarray] | None = None) -> tuple[dict, dict]:
    """(all frames, hidden-person frames) detection metrics of the human-labelled points (or of
    ``centres`` per frame when given)."""
    from holodata import metrics as M

    pred = centres if centres is not None else [M.human_centroids(r["P"][lab]) for r, lab in zip(recs, labels)]
    hid = [i for i, r in enumerate(recs) if r["hidden"]]
    return (M.human_detection_metrics(pred, [r["gt"] for r in recs]),
            M.human_detection_metrics([pred[i] for i in hid], [recs[i]["gt"] for i in hid]))


def near_gt(r: dict, radius: float) -> np.ndarray:
    """Points of ``r``'s cloud within ``radius`` m of a GT human point."""
    from scipy.spatial import cKDTree

    if not len(r["gh"]) or not len(r["P"]):
        return np.zeros(len(r["P"]), bool)
    return np.isfinite(cKDTree(r["gh"]).query(r["P"], distance_upper_bound=radius)[0])


def point_features(r: dict) -> np.ndarray:
    """(M, 15) per-point features of the 3-D labeller (see the module docstring)."""
    from scipy.spatial import cKDTree

    P = np.asarray(r["P"], np.float64)
    tree = cKDTree(P)
    d, j = tree.query(P, k=min(NEIGHBOURS, len(P)))
    Q = P[j] - P[j].mean(1, keepdims=True)
    w = np.maximum(np.linalg.eigvalsh(np.einsum("nki,nkj->nij", Q, Q) / Q.shape[1]), 1e-9)
    dense = tree.query_ball_point(P, 0.3, return_length=True)
    return np.c_[np.log(d[:, 1:4].mean(1) + 1e-3), np.log(d[:, -1] + 1e-3), np.log(w[:, 0] / w[:, 2]),
                 np.log(w[:, 1] / w[:, 2]), np.sqrt(w[:, 2]), P[:, 2] - np.quantile(P[:, 2], 0.02),
                 np.eye(3)[r["bounce"]], r["p_hum"], r["amp"] / 20, r["motion"] / 20, np.log(dense + 1),
                 np.linalg.norm(P[:, :2], axis=1) / 10, r["persist"]].astype(np.float32)


def features(r: dict) -> np.ndarray:
    """:func:`point_features` of record ``r``, computed once and kept in it (each MLP row reads them)."""
    if "features" not in r:
        r["features"] = point_features(r)
    return r["features"]


def mlp_probabilities(train: list[dict], test: list[dict], epochs: int = 8, seed: int = 0,
                      neg_keep: float = 1.0, hidden_weight: float = 1.0, pos_weight: float = 10.0) -> list[np.ndarray]:
    """The 3-D labeller trained on ``train``'s points (label: within 0.15 m of a GT human point,
    positives weighted ×``pos_weight``, ×``hidden_weight`` more in frames whose person is hidden; a random
    ``neg_keep`` share of the negatives kept); its human probability of every point of ``test``."""
    import torch
    from torch import nn

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    Xs, Ys, Ws = [], [], []
    for r in train:
        y = near_gt(r, 0.15)
        keep = y | (rng.random(len(y)) < neg_keep)
        Xs.append(features(r)[keep])
        Ys.append(y[keep])
        Ws.append(np.where(y[keep], pos_weight * (hidden_weight if r["hidden"] else 1.0), 1.0))
    X = torch.from_numpy(np.concatenate(Xs))
    Y = torch.from_numpy(np.concatenate(Ys).astype(np.float32))
    W = torch.from_numpy(np.concatenate(Ws).astype(np.float32))
    mu, sd = X.mean(0), X.std(0) + 1e-6
    net = nn.Sequential(nn.Linear(X.shape[1], 64), nn.SiLU(), nn.Linear(64, 64), nn.SiLU(), nn.Linear(64, 1))
    opt = torch.optim.AdamW(net.parameters(), 2e-3)
    for _ in range(epochs):
        for idx in torch.randperm(len(X)).split(4096):
            loss = (nn.functional.binary_cross_entropy_with_logits(net((X[idx] - mu) / sd)[:, 0], Y[idx],
                                                                   reduction="none") * W[idx]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        return [torch.sigmoid(net((torch.from_numpy(features(r)) - mu) / sd))[:, 0].numpy() for r in test]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--train-on", help="another corpus the 3-D MLP detector trains on (every frame of --train-split)")
    ap.add_argument("--train-split", default="train")
    a = ap.parse_args(argv)
    header()
    recs = frame_records(a.dataset, a.checkpoint, a.split)
    corners = sorted({r["corner"] for r in recs})
    first = set(corners[:len(corners) // 2])
    train = [r for r in recs if r["corner"] in first]
    test = [r for r in recs if r["corner"] not in first]
    print(f"{len(recs)} frames of {len(corners)} corners, {sum(r['hidden'] for r in recs)} with a hidden person; "
          f"the 3-D labeller trains on {len(train)} frames ({len(first)} corners) and is scored on the other "
          f"{len(test)} ({sum(r['hidden'] for r in test)} hidden)")
    print("  labeller                            frames   all frames P / R / F %      hidden person P / R / F %, loc median cm")

    def row(name: str, rs: list[dict], labels_at, thresholds, centres=None) -> None:
        best = None
        for t in thresholds:
            m_all, m_hid = detection(rs, None if centres is not None else labels_at(t), centres)
            key = (np.nan_to_num(m_hid["f_score"]), np.nan_to_num(m_all["f_score"]))
            if best is None or key > best[0]:
                best = (key, t, m_all, m_hid)
        _, t, m_all, m_hid = best
        pct = lambda m: " / ".join(f"{100 * np.nan_to_num(m[k]):5.1f}" for k in ("precision", "recall", "f_score"))  # noqa: E731
        loc = m_hid.get("loc_median_cm")
        print(f"  {name + ('' if t is None else f' (t={t:g})'):<36}{len(rs):5d}    {pct(m_all)}      {pct(m_hid)}, "
              f"{'–' if loc is None or loc != loc else f'{loc:.1f}'}")

    for rad in ORACLE_RADII:
        row(f"oracle r={rad:g} m", recs, lambda t, rad=rad: [near_gt(r, rad) for r in recs], [None])
    for rs, part in ((recs, "all"), (test, "2nd half")):
        row(f"stage one p_hum [{part}]", rs, lambda t, rs=rs: [r["p_hum"] >= t for r in rs], (0.1, 0.2, 0.3, 0.4, 0.5))
        row(f"motion [{part}]", rs, lambda t, rs=rs: [(r["motion"] >= t) & (r["bounce"] > 0) for r in rs], (10, 15, 20, 25, 30))
    from holodata.evaluate.motion import MotionCue, moving_person

    cue = MotionCue()
    cues = [moving_person(r["P"][r["bounce"] > 0], r["motion"][r["bounce"] > 0],
                          np.minimum(r["persist"][r["bounce"] > 0], cue.persist_cap_m), cue) for r in recs]
    row("motion cue [all]", recs, None, [None], centres=cues)
    row("motion cue [2nd half]", test, None, [None], centres=[c for c, r in zip(cues, recs) if r["corner"] not in first])
    probs = mlp_probabilities(train, test)
    row("3-D MLP [2nd half]", test, lambda t: [p >= t for p in probs], (0.5, 0.8, 0.9, 0.95, 0.98))
    if a.train_on:
        other = frame_records(a.train_on, a.checkpoint, a.train_split)
        probs = mlp_probabilities(other, recs, epochs=6, neg_keep=0.2, hidden_weight=3.0, pos_weight=5.0)
        from holodata.evaluate.motion import merge_centres
        from holodata.metrics import strongest_clusters

        for k in (1, 2):
            for t in (10, 20, 40):   # the points at probability >= 0.95, the k clusters of largest summed probability
                cen = [strongest_clusters(r["P"][p >= 0.95], p[p >= 0.95], k, t) for r, p in zip(recs, probs)]
                row(f"3-D MLP top-{k} (t={t:g}) [all]", recs, None, [None], centres=cen)
                row("  + motion cue", recs, None, [None], centres=[merge_centres(c, q) for c, q in zip(cen, cues)])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
