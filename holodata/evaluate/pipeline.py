"""``holodata evaluate`` (:class:`Evaluation`): run a trained checkpoint and the non-learned
baseline over a split, score both with the paper's metrics (holodata.metrics), write metrics.json
(validated against schemas/metrics.schema.json), PNG figures and report.html.

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
from collections.abc import Sequence
from dataclasses import KW_ONLY, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from holodata import metrics as M
from holodata.conventions import Grid, RangeBins, is_human, is_los, reduced_grid
from holodata.geometry.unmirror import los_mask, unmirror
from holodata.ownership import claim_folder
from holodata.progress import track
from holodata.scene_beams import FrameGeometry, SceneBeams

from .baseline import strongest_peaks

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


@dataclass(frozen=True)
class FrameTarget:
    """What one frame's predictions are scored against, the same for every method of the frame.

    ``scene``, ``frame``: which frame (``scene`` keys the per-scene rows); ``ranges`` (3,H,W) float
    m: the GT range images (NaN: no return); ``clouds`` {"los", "nlos"}: (N,3) GT points in the
    radar frame of the frame's pose, m; ``geo``: the frame's beams at the reduced grid (origins,
    directions, and the traced GT points/normals when stored); ``grid``: that reduced grid;
    ``tau`` m: the F-score's distance threshold; ``taus`` m: the thresholds of the
    precision/recall/F curve."""

    scene: str
    frame: int
    ranges: np.ndarray
    clouds: dict
    geo: FrameGeometry
    grid: Grid
    tau: float
    taus: Sequence[float]


def _score_clouds(acc: _Acc, row: dict, pc: dict, human_points, target: FrameTarget) -> None:
    for part in ("los", "nlos"):
        d_pg, d_gp = M.nn_distances(pc[part], target.clouds[part])
        m = M._cloud_summary(d_pg, d_gp, target.tau)
        acc.cloud[part].append(m)
        row["cloud"][part].append(m)
        acc.curve[part].append(M.prf_curve_from_distances(d_pg, d_gp, target.taus))
    acc.pred_centres.append(M.human_centroids(human_points))


def _scene_row(acc: _Acc, scene: str) -> dict:
    return acc.per_scene.setdefault(scene, {"errors": [[], [], []], "cloud": {"los": [], "nlos": []}})


def score_frame(acc: _Acc, target: FrameTarget, pred_range, pred_human, normals=None, los=None,
                cloud_range=None) -> dict:
    """Add one frame's prediction (3,H,W) range (+ (3,H,W) human prob or None) to ``acc``, scored
    against ``target``; its beams start at ``target.geo.origins`` along ``target.geo.directions``.
    ``normals`` (3,H,W,3) / ``los`` (3,H,W) bool override the estimated ones (oracle runs);
    ``cloud_range`` (3,H,W): the ranges to un-mirror into the point cloud when they differ from the
    scored range images (``Predictor.ranges``' gate). Returns the point cloud {"los", "nlos"}."""
    row = _scene_row(acc, target.scene)
    _score_ranges(acc, row, pred_range, target.ranges)
    cloud_range = pred_range if cloud_range is None else cloud_range
    geo, grid = target.geo, target.grid
    P = unmirror(cloud_range, geo.directions, normals=normals, grid=grid, origins=geo.origins)["point"]
    if los is None:
        los = los_mask(P, cloud_range[0], grid, origins=geo.origins)
    pc = _clouds(P, los)
    hum = np.zeros(P.shape[:-1], bool) if pred_human is None else (pred_human >= 0.5)
    _score_clouds(acc, row, pc, _human_points(P, hum), target)
    return pc


def score_points(acc: _Acc, target: FrameTarget, pred: dict, pred_range) -> dict:
    """Add one frame of stage-two output to ``acc``: ``pred`` {point (…,3), los (…) bool, human (…)
    bool} (a refined cloud or ray-traced point images), scored against ``target``; range errors are
    those of ``pred_range`` (3,H,W), the range images stage two was given."""
    row = _scene_row(acc, target.scene)
    _score_ranges(acc, row, pred_range, target.ranges)
    P = np.asarray(pred["point"], np.float64)
    pc = _clouds(P, np.asarray(pred["los"], bool))
    _score_clouds(acc, row, pc, _human_points(P, np.asarray(pred["human"], bool)), target)
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


@dataclass
class _Opened:
    """What an evaluation opens before it scores: the resolved ``checkpoint`` (None for an oracle
    run), the claimed output folder ``out``, the loaded ``run`` (:class:`.predict.Predictor`), the
    dataset ``ds`` and its ``data`` split (``holodata.torch.data.HeatmapDataset``), the reduced
    ``grid``, the range bins ``rb``, the (scene, frame) ``index`` scored and ``base_tf``, the
    baseline's sample transform."""

    checkpoint: Path | None
    out: Path
    run: Any
    ds: Any
    data: Any
    grid: Grid
    rb: RangeBins
    index: list
    base_tf: Any
    oracle_row: bool = True

    @property
    def rows(self) -> tuple[str, ...]:
        """The methods scored: the Table-2 rows with a learned stage two (``oracle_stage1`` only with
        ``oracle_row``), else model and baseline."""
        if self.run.stage2 is None:
            return METHODS
        return tuple(m for m in STAGE2_ROWS if self.oracle_row or m != "oracle_stage1")

    @property
    def max_range(self) -> float:
        """The range bins' maximum range, m."""
        return float(self.rb.max_range)


@dataclass
class _Tally:
    """What scoring a split gathers: one :class:`_Acc` per method (``accs``), and per frame its GT
    human centres, whether its person is hidden (:func:`person_hidden`) and its GT NLOS point count;
    per scene its bands/attenuation (``scene_info``) and beams (``beams``, :class:`SceneBeams`); the
    report's hidden-side pictures (``frames``, drawn at the split positions ``picks``) and its
    example frame (``example``, the one at ``ex_pick``); ``motion``: the motion cue's scorer
    (:class:`.motion.MotionScorer`) or None."""

    accs: dict
    picks: set
    ex_pick: int
    gt_centres: list = field(default_factory=list)
    hidden: list = field(default_factory=list)
    gt_nlos_points: list = field(default_factory=list)
    scene_info: dict = field(default_factory=dict)
    beams: dict = field(default_factory=dict)
    frames: list = field(default_factory=list)
    example: dict | None = None
    motion: Any = None


@dataclass
class Evaluation:
    """``holodata evaluate``: ``checkpoint`` (file or run directory, or "pretrained") and the
    strongest-peaks baseline scored on the ``split`` scenes of the dataset at ``dataset_url``.
    :meth:`run` writes ``out_dir``/metrics.json (+ figures and report.html when ``report``) and
    returns the metrics document (the same dict as the JSON).

    ``device``: the torch device the model runs on; ``batch_size``: frames per model call;
    ``tau`` m: the F-score's distance threshold; ``taus`` m: the thresholds of the
    precision/recall/F curves; ``max_frames``: only the split's first N frames (None: all);
    ``quiet``: no progress bar. ``oracle=True`` scores the ground truth itself (ranges, normals,
    labels) as the "model" (``checkpoint`` may then be None): a check of the metric plumbing, which
    must give perfect scores. ``estimator``: the model's point estimate per beam ("mean", "median",
    "mode"; see :meth:`holodata.torch.model.MultiReturnUNet.predict`; None: the one the checkpoint
    was trained for). ``motion``: a :class:`holodata.evaluate.motion.MotionCue` whose moving person
    (found from the change between a corner's rotations) gives the model row's human centres (or
    joins the human head's: ``MotionCue.alone``), or None (the human head's alone).
    ``oracle_row=False`` leaves out the ``oracle_stage1`` row (the GT range images through the run's
    stage two; a second stage-two pass per frame): the demo scores the shipped weights beside its own
    model, whose run shows that row."""

    dataset_url: str | Path
    checkpoint: str | Path | None
    out_dir: str | Path
    split: str = "test"
    _: KW_ONLY
    device: str = "cpu"
    batch_size: int = 4
    tau: float = M.DEFAULT_TAU_M
    taus: Sequence[float] = M.DEFAULT_TAUS_M
    max_frames: int | None = None
    quiet: bool = False
    report: bool = True
    oracle: bool = False
    estimator: str | None = None
    motion: Any = None
    oracle_row: bool = True

    def run(self) -> dict:
        """Open the run and the split, score every frame, write metrics.json (+ the report); returns
        the metrics document."""
        s = self._open()
        t = self._score_split(s)
        doc = jsonable(self._document(s, t))
        if self.report:
            doc["figures"] = self._write_report(s, t, doc)
        validate_metrics(doc)
        (s.out / "metrics.json").write_text(json.dumps(doc, indent=2) + "\n")
        return doc

    def _open(self) -> _Opened:
        """Resolve the checkpoint, claim the output folder, load the run, open the dataset, check
        that the run's stage one fits it (not for an oracle run) and select the split's frames."""
        from holodata.dataset import open_dataset
        from holodata.torch.data import HeatmapDataset
        from holodata.torch.pretrained import resolve

        from .predict import Predictor

        ds = open_dataset(str(self.dataset_url))
        checkpoint = None if self.oracle else resolve(self.checkpoint, ds.grid)
        out = Path(self.out_dir)
        claim_folder(out, "holodata evaluate")   # a new or empty folder, or a report holodata wrote
        run = Predictor.load(checkpoint, device=self.device, estimator=self.estimator, oracle=self.oracle)
        model_tf, base_tf = run.transforms()
        if not self.oracle:
            from holodata.torch.train import check_stage1

            check_stage1(run.checkpoint, ds, checkpoint)
        data = HeatmapDataset(str(self.dataset_url), split=self.split, norm=run.norm, transform=model_tf)
        index = data.index[:self.max_frames] if self.max_frames else data.index
        return _Opened(checkpoint, out, run, ds, data, reduced_grid(ds.grid, run.downsample), ds.range_bins, index,
                       base_tf, self.oracle_row)

    def _score_split(self, s: _Opened) -> _Tally:
        """Score the split's frames, ``batch_size`` at a time through the model."""
        from holodata.torch.data import apply_transform

        index = s.index
        # the report's hidden-side pictures: up to REPORT_FRAMES frames spread over the split
        picks = set(np.linspace(0, len(index) - 1, min(REPORT_FRAMES, len(index))).round().astype(int).tolist())
        t = _Tally({m: _Acc() for m in s.rows}, picks, len(index) // 2)
        if self.motion is not None and s.run.model is not None:
            from .motion import MotionScorer

            t.motion = MotionScorer(self.motion, s, t.beams)
        for i0 in track(range(0, len(index), self.batch_size), total=math.ceil(len(index) / self.batch_size),
                        description=f"evaluate {self.split}", quiet=self.quiet):
            items = list(range(i0, min(i0 + self.batch_size, len(index))))
            raws = [s.data.read(i) for i in items]
            if s.run.model is not None:
                p_rng, p_hum, p_cloud = s.run.ranges([hm for hm, _, _ in raws])
            for j, i in enumerate(items):
                pred = None if s.run.model is None else (p_rng[j], p_hum[j], p_cloud[j])
                self._score_frame(s, t, i, apply_transform(*raws[j], s.base_tf), pred)
        return t

    def _score_frame(self, s: _Opened, t: _Tally, i: int, item: tuple, pred: tuple | None) -> None:
        """Score frame ``i`` of the split: ``item`` (heatmap, GT ranges, GT labels) in the baseline's
        transform, ``pred`` the model's (ranges, human prob, cloud ranges) or None (oracle)."""
        hm, g_rng, g_lab = item
        target, gt_human = self._target(s, t, i, g_rng, g_lab)
        t.gt_centres.append(M.human_centroids(gt_human))
        t.hidden.append(person_hidden(g_lab))
        b_rng = strongest_peaks(hm, s.rb, k=3)
        p_j, pcm, pcs = _score_model(s.run.stage2, t.accs, target, pred, g_lab)
        if t.motion is not None:   # the moving person joins (or replaces) the model's human centres
            from .motion import merge_centres

            acc = t.accs["model"]
            cue = t.motion.centres(i, hm, pred)
            acc.pred_centres[-1] = cue if self.motion.alone else merge_centres(acc.pred_centres[-1], cue)
        pcb = score_frame(t.accs["baseline"], target, b_rng, None)
        t.gt_nlos_points.append(int(len(target.clouds["nlos"])))
        if i in t.picks:
            t.frames.append(_report_frame(target, gt_human, t.gt_centres[-1], t.hidden[-1], pcm, t.accs["model"]))
        if i == t.ex_pick:
            t.example = {"scene": target.scene, "frame": target.frame, "gt": g_rng, "model": p_j, "baseline": b_rng,
                         "clouds": {"gt": target.clouds, "model": pcm, "baseline": pcb, **pcs}}

    def _target(self, s: _Opened, t: _Tally, i: int, g_rng, g_lab) -> tuple[FrameTarget, np.ndarray]:
        """Frame ``i``'s :class:`FrameTarget` and its GT human points (N,3) in the radar frame; the
        first frame of a scene records the scene's bands and beams in ``t``. GT points are the traced
        ones (``gt/point``) when stored, else the GT ranges un-mirrored with the GT normals."""
        sid, k = s.index[i]
        sc = s.ds.scene(sid)
        if sid not in t.scene_info:
            t.scene_info[sid] = _scene_info(sc, s.data, i, s.rb)
            t.beams[sid] = SceneBeams(sc, s.ds.grid)
        geo = t.beams[sid].frame(k, s.run.downsample)
        G = geo.gt_point
        if G is None:
            G = unmirror(g_rng, geo.directions, normals=geo.gt_normal, grid=s.grid, origins=geo.origins)["point"]
        target = FrameTarget(sid, k, g_rng, _clouds(G, is_los(g_lab)), geo, s.grid, self.tau, self.taus)
        return target, _human_points(G, is_human(g_lab))

    def _document(self, s: _Opened, t: _Tally) -> dict:
        """The metrics document (before :func:`jsonable`; its figures still to come)."""
        methods = {m: summarise(t.accs[m], t.gt_centres, t.scene_info, s.max_range, t.hidden) for m in s.rows}
        return {
            "format": "holodata-metrics-1",
            "dataset": str(self.dataset_url), "split": self.split,
            "checkpoint": "oracle" if self.oracle else str(s.checkpoint),
            "n_frames": len(s.index), "scenes": sorted(t.scene_info),
            "settings": self._settings(s, t),
            "methods": methods,
            "figures": [],
        }

    def _settings(self, s: _Opened, t: _Tally) -> dict:
        """The metrics document's ``settings``: how the run was scored."""
        run = s.run
        return {"tau_m": self.tau, "taus_m": list(self.taus), "human_match_m": M.HUMAN_MATCH_M,
                "max_range_m": s.max_range, "cd_convention": "sum", "downsample": run.downsample,
                "grid": s.grid.to_attrs(), "range_bins": s.rb.to_attrs(), "norm": run.norm.to_dict(),
                "baseline": "three strongest range peaks per beam (>= 6 dB over the beam median, beyond 0.25 m)",
                "train_epochs": int(run.checkpoint.get("epoch", 0)), "estimator": run.point_estimator,
                "beam_origin": {sid: b.origin.to_attrs() for sid, b in t.beams.items()},
                "stage2": _stage2_settings(run.stage2_checkpoint),
                "gt_nlos_points_per_frame": float(np.mean(t.gt_nlos_points)) if t.gt_nlos_points else 0.0,
                "frames_hidden_person": int(sum(t.hidden)),
                "motion_cue": None if t.motion is None else self.motion.to_dict()}

    def _write_report(self, s: _Opened, t: _Tally, doc: dict) -> list:
        """report.html and its figures into the output folder; returns the figures' names."""
        from .report import write_report

        errs = {m: [_sample(np.concatenate(t.accs[m].errors[b]) if t.accs[m].errors[b] else np.zeros(0))
                    for b in range(3)]
                for m in METHODS}  # the range errors of the other rows are the model's (or zero)
        log = None
        if not self.oracle:
            ck = Path(s.checkpoint)
            run_dir = ck if ck.is_dir() else ck.parent
            log = run_dir / "metrics.jsonl"
        return write_report(s.out, doc, t.example, errs, log, frames=t.frames)


def _score_model(stage2, accs: dict, target: FrameTarget, pred: tuple | None, g_lab) -> tuple:
    """Score one frame's model rows: ``pred`` (ranges, human prob, cloud ranges) each (3,H,W), or
    None for an oracle run (the GT ranges, GT normals and GT labels as the prediction); with a
    learned ``stage2``, its refined and unrefined rows beside the analytic one, and the GT-fed one when
    ``accs`` has that row. Returns
    (the model's range images, its point cloud, the other rows' point clouds by row)."""
    if pred is None:  # oracle: the ground truth is the prediction
        h = is_human(g_lab).astype(np.float32)
        pcm = score_frame(accs["model"], target, target.ranges, h, normals=target.geo.gt_normal, los=is_los(g_lab))
        return target.ranges, pcm, {}
    p_rng, p_hum, p_cloud = pred
    if stage2 is None:
        return p_rng, score_frame(accs["model"], target, p_rng, p_hum, cloud_range=p_cloud), {}
    geo, grid = target.geo, target.grid
    pcs = {"model_analytic": score_frame(accs["model_analytic"], target, p_rng, p_hum, cloud_range=p_cloud)}
    s2m = stage2.predict(p_cloud, p_hum, geo.directions, geo.origins, grid)
    pcs["model_no_refine"] = score_points(accs["model_no_refine"], target, s2m["no_refine"], p_rng)
    pcm = score_points(accs["model"], target, s2m["refined"] or s2m["no_refine"], p_rng)
    if "oracle_stage1" in accs:
        s2g = stage2.predict(target.ranges, is_human(g_lab).astype(np.float32), geo.directions, geo.origins, grid)
        pcs["oracle_stage1"] = score_points(accs["oracle_stage1"], target, s2g["refined"] or s2g["no_refine"],
                                            target.ranges)
    return p_rng, pcm, pcs


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


def _report_frame(target: FrameTarget, gt_human, gt_centres, hidden: bool, pred_clouds: dict, model: _Acc) -> dict:
    """One held-out frame for the report's hidden-side picture (radar frame, subsampled clouds):
    ``target``'s GT clouds, ``gt_human`` (N,3) GT human points and ``gt_centres`` their centres,
    ``hidden`` (:func:`person_hidden`), the model's ``pred_clouds`` and, from ``model`` (its
    accumulator, this frame last), its centres and NLOS scores."""
    gt_clouds = target.clouds
    nlos_score = model.cloud["nlos"][-1]
    return {"scene": target.scene, "frame": int(target.frame), "hidden_person": bool(hidden),
            "gt": {"los": _subsample(gt_clouds["los"]), "nlos": _subsample(gt_clouds["nlos"]),
                   "human": _subsample(gt_human)},
            "pred": {"los": _subsample(pred_clouds["los"]), "nlos": _subsample(pred_clouds["nlos"])},
            "gt_centres": np.asarray(gt_centres, float).reshape(-1, 3),
            "pred_centres": np.asarray(model.pred_centres[-1], float).reshape(-1, 3),
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
