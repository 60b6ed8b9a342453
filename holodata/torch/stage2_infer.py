"""Inference of a trained stage two (:mod:`holodata.torch.stage2`): load ``RUN/stage2.pt``, ray-trace
one frame's range images into points, refine them, and choose the refined cloud's operating point.

Refined points' LOS/NLOS and human: the means over each voxel's input points of their LOS flags
(visible in the first-bounce range image, the rule evaluate uses for un-refined clouds; bounce-1
points are LOS by definition) and stage-one human probabilities. Training:
:mod:`holodata.torch.stage2_train`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from holodata.conventions import Grid, is_human, is_los
from holodata.errors import InputError
from holodata.safe_io import load_torch

from .stage2 import (
    CLASS_EMPTY,
    CLASS_HUMAN,
    CLASS_STRUCTURE,
    RayTracer,
    RayTracerConfig,
    RefinerConfig,
    VoxelRefiner,
    voxel_point_mean,
    voxelize,
)

STAGE2_CHECKPOINT = "stage2.pt"


@dataclass
class Frames:
    """Stage-two frames in memory (each radar frame's own radar frame). range/label (T,3,H,W);
    gt_point/gt_normal (T,3,H,W,3) NaN = none; origins/directions (T,H,W,3); s1_range/s1_human
    (T,3,H,W) the stage-one prediction or None."""

    range: np.ndarray
    label: np.ndarray
    gt_point: np.ndarray
    gt_normal: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    s1_range: np.ndarray | None = None
    s1_human: np.ndarray | None = None
    keys: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.range)

    def subset(self, idx) -> Frames:
        """The frames ``idx`` (indices into this set), stage-one predictions included."""
        idx = np.asarray(idx, int)
        pick = lambda a: None if a is None else a[idx]  # noqa: E731
        return Frames(self.range[idx], self.label[idx], self.gt_point[idx], self.gt_normal[idx], self.origins[idx],
                      self.directions[idx], pick(self.s1_range), pick(self.s1_human), [self.keys[i] for i in idx])


CALIBRATION_FRAMES = 40


def calibration_index(n: int, max_frames: int = CALIBRATION_FRAMES) -> np.ndarray:
    """The evenly spaced frames (of ``n``) the operating points are calibrated on (:func:`calibrate_gate`,
    :func:`calibrate_keep`): at most ``max_frames``, first and last included."""
    return np.unique(np.linspace(0, n - 1, min(max_frames, n)).astype(int))


def los_flags(points: np.ndarray, first_range: np.ndarray, grid: Grid, origins: np.ndarray | None = None) -> np.ndarray:
    """(3,H,W) LOS flags of ray-traced points (3,H,W,3): visible in the first-bounce range image
    (:func:`holodata.geometry.unmirror.los_mask`, from the beams' origins (H,W,3) when given)."""
    from holodata.geometry.unmirror import los_mask

    return los_mask(np.asarray(points, np.float64), first_range, grid,
                    origins=None if origins is None else np.asarray(origins, np.float64))


class Stage2:
    """A trained stage two: ``ray_tracer`` (RayTracer) and ``refiner`` (VoxelRefiner or None).
    ``keep_threshold``: a point is kept when its voxel's P(empty) is below it (calibrated on the
    training frames after training, :func:`calibrate_keep`; 0.5 = the arg-max class); ``min_confidence``
    (per bounce or None): the gate on stage one's returns this stage two was calibrated with
    (:func:`calibrate_gate`), applied by whoever runs stage one for it (``Predictor.ranges``);
    ``human_threshold``: a point is human when its human score reaches it (calibrated on the
    training frames after the keep threshold, :func:`calibrate_human`; 0.5 before)."""

    def __init__(self, ray_tracer: RayTracer, refiner: VoxelRefiner | None, device="cpu", keep_threshold: float = 0.5,
                 min_confidence=None, human_threshold: float = 0.5):
        self.rt, self.refiner, self.device = ray_tracer.eval(), (refiner.eval() if refiner is not None else None), device
        self.keep_threshold = float(keep_threshold)
        self.human_threshold = float(human_threshold)
        self.min_confidence = None if min_confidence is None else [float(c) for c in min_confidence]

    @torch.no_grad()
    def predict(self, R: np.ndarray, human: np.ndarray | None, directions: np.ndarray, origins: np.ndarray,
                grid: Grid, all_voxels: bool = False) -> dict:
        """One frame: R (3,H,W) m NaN = none, human (3,H,W) probability or None, directions/origins
        (H,W,3) → {"no_refine": {point (3,H,W,3), los (3,H,W), human (3,H,W)},
        "refined": {point (M,3), los (M,), human (M,)} (None without a refiner)}.

        The refined cloud is the ray-traced points whose voxel the refiner keeps (P(empty) below
        ``keep_threshold``), each where the ray tracer put it, LOS as its own flag (:func:`los_flags`),
        human when its voxel's human score reaches ``human_threshold``: its points' mean stage-one
        human probability, or 1 where the refiner classes the voxel human (the un-refined cloud:
        each point's own probability). Why points and not one refined point per voxel (centre + offset, the paper's output):
        the F-score at 10 cm measures what a 10 cm voxel's single point gives away on dense surfaces,
        while the refiner's skill is telling wrong voxels from right ones (docs/design/stage2.md).
        ``all_voxels``: keep every point and add ``p_empty`` and ``human_score`` (M,), its voxel's (for
        :func:`calibrate_keep` and :func:`calibrate_human`)."""
        dev = self.device
        Rt = torch.from_numpy(np.asarray(R, np.float32))[None].to(dev)
        d = torch.from_numpy(np.asarray(directions, np.float32)).to(dev)
        o = torch.from_numpy(np.asarray(origins, np.float32)).to(dev)
        out = self.rt(Rt, d, o)
        P = out["point"][0].cpu().numpy().astype(np.float64)
        los = los_flags(P, np.asarray(R)[0], grid, origins)
        hp = np.zeros(R.shape, np.float32) if human is None else np.asarray(human, np.float32)
        res = {"no_refine": {"point": P, "los": los, "human": hp >= self.human_threshold}, "refined": None}
        if self.refiner is None:
            return res
        ok = np.isfinite(P).all(-1)
        if not ok.any():
            res["refined"] = {"point": np.zeros((0, 3)), "los": np.zeros(0, bool), "human": np.zeros(0, bool),
                              "p_empty": np.zeros(0), "human_score": np.zeros(0)}
            return res
        pts = torch.from_numpy(P[ok]).float().to(dev)
        b = torch.from_numpy(np.nonzero(ok)[0]).to(dev)
        lf = torch.from_numpy(los[ok].astype(np.float32)).to(dev)
        hf = torch.from_numpy(hp[ok]).to(dev)
        vox = voxelize(pts, torch.zeros_like(b), b, hf, self.refiner.cfg.voxel, self.refiner.cfg.max_range, los=lf)
        ro = self.refiner(vox)
        prob = torch.softmax(ro["cls_logit"], -1)
        p_empty = prob[:, CLASS_EMPTY].cpu().numpy().astype(np.float64)
        score = torch.where(prob[:, CLASS_HUMAN] > prob[:, CLASS_STRUCTURE], 1.0, voxel_point_mean(vox, hf))
        score = score.cpu().numpy().astype(np.float64)[vox.point_voxel.cpu().numpy()]
        pv = vox.point_voxel.cpu().numpy()
        ref = {"point": P[ok], "los": los[ok], "human": score >= self.human_threshold}
        if all_voxels:
            res["refined"] = {**ref, "p_empty": p_empty[pv], "human_score": score}
        else:
            keep = p_empty[pv] < self.keep_threshold
            res["refined"] = {k: v[keep] for k, v in ref.items()}
        return res


KEEP_CANDIDATES = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.01)
HUMAN_CANDIDATES = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5)
GATE_CANDIDATES = (0.0, 0.2, 0.35, 0.5, 0.65, 0.8, 1.01)


