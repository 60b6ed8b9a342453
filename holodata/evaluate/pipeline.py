"""``holodata evaluate``: run a trained checkpoint and the non-learned baseline over a split,
score both with the paper's metrics (holodata.metrics), write metrics.json (validated against
schemas/metrics.schema.json), PNG figures and report.html.

Point clouds live in the radar frame of each frame's pose, and every beam starts where the ground
truth was traced from (the scene's beam-origin model, :mod:`holodata.scene_beams`): predicted
range images are un-mirrored from those origins along those directions with normals estimated
from the predicted images (paper eq. 2–5, no learning); ground-truth clouds are the traced points
(gt/point moved into the radar frame with pose/T_world_radar; without them, the GT ranges
un-mirrored with the GT normals). GT LOS/NLOS comes from ``gt/label``; a predicted point is LOS
when the predicted first-bounce image shows free space up to it
(:func:`holodata.geometry.unmirror.los_mask`). Human centroids are clusters of human-labelled
points, the same procedure for prediction and GT. ``oracle`` runs score the ground truth itself
(GT ranges, GT normals, GT labels) through the same un-mirroring: a perfect prediction, which
must score perfectly.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from holodata import metrics as M
from holodata.conventions import Grid, RangeBins, is_human, is_los, reduced_grid
from holodata.ownership import claim_folder
from holodata.progress import track

from .baseline import strongest_peaks
from holodata.scene_beams import FrameGeometry, SceneBeams
from holodata.geometry.unmirror import los_mask, unmirror

METHODS = ("model", "baseline")
# Table-2 rows when the run has a learned stage two (RUN/stage2.pt): the refined model, the model's
# ray-traced points before refinement, today's analytic stage two on the model's ranges, the
# baseline, and the GT range images through the trained stage two (stage-one error removed)
STAGE2_ROWS = ("model", "model_no_refine", "model_analytic", "baseline", "oracle_stage1")
ERR_SAMPLE = 200_000  # errors kept per bounce for the CDF figure
REPORT_FRAMES = 6       # held-out frames drawn one large picture each in the report (the hidden side)
REPORT_POINTS = 6000    # points kept per cloud part for those pictures


@dataclass
class _Acc:
    """Running sums of one method."""

    errors: list = field(default_factory=lambda: [[], [], []])
    n_fin: list = field(default_factory=lambda: [0, 0, 0])
    cloud: dict = field(default_factory=lambda: {"los": [], "nlos": []})
    curve: dict = field(default_factory=lambda: {"los": [], "nlos": []})
    pred_centres: list = field(default_factory=list)
    per_scene: dict = field(default_factory=dict)


def _clouds(points, los):
    ok = np.isfinite(points).all(-1)
    return {"los": points[ok & los], "nlos": points[ok & ~los]}


def _human_points(points, human):
    ok = np.isfinite(points).all(-1) & human
    return points[ok]


def person_hidden(label) -> bool:
    """Whether a frame's person is hidden: ``label`` (3,H,W) GT labels hold human returns and none
    of them is line-of-sight (the person is seen only through bounces 2-3, the case NLOS imaging is for)."""
    hum = is_human(label)
    return bool(hum.any() and not (hum & is_los(label)).any())


def _score_ranges(acc: _Acc, row: dict, pred_range, gt_range) -> None:
    for b in range(3):
        e = M.range_errors(pred_range[b], gt_range[b])
        acc.errors[b].append(e)
        row["errors"][b].append(e)
        acc.n_fin[b] += int(np.isfinite(pred_range[b][np.isfinite(gt_range[b])]).sum())


def _score_clouds(acc: _Acc, row: dict, pc: dict, human_points, gt_clouds, tau: float, taus) -> None:
    for part in ("los", "nlos"):
        d_pg, d_gp = M.nn_distances(pc[part], gt_clouds[part])
        m = M._cloud_summary(d_pg, d_gp, tau)
        acc.cloud[part].append(m)
        row["cloud"][part].append(m)
        acc.curve[part].append(M.prf_curve_from_distances(d_pg, d_gp, taus))
    acc.pred_centres.append(M.human_centroids(human_points))


def _scene_row(acc: _Acc, scene: str) -> dict:
    return acc.per_scene.setdefault(scene, {"errors": [[], [], []], "cloud": {"los": [], "nlos": []}})


def score_frame(acc: _Acc, scene: str, pred_range, pred_human, gt_range, gt_clouds, grid: Grid,
                tau: float, taus, max_range: float, geo: FrameGeometry, normals=None, los=None,
                cloud_range=None) -> dict:
    """Add one frame's prediction (3,H,W) range (+ (3,H,W) human prob or None) to ``acc``; its beams
    start at ``geo.origins`` along ``geo.directions``. ``normals`` (3,H,W,3) / ``los`` (3,H,W) bool
    override the estimated ones (oracle runs); ``cloud_range`` (3,H,W): the ranges to un-mirror into
    the point cloud when they differ from the scored range images (``Predictor.ranges``' gate)."""
    row = _scene_row(acc, scene)
    _score_ranges(acc, row, pred_range, gt_range)
    cloud_range = pred_range if cloud_range is None else cloud_range
    P = unmirror(cloud_range, geo.directions, normals=normals, grid=grid, origins=geo.origins)["point"]
    if los is None:
        los = los_mask(P, cloud_range[0], grid, origins=geo.origins)
    pc = _clouds(P, los)
    hum = np.zeros(P.shape[:-1], bool) if pred_human is None else (pred_human >= 0.5)
    _score_clouds(acc, row, pc, _human_points(P, hum), gt_clouds, tau, taus)
    return pc


def score_points(acc: _Acc, scene: str, pred: dict, pred_range, gt_range, gt_clouds, tau: float, taus) -> dict:
    """Add one frame of stage-two output to ``acc``: ``pred`` {point (…,3), los (…) bool, human (…)
    bool} (a refined cloud or ray-traced point images), scored against ``gt_clouds``; range
    errors are those of ``pred_range`` (3,H,W), the range images stage two was given."""
    row = _scene_row(acc, scene)
    _score_ranges(acc, row, pred_range, gt_range)
    P = np.asarray(pred["point"], np.float64)
    pc = _clouds(P, np.asarray(pred["los"], bool))
    _score_clouds(acc, row, pc, _human_points(P, np.asarray(pred["human"], bool)), gt_clouds, tau, taus)
    return pc


def _mean_curve(curves: list) -> dict:
    if not curves:
        return {"tau": [], "precision": [], "recall": [], "f_score": []}
    out = {"tau": curves[0]["tau"]}
    for k in ("precision", "recall", "f_score"):
        out[k] = [float(v) for v in np.mean([c[k] for c in curves], axis=0)]
    return out


def summarise(acc: _Acc, gt_centres: list, scene_info: dict, max_range: float, hidden=None) -> dict:
    """One method's metrics document; ``hidden`` (one bool per frame, :func:`person_hidden`) selects
    the frames scored again as ``human_hidden`` (None: no frame)."""
    hid = [False] * len(gt_centres) if hidden is None else list(hidden)
    rng = {}
    for b in range(3):
        e = np.concatenate(acc.errors[b]) if acc.errors[b] else np.zeros(0)
        rng[f"bounce_{b + 1}"] = M.range_metrics_from_errors(e, max_range, n_pred_finite=acc.n_fin[b])
    per_scene = []
    for sid, r in acc.per_scene.items():
        nl = M.mean_cloud_metrics(r["cloud"]["nlos"])
        lo = M.mean_cloud_metrics(r["cloud"]["los"])
        per_scene.append({
            "scene": sid, "n_frames": nl["n_frames"], "bands": scene_info[sid]["bands"],
            "attenuation_db": scene_info[sid]["attenuation_db"],
            "range_mean_cm": [M.range_metrics_from_errors(np.concatenate(r["errors"][b]),
                                                          max_range)["mean_cm"] for b in range(3)],
            "cd": nl["cd"], "mhd": nl["mhd"], "f_score": nl["f_score"],
            "los_cd": lo["cd"], "los_f_score": lo["f_score"],
        })
    return {
        "range": rng,
        "points": {p: M.mean_cloud_metrics(acc.cloud[p]) for p in ("los", "nlos")},
        "prf_curve": {p: _mean_curve(acc.curve[p]) for p in ("los", "nlos")},
        "human": M.human_detection_metrics(acc.pred_centres, gt_centres),
        "human_hidden": M.human_detection_metrics([c for c, h in zip(acc.pred_centres, hid) if h],
                                                  [c for c, h in zip(gt_centres, hid) if h]),
        "breakdown": M.breakdown(per_scene, keys=("cd", "mhd", "f_score")),
        "per_scene": per_scene,
    }


def jsonable(x):
    """NaN/inf → None, numpy → Python, recursively."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    return x


def load_schema() -> dict:
    from importlib.resources import files

    return json.loads(files("holodata.schemas").joinpath("metrics.schema.json").read_text())


def validate_metrics(doc: dict) -> None:
    import jsonschema

    jsonschema.validate(doc, load_schema())


def evaluate(dataset_url, checkpoint, out_dir, split: str = "test", *, device: str = "cpu",
             batch_size: int = 4, tau: float = M.DEFAULT_TAU_M, taus=M.DEFAULT_TAUS_M,
             max_frames: int | None = None, quiet: bool = False, report: bool = True,
             oracle: bool = False, estimator: str | None = None) -> dict:
    """Evaluate ``checkpoint`` (file or run directory) and the strongest-peaks baseline on the
    ``split`` scenes of the dataset at ``dataset_url``; write ``out_dir``/metrics.json (+ figures
    and report.html when ``report``). Returns the metrics document (the same dict as the JSON).

    ``oracle=True`` scores the ground truth itself (ranges, normals, labels) as the "model"
    (``checkpoint`` may then be None): a check of the metric plumbing, which must give perfect
    scores. ``estimator``: the model's point estimate per beam ("mean", "median", "mode"; see
    :meth:`holodata.torch.model.MultiReturnUNet.predict`; None: the one the checkpoint was trained for)."""
    from holodata.dataset import open_dataset
    from holodata.torch.data import HeatmapDataset, apply_transform

    from .predict import Predictor

    from holodata.torch.pretrained import resolve

    checkpoint = None if oracle else resolve(checkpoint)
    out = Path(out_dir)
    claim_folder(out, "holodata evaluate")   # a new or empty folder, or a report holodata wrote
    run = Predictor.load(checkpoint, device=device, estimator=estimator, oracle=oracle)
    model, stage2, ck, ck2 = run.model, run.stage2, run.checkpoint, run.stage2_checkpoint
    rows = STAGE2_ROWS if stage2 is not None else METHODS
    norm = run.norm
    f = run.downsample
    model_tf, base_tf = run.transforms()
    ds = open_dataset(str(dataset_url))
    if not oracle:
        from holodata.torch.train import check_stage1

        check_stage1(ck, ds, checkpoint)
    data = HeatmapDataset(str(dataset_url), split=split, norm=norm, transform=model_tf)
    grid = reduced_grid(ds.grid, f)
    rb: RangeBins = ds.range_bins
    max_range = float(rb.max_range)
    index = data.index[:max_frames] if max_frames else data.index
    accs = {m: _Acc() for m in rows}
    gt_centres, hidden, scene_info, beams, gt_nlos_points = [], [], {}, {}, []
    example = None
    ex_pick = len(index) // 2
    # the report's hidden-side pictures: up to REPORT_FRAMES frames spread over the split
    frame_picks = set(np.linspace(0, len(index) - 1, min(REPORT_FRAMES, len(index))).round().astype(int).tolist())
    frames = []

    for i0 in track(range(0, len(index), batch_size), total=math.ceil(len(index) / batch_size),
                    description=f"evaluate {split}", quiet=quiet):
        items = list(range(i0, min(i0 + batch_size, len(index))))
        raws = [data.read(i) for i in items]
        if model is not None:
            p_rng, p_hum, p_cloud = run.ranges([hm for hm, _, _ in raws])
        for j, i in enumerate(items):
            sid, k = index[i]
            hm, g_rng, g_lab = apply_transform(*raws[j], base_tf)
            sc = ds.scene(sid)
            if sid not in scene_info:
                scene_info[sid] = _scene_info(sc, data, i, rb)
                beams[sid] = SceneBeams(sc, ds.grid)
            geo = beams[sid].frame(k, f)
            g_nrm, G = geo.gt_normal, geo.gt_point
            if G is None:
                G = unmirror(g_rng, geo.directions, normals=g_nrm, grid=grid, origins=geo.origins)["point"]
            g_los = is_los(g_lab)
            gc = _clouds(G, g_los)
            gt_centres.append(M.human_centroids(_human_points(G, is_human(g_lab))))
            hidden.append(person_hidden(g_lab))
            b_rng = strongest_peaks(hm, rb, k=3)
            if model is None:  # oracle: the ground truth is the prediction
                p_j, h_j = g_rng, is_human(g_lab).astype(np.float32)
                pcm = score_frame(accs["model"], sid, g_rng, h_j, g_rng, gc, grid, tau, taus, max_range, geo,
                                  normals=g_nrm, los=g_los)
            elif stage2 is None:
                p_j = p_rng[j]
                pcm = score_frame(accs["model"], sid, p_j, p_hum[j], g_rng, gc, grid, tau, taus, max_range, geo,
                                  cloud_range=p_cloud[j])
            else:
                p_j = p_rng[j]
                pcs = {"model_analytic": score_frame(accs["model_analytic"], sid, p_j, p_hum[j], g_rng, gc, grid,
                                                     tau, taus, max_range, geo, cloud_range=p_cloud[j])}
                s2m = stage2.predict(p_cloud[j], p_hum[j], geo.directions, geo.origins, grid)
                s2g = stage2.predict(g_rng, is_human(g_lab).astype(np.float32), geo.directions,
                                     geo.origins, grid)
                pcs["model_no_refine"] = score_points(accs["model_no_refine"], sid, s2m["no_refine"], p_j, g_rng, gc, tau, taus)
                pcm = score_points(accs["model"], sid, s2m["refined"] or s2m["no_refine"], p_j, g_rng, gc, tau, taus)
                pcs["oracle_stage1"] = score_points(accs["oracle_stage1"], sid, s2g["refined"] or s2g["no_refine"],
                                                    g_rng, g_rng, gc, tau, taus)
            pcb = score_frame(accs["baseline"], sid, b_rng, None, g_rng, gc, grid, tau, taus, max_range, geo)
            gt_nlos_points.append(int(len(gc["nlos"])))
            if i in frame_picks:
                am = accs["model"]
                frames.append(_report_frame(sid, k, gc, _human_points(G, is_human(g_lab)), pcm, gt_centres[-1],
                                            am.pred_centres[-1], am.cloud["nlos"][-1], hidden[-1]))
            if i == ex_pick:
                example = {"scene": sid, "frame": k, "gt": g_rng, "model": p_j, "baseline": b_rng,
                           "clouds": {"gt": gc, "model": pcm, "baseline": pcb}}
                if stage2 is not None:
                    example["clouds"].update(pcs)

    methods = {m: summarise(accs[m], gt_centres, scene_info, max_range, hidden) for m in rows}
    doc = {
        "format": "holodata-metrics-1",
        "dataset": str(dataset_url), "split": split, "checkpoint": "oracle" if oracle else str(checkpoint),
        "n_frames": len(index), "scenes": sorted(scene_info),
        "settings": {"tau_m": tau, "taus_m": list(taus), "human_match_m": M.HUMAN_MATCH_M,
                     "max_range_m": max_range, "cd_convention": "sum", "downsample": f,
                     "grid": grid.to_attrs(), "range_bins": rb.to_attrs(), "norm": norm.to_dict(),
                     "baseline": "three strongest range peaks per beam (>= 6 dB over the beam median, beyond 0.25 m)",
                     "train_epochs": int(ck.get("epoch", 0)), "estimator": run.point_estimator,
                     "beam_origin": {sid: b.origin.to_attrs() for sid, b in beams.items()},
                     "stage2": _stage2_settings(ck2),
                     "gt_nlos_points_per_frame": float(np.mean(gt_nlos_points)) if gt_nlos_points else 0.0,
                     "frames_hidden_person": int(sum(hidden))},
        "methods": methods,
        "figures": [],
    }
    doc = jsonable(doc)
    if report:
        from .report import write_report

        errs = {m: [_sample(np.concatenate(accs[m].errors[b]) if accs[m].errors[b] else np.zeros(0)) for b in range(3)]
                for m in METHODS}  # the range errors of the other rows are the model's (or zero)
        log = None
        if not oracle:
            run_dir = Path(checkpoint) if Path(checkpoint).is_dir() else Path(checkpoint).parent
            log = run_dir / "metrics.jsonl"
        doc["figures"] = write_report(out, doc, example, errs, log, frames=frames)
    validate_metrics(doc)
    (out / "metrics.json").write_text(json.dumps(doc, indent=2) + "\n")
    return doc


def _stage2_settings(ck2) -> str:
    if ck2 is None:
        return "analytic (normals from the range images, paper eq. 2-5)"
    c = ck2["stage2_config"]
    refined = ck2["epoch"] > c["epochs_rt"]
    return (f"learned: hybrid ray tracer ({c['epochs_rt']} epochs)"
            + (f" + voxel refiner ({ck2['epoch'] - c['epochs_rt']} epochs, {c['voxel'] * 100:.0f} cm voxels, "
               f"points kept where P(empty) < {(ck2.get('keep') or {}).get('threshold', 0.5):g})" if refined else ""))


def _subsample(p: np.ndarray, n: int = REPORT_POINTS) -> np.ndarray:
    p = np.asarray(p, np.float32).reshape(-1, 3)
    if len(p) <= n:
        return p
    return p[np.sort(np.random.default_rng(0).choice(len(p), n, replace=False))]


def _report_frame(scene, frame, gt_clouds, gt_human, pred_clouds, gt_centres, pred_centres, nlos_score, hidden) -> dict:
    """One held-out frame for the report's hidden-side picture (radar frame, subsampled clouds)."""
    return {"scene": scene, "frame": int(frame), "hidden_person": bool(hidden),
            "gt": {"los": _subsample(gt_clouds["los"]), "nlos": _subsample(gt_clouds["nlos"]),
                   "human": _subsample(gt_human)},
            "pred": {"los": _subsample(pred_clouds["los"]), "nlos": _subsample(pred_clouds["nlos"])},
            "gt_centres": np.asarray(gt_centres, float).reshape(-1, 3),
            "pred_centres": np.asarray(pred_centres, float).reshape(-1, 3),
            "nlos_f_score": nlos_score.get("f_score"), "nlos_cd": nlos_score.get("cd"),
            "counts": {"gt_los": len(gt_clouds["los"]), "gt_nlos": len(gt_clouds["nlos"]), "gt_human": len(gt_human),
                       "pred_los": len(pred_clouds["los"]), "pred_nlos": len(pred_clouds["nlos"])}}


def _sample(e: np.ndarray) -> np.ndarray:
    if e.size <= ERR_SAMPLE:
        return e
    return np.random.default_rng(0).choice(e, ERR_SAMPLE, replace=False)


def _scene_info(sc, data, i: int, rb: RangeBins) -> dict:
    attrs = dict(sc.attrs)
    att = M.scene_attenuation_db(attrs)
    if att is None:
        hm, g_rng, g_lab = data.read(i)
        att = M.estimate_attenuation_db(hm[None], g_rng[None], g_lab[None], rb.dr)
    return {"bands": M.scene_bands(attrs, att), "attenuation_db": att}