def apply_gate(rng: np.ndarray, confidence: np.ndarray, min_confidence) -> np.ndarray:
    """Stage one's ranges (…,3,H,W) m without the returns whose confidence (…,3,H,W) is below their
    bounce's ``min_confidence`` (3 values; None: unchanged): what stage two un-mirrors."""
    if min_confidence is None:
        return rng
    return np.where(confidence >= np.asarray(min_confidence, np.float32)[:, None, None], rng, np.nan)


def _gt_clouds(frames: Frames, k: int) -> dict:
    """Frame ``k``'s GT points (M,3) m split into {"los", "nlos"} by their labels."""
    gp = frames.gt_point[k].astype(np.float64)
    ok, glos = np.isfinite(gp).all(-1), is_los(frames.label[k])
    return {"los": gp[ok & glos], "nlos": gp[ok & ~glos]}


def _mean_f(points: np.ndarray, los: np.ndarray, gt: dict, tau: float) -> float:
    """Mean of the LOS and NLOS F-scores at ``tau`` m of predicted ``points`` (M,3) flagged ``los``
    (M,) against :func:`_gt_clouds` (holodata.metrics, as evaluate scores them)."""
    from holodata import metrics as M

    return float(np.mean([M.point_cloud_metrics(points[sel], gt[part], tau)["f_score"]
                          for part, sel in (("los", los), ("nlos", ~los))]))


def calibrate_gate(s1_range: np.ndarray, s1_conf: np.ndarray, frames: Frames, grid: Grid, tau: float = 0.10,
                   max_frames: int = CALIBRATION_FRAMES, candidates=GATE_CANDIDATES) -> dict:
    """Stage one's confidence gate for bounces 2 and 3: the ``min_confidence`` per bounce below which
    a return is dropped, chosen to maximise the mean of the LOS and NLOS F-scores at ``tau`` m of the
    un-mirrored points (:func:`holodata.geometry.unmirror.unmirror` with normals from the range images,
    LOS from the first bounce, as evaluate scores them) over up to ``max_frames`` evenly spaced
    training frames: bounce 3 first (bounce 2 ungated), then bounce 2 given it. ``s1_range`` /
    ``s1_conf`` (T,3,H,W): stage one's ungated ranges (m) and :func:`holodata.torch.model.mode_confidence`.
    Why: a wrong bounce-3 return costs precision on the hidden side more than a right one adds recall
    (on held-out corners most of them are decimetres off), and stage one knows which it is unsure of.
    Bounce 1 is never gated (it carries the LOS surface and every later bounce's normal), so the LOS
    flags stay; the points are un-mirrored once per frame, with the normals of the ungated images
    (a gated image's planes lose a few points; 13 gates cost one un-mirroring). Returns
    {"min_confidence": [0, c2, c3], "scores": {"b2"|"b3": {candidate: mean F}}}."""
    from holodata.geometry.unmirror import los_mask, unmirror

    idx = calibration_index(len(frames), max_frames)
    cache = []   # per frame: the ungated points, their LOS flags, confidences and the GT clouds
    for k in idx:
        P = unmirror(s1_range[k], frames.directions[k], grid=grid, origins=frames.origins[k])["point"]
        los = los_mask(P, s1_range[k][0], grid, origins=frames.origins[k])
        cache.append((P, los, s1_conf[k], _gt_clouds(frames, k)))

    def score(gate) -> float:
        f = []
        for P, los, conf, gt in cache:
            # a gated return removes its point and every later bounce's (un-mirroring needs the chain)
            ok = np.cumprod(conf >= np.asarray(gate)[:, None, None], axis=0).astype(bool) & np.isfinite(P).all(-1)
            f.append(_mean_f(P[ok], los[ok], gt, tau))
        return float(np.mean(f))

    gate, scores = [0.0, 0.0, 0.0], {}
    for b in (2, 1):
        scores[f"b{b + 1}"] = {float(c): score(gate[:b] + [float(c)] + gate[b + 1:]) for c in candidates}
        gate[b] = max(scores[f"b{b + 1}"], key=scores[f"b{b + 1}"].get)
    return {"min_confidence": gate, "scores": scores}


def calibrate_keep(stage2: Stage2, frames: Frames, grid: Grid, tau: float = 0.10, max_frames: int = CALIBRATION_FRAMES,
                   candidates=KEEP_CANDIDATES) -> dict:
    """The refiner's keep threshold on P(empty) that maximises the mean of the refined cloud's LOS
    and NLOS F-scores at ``tau`` m (holodata.metrics, as evaluate scores them) over up to
    ``max_frames`` evenly spaced training frames, fed what the refiner is given at inference: stage
    one's (gated) predictions and human probabilities when ``frames`` holds them, else the GT ranges
    and human mask. The training objective (eq. 7, class weights) fixes the classes, not the
    F-optimal operating point of the cloud, and that point differs between exact inputs (where most
    voxels are real) and stage one's (where the wrong ones are what the threshold is for). Returns
    {"threshold", "scores": {threshold: mean F}}."""
    if stage2.refiner is None:
        return {"threshold": stage2.keep_threshold, "scores": {}}
    idx = calibration_index(len(frames), max_frames)
    sums = {c: [] for c in candidates}
    for k in idx:
        gt = _gt_clouds(frames, k)
        R, H = ((frames.range[k], is_human(frames.label[k]).astype(np.float32)) if frames.s1_range is None
                else (frames.s1_range[k], frames.s1_human[k]))
        r = stage2.predict(R, H, frames.directions[k], frames.origins[k], grid, all_voxels=True)["refined"]
        for c in candidates:
            keep = r["p_empty"] < c
            sums[c].append(_mean_f(r["point"][keep], r["los"][keep], gt, tau))
    scores = {float(c): float(np.mean(v)) if v else 0.0 for c, v in sums.items()}
    return {"threshold": max(scores, key=scores.get), "scores": scores}


def calibrate_human(stage2: Stage2, frames: Frames, grid: Grid, max_frames: int = CALIBRATION_FRAMES,
                    candidates=HUMAN_CANDIDATES) -> dict:
    """The human threshold on the refined cloud's human score (:meth:`Stage2.predict`) that maximises
    human detection F (the paper's protocol as evaluate scores it: clusters of human points,
    :func:`holodata.metrics.human_centroids`, matched within 50 cm of the GT person's,
    :func:`holodata.metrics.human_detection_metrics`) over up to ``max_frames`` evenly spaced
    training frames, fed stage one's (gated) predictions where ``frames`` holds them, at the keep
    threshold already calibrated. Why: the per-beam human head is trained with a class weight
    (holodata.torch.losses), which fixes a pixel's odds, not where clusters of a few dozen returns
    out of 10⁴-10⁵ are best told apart; a person seen only via walls gets lower probabilities than
    one in the open. None of the frames holding a person: 0.5 is kept. Returns {"threshold",
    "scores": {threshold: F}}."""
    from holodata import metrics as M

    idx = calibration_index(len(frames), max_frames)
    cache = []
    for k in idx:
        gp, lab = frames.gt_point[k].astype(np.float64), frames.label[k]
        gt = M.human_centroids(gp[np.isfinite(gp).all(-1) & is_human(lab)])
        R, H = ((frames.range[k], is_human(lab).astype(np.float32)) if frames.s1_range is None
                else (frames.s1_range[k], frames.s1_human[k]))
        out = stage2.predict(R, H, frames.directions[k], frames.origins[k], grid, all_voxels=True)
        r = out["refined"] if out["refined"] is not None else {
            "point": out["no_refine"]["point"].reshape(-1, 3), "human_score": np.asarray(H, np.float64).reshape(-1)}
        keep = r["p_empty"] < stage2.keep_threshold if "p_empty" in r else np.isfinite(r["point"]).all(-1)
        cache.append((r["point"][keep], r["human_score"][keep], gt))
    if not any(len(gt) for _, _, gt in cache):
        return {"threshold": stage2.human_threshold, "scores": {}}
    scores = {}
    for c in candidates:
        pred = [M.human_centroids(P[h >= c]) for P, h, _ in cache]
        f = M.human_detection_metrics(pred, [gt for _, _, gt in cache])["f_score"]
        scores[float(c)] = float(f) if np.isfinite(f) else 0.0
    return {"threshold": max(scores, key=lambda c: (scores[c], c)), "scores": scores}


def load_stage2(path, device: str = "cpu") -> tuple[Stage2, dict]:
    """Stage2 from ``RUN/stage2.pt`` (or the file) and its checkpoint dict; InputError when absent."""
    p = Path(path)
    if p.is_dir():
        p = p / STAGE2_CHECKPOINT
    if not p.exists():
        raise InputError(f"{p}: no such stage-two checkpoint (train it: holodata train DATASET --out RUN)")
    ck = load_torch(p, "stage-two checkpoint")
    rt = RayTracer(RayTracerConfig(**{"normals": "difference", **ck["rt_config"]}))  # before the key: eq. 4 alone
    rt.load_state_dict(ck["rt_state"])
    ref = None
    if ck.get("refiner_state") is not None and ck["epoch"] > ck["stage2_config"]["epochs_rt"]:
        ref = VoxelRefiner(RefinerConfig.from_dict(ck["refiner_config"]))
        try:
            ref.load_state_dict(ck["refiner_state"])
        except RuntimeError as err:
            raise InputError(f"{p}: refiner weights of another holodata version (retrain: holodata train DATASET "
                             f"--stage 2 --out RUN)") from err
        ref = ref.to(device)
    keep = (ck.get("keep") or {}).get("threshold", 0.5)
    gate = (ck.get("gate") or {}).get("min_confidence")
    human = (ck.get("human") or {}).get("threshold", 0.5)
    return Stage2(rt.to(device), ref, device, keep_threshold=keep, min_confidence=gate, human_threshold=human), ck
