"""Training and inference of the learned stage two (:mod:`holodata.torch.stage2`).

Stage two trains after stage one, from the dataset's ground truth: its input is either the GT
range images with augmentation (Gaussian range noise of a random σ ≤ ``noise_max_m`` per frame,
random pixel dropout, random y-mirroring of the whole frame) or, with probability ``p_stage1``
(default 0, docs/design/stage2.md), the stage-one model's own prediction of the training frame.
Phase 1 trains the ray tracer (eq. 6); phase 2 freezes it and trains the volumetric refiner on
its points (eq. 7), as the paper does; then :func:`calibrate_keep` picks the refined cloud's
operating point on the training frames.

Inference (:class:`Stage2`, :func:`load_stage2`, :func:`calibrate_keep`) lives in
:mod:`holodata.torch.stage2_infer`. Run directory: ``stage2.pt`` (latest epoch of either phase; atomic, resumable),
``stage2_config.json``, ``stage2_metrics.jsonl``. The stage-one checkpoint stays ``checkpoint.pt``.

Refined points' LOS/NLOS and human: the means over each voxel's input points of their LOS flags
(visible in the first-bounce range image, the rule evaluate uses for un-refined clouds;
bounce-1 points are LOS by definition) and stage-one human probabilities.
"""
from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from holodata.conventions import Grid, is_human, reduced_grid
from holodata.dataset.heatmap import read_heatmap
from holodata.dataset.layout import GT_LABEL, GT_NORMAL, GT_POINT, GT_RANGE, POSE_T_WORLD_RADAR
from holodata.errors import InputError
from holodata.progress import track
from holodata.safe_io import load_torch

from ..ownership import claim_folder
from .optim import OptimiserSettings, set_lr, settings_dict
from .stage2 import (
    CLASS_HUMAN,
    CLASS_STRUCTURE,
    RayTracer,
    RayTracerConfig,
    RefinerConfig,
    VoxelRefiner,
    lookup,
    ray_trace_loss,
    refine_loss,
    unique_coords,
    voxel_keys,
    voxelize,
)
from .stage2_infer import (
    STAGE2_CHECKPOINT,
    Frames,
    Stage2,
    apply_gate,
    calibrate_gate,
    calibrate_human,
    calibrate_keep,
    calibration_index,
    los_flags,
)
from .train import RunOptions, _atomic_save, _truncate_log, check_fields, check_stage1

STAGE2_LOG = "stage2_metrics.jsonl"


@dataclass
class Stage2Config(OptimiserSettings):
    """Stage-two settings. Phases: ``epochs_rt`` ray-tracer epochs, then ``epochs_refine``
    refiner epochs (ray tracer frozen), each with its own AdamW and cosine decay
    (:class:`~holodata.torch.optim.OptimiserSettings`: lr, lr_floor, weight_decay). Model:
    ``channels``/``res_blocks``/``fusion_blocks`` of each hybrid block; ``voxel`` (m), ``refine_channels``
    (per UNet level), ``refine_blocks``.
    Augmentation: ``p_clean`` (share of GT-input samples left exact), ``noise_max_m`` (σ of the
    range noise drawn per frame in [0, noise_max_m]), ``dropout`` (share of pixels dropped), ``p_stage1``
    (share of samples whose input is the stage-one prediction; default 0: ranges decimetres off teach
    the ray tracer to distrust exact ones, docs/design/stage2.md), ``flip`` (random y-mirror).
    Loss: eq. 6 weights ``w_sn``, ``w_point`` (+ ``w_normal``), RT loss pixels only where
    |R_in − R_gt| < ``input_gate_m``; eq. 7 weights ``w_cls``, ``w_reg``, ``w_dist``, class weights
    ``human_weight`` / ``empty_weight``, EDT clipped at ``edt_clip`` voxels. ``crop_w``: train on
    random azimuth windows of this many columns (wrapping) of each frame, as stage one does at the
    paper's grid; inference and calibration run on whole rings (the ray tracer is convolutional,
    the refiner works on the points it is given)."""

    epochs_rt: int = 20
    epochs_refine: int = 20
    batch_size: int = 4
    seed: int = 0
    device: str = "cpu"
    channels: int = 32
    res_blocks: int = 4
    fusion_blocks: int = 2
    voxel: float = 0.1
    refine_channels: tuple = (16, 32, 48, 64)
    refine_blocks: int = 1
    noise_max_m: float = 0.03
    dropout: float = 0.05
    p_stage1: float = 0.0
    flip: bool = True
    input_gate_m: float = 0.3
    w_sn: float = 1.0
    w_point: float = 1.0
    w_normal: float = 0.5
    w_cls: float = 1.0
    w_reg: float = 1.0
    w_dist: float = 0.2
    p_clean: float = 0.3
    human_weight: float = 3.0
    empty_weight: float = 1.0
    edt_clip: float = 8.0
    frames_per_scene: int | None = None
    crop_w: int | None = None

    @classmethod
    def from_dict(cls, data: dict, source: str = "stage-two config") -> Stage2Config:
        check_fields(cls, data, source, "stage-two")
        d = dict(data)
        if "refine_channels" in d:
            d["refine_channels"] = tuple(d["refine_channels"])
        return cls(**d)

    def to_dict(self) -> dict:
        d = settings_dict(self, ("epochs_rt", "epochs_refine", "batch_size"))
        d["refine_channels"] = list(self.refine_channels)
        return d

    @property
    def epochs(self) -> int:
        return self.epochs_rt + self.epochs_refine

    def rt_config(self, max_range: float) -> RayTracerConfig:
        return RayTracerConfig(self.channels, self.res_blocks, self.fusion_blocks, float(max_range))

    def refiner_config(self, max_range: float) -> RefinerConfig:
        return RefinerConfig(voxel=self.voxel, channels=tuple(self.refine_channels), blocks=self.refine_blocks,
                             max_range=float(max_range))


# ----------------------------------------------------------------------------- frames


class _SceneGeometry:
    """Adapter over the dataset's beam geometry: beam origins/directions (H,W,3) and GT
    points/normals (3,H,W,3) of frame k in its own radar frame at downsample ``f``. Uses
    :class:`holodata.scene_beams.SceneBeams` (per-beam origins of the scene's origin model)
    when available, else origins 0 and the grid's directions."""

    def __init__(self, sc, full_grid: Grid, f: int):

        self.sc, self.f, self.grid = sc, f, reduced_grid(full_grid, f)
        try:
            from holodata.scene_beams import SceneBeams
        except ImportError:
            SceneBeams = None
        self.beams = SceneBeams(sc, full_grid) if SceneBeams is not None else None

    def frame(self, k: int) -> dict:
        sc, f = self.sc, self.f
        if self.beams is not None:
            g = self.beams.frame(k, f)
            nan = np.full((3,) + g.origins.shape, np.nan)
            return {"origins": g.origins.astype(np.float32), "directions": g.directions.astype(np.float32),
                    "gt_point": (nan if g.gt_point is None else g.gt_point).astype(np.float32),
                    "gt_normal": (nan if g.gt_normal is None else g.gt_normal).astype(np.float32)}
        names = set(sc.arrays())
        T = np.asarray(sc[POSE_T_WORLD_RADAR][k], dtype=np.float64)
        p = np.asarray(sc[GT_POINT][k], dtype=np.float64)[:, ::f, ::f]
        n = np.asarray(sc[GT_NORMAL][k], dtype=np.float64)[:, ::f, ::f] if GT_NORMAL in names else np.full(p.shape, np.nan)
        H, W = self.grid.H, self.grid.W
        return {"origins": np.zeros((H, W, 3), np.float32), "directions": self.grid.directions().astype(np.float32),
                "gt_point": ((p - T[:3, 3]) @ T[:3, :3]).astype(np.float32),
                "gt_normal": (n @ T[:3, :3]).astype(np.float32)}


def load_frames(dataset_url, split: str, f: int, frames_per_scene: int | None = None, quiet: bool = True) -> tuple[Frames, Grid]:
    """The ``split`` frames of a dataset at downsample ``f`` (GT arrays, beam geometry)."""
    from holodata.dataset import open_dataset
    from holodata.dataset.splits import split_scenes

    ds = open_dataset(str(dataset_url))
    grid = reduced_grid(ds.grid, f)
    scenes = split_scenes(ds, split)
    cols = {k: [] for k in ("range", "label", "gt_point", "gt_normal", "origins", "directions")}
    keys = []
    for sid in scenes:
        sc = ds.scene(sid)
        geo = _SceneGeometry(sc, ds.grid, f)
        n = int(sc[GT_RANGE].shape[0])
        if frames_per_scene:
            n = min(n, frames_per_scene)
        for k in track(range(n), total=n, description=f"stage-two frames {sid}", quiet=quiet):
            cols["range"].append(np.asarray(sc[GT_RANGE][k], np.float32)[:, ::f, ::f])
            cols["label"].append(np.asarray(sc[GT_LABEL][k], np.uint8)[:, ::f, ::f])
            for name, v in geo.frame(k).items():
                cols[name].append(v)
            keys.append((sid, k))
    if not keys:
        raise InputError(f"{dataset_url}: split {split!r} has no frames for stage two")
    return Frames(**{k: np.stack(v) for k, v in cols.items()}, keys=keys), grid


def stage1_predictions(dataset_url, ck: dict, keys: list, device: str = "cpu", batch_size: int = 4,
                       quiet: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stage-one model's (range, human prob, confidence) (T,3,H,W) for the frames ``keys``
    [(scene, k)]; no confidence gate applied (:func:`holodata.torch.model.mode_confidence`)."""
    from holodata.dataset import open_dataset

    from .checkpoint import inference_transform
    from .data import HeatmapNorm, apply_transform
    from .train import model_from_checkpoint

    model = model_from_checkpoint(ck, device=device)
    norm = HeatmapNorm.from_dict(ck["norm"])
    t, window = inference_transform(ck)
    ds = open_dataset(str(dataset_url))
    rs, hs, cs = [], [], []
    for i0 in track(range(0, len(keys), batch_size), total=math.ceil(len(keys) / batch_size),
                    description="stage-one predictions", quiet=quiet):
        xs = []
        for sid, k in keys[i0:i0 + batch_size]:
            sc = ds.scene(sid)
            hm = read_heatmap(sc, k)
            r = np.asarray(sc[GT_RANGE][k], np.float32)
            xs.append(norm(apply_transform(hm, r, np.zeros(r.shape, np.uint8), t)[0]))
        with torch.no_grad():
            p = model.predict(torch.from_numpy(np.stack(xs)).to(device), window=window)
        rs.append(p["range"].float().cpu().numpy())
        hs.append(p["human_prob"].float().cpu().numpy())
        cs.append(p["confidence"].float().cpu().numpy() if "confidence" in p else np.ones_like(rs[-1]))
    return np.concatenate(rs), np.concatenate(hs), np.concatenate(cs)


def make_batch(fr: Frames, idx, cfg: Stage2Config, rng: np.random.Generator | None, device) -> dict:
    """Tensors of frames ``idx``: input range/human (augmented when ``rng``), GT, geometry."""
    R = fr.range[idx].copy()
    lab = fr.label[idx]
    hum = is_human(lab).astype(np.float32)
    gp, gn = fr.gt_point[idx].copy(), fr.gt_normal[idx].copy()
    org, dirs = fr.origins[idx].copy(), fr.directions[idx].copy()
    R_in, H_in = R.copy(), hum.copy()
    if rng is not None:
        for j in range(len(idx)):
            if fr.s1_range is not None and rng.random() < cfg.p_stage1:
                R_in[j], H_in[j] = fr.s1_range[idx[j]], fr.s1_human[idx[j]]
                continue
            if rng.random() < cfg.p_clean:
                continue  # exact GT ranges and human mask (what the oracle_stage1 row feeds)
            sigma = rng.uniform(0, cfg.noise_max_m)
            R_in[j] = R[j] + rng.normal(0, 1, R[j].shape).astype(np.float32) * sigma
            drop = rng.random(R[j].shape) < cfg.dropout
            R_in[j][drop] = np.nan
            H_in[j] = np.clip(hum[j] * 0.9 + 0.05 + rng.normal(0, 0.05, hum[j].shape), 0, 1)
        if cfg.flip:
            for j in range(len(idx)):
                if rng.random() < 0.5:  # mirror the frame in y: column j -> (W - j) % W, y -> -y
                    W = R.shape[-1]
                    cols = (-np.arange(W)) % W
                    R[j], R_in[j], H_in[j] = R[j][..., cols], R_in[j][..., cols], H_in[j][..., cols]
                    for a in (gp, gn):
                        a[j] = a[j][:, :, cols]
                        a[j][..., 1] *= -1
                    for a in (org, dirs):
                        a[j] = a[j][:, cols]
                        a[j][..., 1] *= -1
                    lab = lab.copy()
                    lab[j] = lab[j][..., cols]
    # LOS flags look up each point's direction in the whole first-bounce image (an un-mirrored point
    # lies anywhere around the ring), so they keep the full ring when the beams are cropped
    los_range, los_origins = R_in[:, 0].copy(), org.copy()
    W = R.shape[-1]
    if rng is not None and cfg.crop_w and cfg.crop_w < W:
        cols = (rng.integers(W, size=len(idx))[:, None] + np.arange(cfg.crop_w)) % W   # (n, crop_w)

        def crop(a, axis):   # frame j's columns cols[j] along ``axis`` of a[j]
            return np.stack([np.take(a[j], cols[j], axis=axis) for j in range(len(a))])

        R, R_in, H_in, lab, gp, gn = (crop(a, 2) for a in (R, R_in, H_in, lab, gp, gn))   # (3, H, W[, 3])
        org, dirs = crop(org, 1), crop(dirs, 1)                                          # (H, W, 3)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device)  # noqa: E731
    return {"range_in": t(R_in), "human_in": t(H_in), "range": t(R), "label": t(lab), "gt_point": t(gp),
            "gt_normal": t(gn), "origins": t(org), "directions": t(dirs), "los_range": t(los_range),
            "los_origins": t(los_origins)}


# ----------------------------------------------------------------------------- refiner targets


def refine_targets(vox_coords: torch.Tensor, gt_points: list, gt_human: list, voxel: float, edt_clip: float):
    """Targets of eq. 7 for the occupied input voxels (M,4) [batch, x, y, z]: class (M,) (empty /
    human / structure of the GT points in the voxel; human when any is human), offset (M,3) m of the
    GT points' mean from the voxel centre, EDT (M,) voxels to the nearest GT-occupied voxel
    clipped at ``edt_clip`` (the value scipy.ndimage.distance_transform_edt of the GT occupancy
    takes at those voxels, from a k-d tree over the occupied ones). gt_points[j] (Q_j,3) / gt_human[j] (Q_j,) bool per frame j."""
    from scipy.spatial import cKDTree

    M = len(vox_coords)
    cls = torch.zeros(M, dtype=torch.long)
    reg = torch.zeros(M, 3)
    edt = torch.full((M,), float(edt_clip))
    vc = vox_coords.cpu()
    for j, (P, hm) in enumerate(zip(gt_points, gt_human)):
        sel = torch.nonzero(vc[:, 0] == j).squeeze(1)
        if len(sel) == 0:
            continue
        if len(P) == 0:
            continue
        P = torch.from_numpy(P).float()
        ijk = torch.floor(P / voxel).long()
        gcoords, inv, _ = unique_coords(torch.cat([torch.full((len(P), 1), j), ijk], 1))
        G = len(gcoords)
        gmean = torch.zeros(G, 3).index_add_(0, inv, P) / torch.zeros(G).index_add_(0, inv, torch.ones(len(P)))[:, None]
        ghum = torch.zeros(G).index_add_(0, inv, torch.from_numpy(hm.astype(np.float32))) > 0
        gk = voxel_keys(gcoords)
        sk, order = torch.sort(gk)
        hit = lookup(sk, order, voxel_keys(vc[sel]), -1)
        ok = hit >= 0
        h = hit[ok]
        cls[sel[ok]] = torch.where(ghum[h], CLASS_HUMAN, CLASS_STRUCTURE)
        centre = (vc[sel[ok], 1:].float() + 0.5) * voxel
        reg[sel[ok]] = gmean[h] - centre
        # EDT: Euclidean distance (voxels) to the nearest GT-occupied voxel, clipped; a k-d tree over
        # the occupied voxels gives exactly the distance transform's value at the queried voxels
        dist, _ = cKDTree(gcoords[:, 1:].numpy()).query(vc[sel, 1:].numpy(), distance_upper_bound=edt_clip)
        edt[sel] = torch.from_numpy(np.minimum(dist, edt_clip)).float()
    return cls, reg, edt


# ----------------------------------------------------------------------------- training


def _refine_batch(rt: RayTracer, batch: dict, cfg: Stage2Config, device, grid: Grid):
    """Ray-traced points of a batch → (Voxels, targets) for the refiner."""
    with torch.no_grad():
        out = rt(batch["range_in"], batch["directions"], batch["origins"])
    P = out["point"]
    ok = torch.isfinite(P).all(-1)
    Pn = P.cpu().numpy().astype(np.float64)
    R1 = batch["los_range"].cpu().numpy()
    org = batch["los_origins"].cpu().numpy()
    los = np.stack([los_flags(Pn[j], R1[j], grid, org[j]) for j in range(len(Pn))])
    nz = torch.nonzero(ok)
    vox = voxelize(P[ok].float(), nz[:, 0], nz[:, 1], batch["human_in"][ok], cfg.voxel, rt.cfg.max_range,
                   los=torch.from_numpy(los).to(device)[ok])
    gpts, ghum = [], []
    gp = batch["gt_point"].cpu().numpy()
    lab = batch["label"].cpu().numpy()
    for j in range(len(gp)):
        m = np.isfinite(gp[j]).all(-1)
        gpts.append(gp[j][m].astype(np.float64))
        ghum.append(is_human(lab[j][m]))
    cls, reg, edt = refine_targets(vox.coords, gpts, ghum, cfg.voxel, cfg.edt_clip)
    return vox, cls.to(device), reg.to(device), edt.to(device)


def fit_stage2(frames: Frames, out_dir, cfg: Stage2Config, max_range: float, grid: Grid,
               options: RunOptions | None = None, confidence_gate: dict | None = None,
               calibration: Frames | None = None) -> dict:
    """Train stage two on ``frames`` (on the beam ``grid``) into ``out_dir``/stage2.pt; resumes from
    it when present and ``options.resume`` (same configuration required); ``confidence_gate``: stage
    one's confidence gate (:func:`calibrate_gate`), stored with the checkpoint; ``calibration``: the
    frames the keep threshold is calibrated on (:func:`calibrate_keep`; default ``frames``).
    ``options.init``: a stage-two checkpoint (dict) whose ray tracer and refiner weights a fresh run
    starts from (fine-tuning): its models' shapes must be this configuration's (one-line InputError
    naming ``options.meta["init"]`` otherwise); its keep and human operating points are not taken over
    but calibrated anew on these frames; with 0 epochs the run's checkpoint holds its weights as they
    are. The refiner counts (at inference and for the calibrations) only after a refiner epoch of this
    run (``epochs_refine`` > 0), as without ``init``. Returns {"checkpoint", "epochs", "resumed_from",
    "history", "keep", "gate", "human"}."""
    from .train import resolve_device, seed_everything

    opts = options or RunOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    dev = resolve_device(cfg.device)
    seed_everything(cfg.seed)
    run = _Stage2Run(cfg, RayTracer(cfg.rt_config(max_range)).to(dev), VoxelRefiner(cfg.refiner_config(max_range)).to(dev),
                     dev, grid, opts.quiet)
    ck_path = out / STAGE2_CHECKPOINT
    start, history = run.resume_or_init(ck_path, opts)
    (out / "stage2_config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
    _truncate_log(out / STAGE2_LOG, start)
    for epoch in range(start, cfg.epochs):
        history.append(run.epoch(frames, epoch))
        run.save(ck_path, history, opts.meta)
        with open(out / STAGE2_LOG, "a") as fh:
            fh.write(json.dumps(history[-1]) + "\n")
    keep, human = _calibrate(run, ck_path, frames if calibration is None else calibration, confidence_gate)
    return {"checkpoint": ck_path, "epochs": cfg.epochs, "resumed_from": start, "history": history, "keep": keep,
            "gate": confidence_gate, "human": human}


class _Stage2Run:
    """The models :func:`fit_stage2` trains (``rt`` the ray tracer, ``ref`` the refiner) with their
    settings, device and beam grid, and the optimiser of the current phase (a new AdamW when the phase
    changes; the resumed checkpoint's state when it was saved in that phase)."""

    def __init__(self, cfg: Stage2Config, rt: RayTracer, ref: VoxelRefiner, dev, grid: Grid, quiet: bool):
        self.cfg, self.rt, self.ref, self.dev, self.grid, self.quiet = cfg, rt, ref, dev, grid, quiet
        self.class_weights = torch.tensor([cfg.empty_weight, cfg.human_weight, 1.0], device=dev)
        self.opt: torch.optim.Optimizer | None = None
        self.opt_phase: str | None = None
        self.opt_state: dict | None = None   # the resumed checkpoint's {"phase", "state"}

    def resume_or_init(self, ck_path: Path, opts: RunOptions) -> tuple[int, list]:
        """Load the run's own checkpoint (same settings but device and epochs required; weights,
        optimiser state, torch RNG) or, on a fresh run, ``opts.init``'s weights (saved at once when
        there is no epoch to train); (epochs done, history)."""
        cfg, rt, ref = self.cfg, self.rt, self.ref
        if opts.resume and ck_path.exists():
            ck = load_torch(ck_path, "stage-two checkpoint")
            saved = {**Stage2Config().to_dict(), **ck["stage2_config"]}   # settings added since: their defaults
            same = {k: v for k, v in saved.items() if k not in ("device", "epochs_rt", "epochs_refine")}
            want = {k: v for k, v in cfg.to_dict().items() if k not in ("device", "epochs_rt", "epochs_refine")}
            if same != want or ck["stage2_config"]["epochs_rt"] != cfg.epochs_rt:
                raise InputError(f"{ck_path}: stage-two checkpoint config differs from the requested one; use a new --out")
            rt.load_state_dict(ck["rt_state"])
            ref.load_state_dict(ck["refiner_state"])
            self.opt_state = ck["optimizer_state"]
            torch.set_rng_state(ck["torch_rng"])
            return int(ck["epoch"]), list(ck["history"])
        if opts.init is not None:
            load_init_weights(opts.init, rt, ref, (opts.meta or {}).get("init", "init checkpoint"))
            if cfg.epochs == 0:   # nothing to train: the run's checkpoint is the init's weights
                _atomic_save(self._checkpoint(0, "rt", None, [], opts.meta), ck_path)
        return 0, []

    def epoch(self, frames: Frames, epoch: int) -> dict:
        """Train one epoch (0-based ``epoch``) of the phase it falls in; its metrics row."""
        cfg = self.cfg
        phase = "rt" if epoch < cfg.epochs_rt else "refine"
        e0, n_ep = (0, cfg.epochs_rt) if phase == "rt" else (cfg.epochs_rt, cfg.epochs_refine)
        opt = self._optimizer(phase)
        lr = cfg.lr_at(epoch - e0, max(n_ep, 1))
        set_lr(opt, lr)
        rng = np.random.default_rng([cfg.seed, epoch])
        order = rng.permutation(len(frames))
        self.rt.train(phase == "rt")
        self.ref.train(phase == "refine")
        sums: dict = {}
        n_seen, t0 = 0, time.perf_counter()
        batches = [order[i:i + cfg.batch_size] for i in range(0, len(order), cfg.batch_size)]
        for idx in track(batches, total=len(batches), description=f"stage two {phase} {epoch + 1}/{cfg.epochs}",
                         quiet=self.quiet):
            batch = make_batch(frames, idx, cfg, rng, self.dev)
            loss, parts, params = self._rt_loss(batch) if phase == "rt" else self._refine_loss(batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, 5.0)
            opt.step()
            n_seen += len(idx)
            sums["loss"] = sums.get("loss", 0.0) + float(loss.detach()) * len(idx)
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v * len(idx)
        dt = time.perf_counter() - t0
        return {"epoch": epoch + 1, "phase": phase, **{k: v / max(n_seen, 1) for k, v in sums.items()}, "lr": lr,
                "samples": n_seen, "seconds": round(dt, 3)}

    def _optimizer(self, phase: str) -> torch.optim.Optimizer:
        """The phase's optimiser: over the ray tracer's parameters, then the refiner's."""
        if self.opt is None or self.opt_phase != phase:
            self.opt = self.cfg.optimizer(self.rt.parameters() if phase == "rt" else self.ref.parameters())
            if self.opt_state is not None and self.opt_state.get("phase") == phase:
                self.opt.load_state_dict(self.opt_state["state"])
            self.opt_phase = phase
        return self.opt

    def _rt_loss(self, batch: dict):
        """Eq. 6 on a batch, over the pixels whose input range is within ``input_gate_m`` of the truth."""
        cfg = self.cfg
        o = self.rt(batch["range_in"], batch["directions"], batch["origins"])
        gate = (batch["range_in"] - batch["range"]).abs() < cfg.input_gate_m
        loss, parts = ray_trace_loss(o, batch["gt_point"], batch["gt_normal"], batch["directions"], gate,
                                     cfg.w_sn, cfg.w_point, cfg.w_normal)
        return loss, parts, self.rt.parameters()

    def _refine_loss(self, batch: dict):
        """Eq. 7 on the voxels of the (frozen) ray tracer's points of a batch."""
        cfg = self.cfg
        vox, cls, reg, edt = _refine_batch(self.rt, batch, cfg, self.dev, self.grid)
        o = self.ref(vox)
        loss, parts = refine_loss(o, cls, reg, edt, cfg.w_cls, cfg.w_reg, cfg.w_dist, self.class_weights)
        return loss, parts, self.ref.parameters()

    def _checkpoint(self, epoch: int, phase: str, optimizer_state: dict | None, history: list,
                    meta: dict | None) -> dict:
        return {"format": "holodata-stage2-1", "epoch": epoch, "phase": phase, "stage2_config": self.cfg.to_dict(),
                "rt_config": self.rt.cfg.to_dict(), "refiner_config": self.ref.cfg.to_dict(),
                "rt_state": self.rt.state_dict(), "refiner_state": self.ref.state_dict(),
                "optimizer_state": optimizer_state, "history": history, "torch_rng": torch.get_rng_state(),
                "meta": meta or {}}

    def save(self, ck_path: Path, history: list, meta: dict | None) -> None:
        """The checkpoint after the last epoch of ``history`` (atomic), with its phase's optimiser state."""
        row = history[-1]
        assert self.opt is not None
        _atomic_save(self._checkpoint(row["epoch"], row["phase"], {"phase": row["phase"], "state": self.opt.state_dict()},
                                      history, meta), ck_path)


def _calibrate(run: _Stage2Run, ck_path: Path, cal: Frames, confidence_gate: dict | None) -> tuple[dict | None, dict | None]:
    """Complete the checkpoint's operating points on the frames ``cal``: stage one's confidence gate,
    and once the refiner has trained (``epochs_refine`` > 0) the keep threshold of the refined cloud,
    then where its human points are told apart (each kept when already there); (keep, human)."""
    if not ck_path.exists():
        return None, None
    cfg, dev, grid = run.cfg, run.dev, run.grid
    ck = load_torch(ck_path, "stage-two checkpoint")
    keep, changed = ck.get("keep"), confidence_gate is not None and ck.get("gate") != confidence_gate
    if confidence_gate is not None:
        ck["gate"] = confidence_gate
    if cfg.epochs_refine > 0 and keep is None:  # the operating point of the refined cloud, on the training frames
        keep = calibrate_keep(Stage2(run.rt, run.ref, dev), cal, grid)
        ck["keep"], changed = keep, True
    if cfg.epochs_refine > 0 and ck.get("human") is None:   # then where its human points are told apart
        s2 = Stage2(run.rt, run.ref, dev, keep_threshold=keep["threshold"])
        ck["human"], changed = calibrate_human(s2, cal, grid), True
    if changed:
        _atomic_save(ck, ck_path)
    return keep, ck.get("human")


def check_init(init: dict, rt_cfg: RayTracerConfig, ref_cfg: RefinerConfig, source) -> None:
    """One InputError line naming ``source`` unless the stage-two checkpoint ``init`` (dict) holds a
    ray tracer and refiner of the shapes ``rt_cfg`` and ``ref_cfg`` describe."""
    try:
        have = {"ray tracer": RayTracerConfig(**{"normals": "difference", **init["rt_config"]}).to_dict(),
                "refiner": RefinerConfig.from_dict(init["refiner_config"]).to_dict()}
    except (KeyError, TypeError) as err:
        raise InputError(f"{source}: not a stage-two checkpoint holodata can fine-tune from "
                         f"({err.__class__.__name__}: {err})") from err
    want = {"ray tracer": rt_cfg.to_dict(), "refiner": ref_cfg.to_dict()}
    diff = [f"{name} {k} {have[name].get(k)} (requested {v})" for name in want for k, v in want[name].items()
            if have[name].get(k) != v]
    if diff:
        raise InputError(f"{source}: its stage-two model differs from the requested one: {'; '.join(diff)} "
                         f"(fine-tune with its settings, or train from scratch)")


def load_init_weights(init: dict, rt: RayTracer, ref: VoxelRefiner, source) -> None:
    """Load the ray tracer and refiner weights of the stage-two checkpoint ``init`` (dict) into ``rt``
    and ``ref`` (:func:`check_init` first); one InputError line naming ``source`` when they do not fit."""
    check_init(init, rt.cfg, ref.cfg, source)
    try:
        rt.load_state_dict(init["rt_state"])
        ref.load_state_dict(init["refiner_state"])
    except (KeyError, RuntimeError) as err:
        raise InputError(f"{source}: its stage-two weights do not fit this holodata's models "
                         f"({' '.join(str(err).split())[:200]})") from err


def train_stage2(dataset_url, out_dir, cfg: Stage2Config | dict | None = None, stage1=None,
                 quiet: bool = False, init=None) -> dict:
    """Train stage two on the ``train`` split of the dataset into ``out_dir``.

    ``stage1``: a stage-one checkpoint (file or run dir) whose predictions join the training
    inputs (and whose downsample stage two works at); default ``out_dir/checkpoint.pt``. It must
    exist and match the dataset's grid and range bins (InputError otherwise). When it lives
    outside ``out_dir`` it is copied there as ``checkpoint.pt`` so the run is self-contained.
    ``init``: a stage-two checkpoint (file, run directory, or ``"pretrained"``: the weights holodata
    ships) a fresh run fine-tunes from (:func:`fit_stage2`); the confidence gate, keep and human
    operating points are calibrated on this dataset's training frames."""
    from holodata.dataset import open_dataset

    from .checkpoint import CHECKPOINT, load_checkpoint

    cfg = cfg if isinstance(cfg, Stage2Config) else Stage2Config.from_dict(cfg or {})
    out = Path(out_dir)
    init_ck, init_file = None, None
    if init is not None:
        from .pretrained import resolve

        init_file = resolve(init, open_dataset(str(dataset_url)).grid)
        init_file = init_file / STAGE2_CHECKPOINT if init_file.is_dir() else init_file
        if not init_file.is_file():
            raise InputError(f"{init_file}: no such stage-two checkpoint to fine-tune from")
        init_ck = load_torch(init_file, "stage-two checkpoint")
    src = Path(stage1) if stage1 is not None else out / CHECKPOINT
    src_file = src / CHECKPOINT if src.is_dir() else src
    ck1 = load_checkpoint(src_file)
    ds = open_dataset(str(dataset_url))
    check_stage1(ck1, ds, src_file)
    if init_ck is not None:   # before the frames are read: a mismatch is one line at once
        mr = float(ds.range_bins.max_range)
        check_init(init_ck, cfg.rt_config(mr), cfg.refiner_config(mr), init_file)
    claim_folder(out, "holodata train")   # a new or empty folder, or a run holodata wrote
    if (out / CHECKPOINT).resolve() != src_file.resolve() and not (out / CHECKPOINT).exists():
        shutil.copy2(src_file, out / CHECKPOINT)
    f = int((ck1.get("transform") or {}).get("downsample", 1))
    frames, grid = load_frames(dataset_url, "train", f, cfg.frames_per_scene, quiet=quiet)
    # stage one's own predictions: its confidence gate is calibrated on them (calibrate_gate), then
    # they are gated as at inference, for the keep threshold; only the calibration frames need them
    # unless some are fed to stage two as inputs (p_stage1 > 0)
    pred = np.arange(len(frames)) if cfg.p_stage1 > 0 else calibration_index(len(frames))
    cal = frames.subset(pred)
    s1_range, cal.s1_human, s1_conf = stage1_predictions(dataset_url, ck1, cal.keys, device=cfg.device, quiet=quiet)
    gate = calibrate_gate(s1_range, s1_conf, cal, grid)
    cal.s1_range = apply_gate(s1_range, s1_conf, gate["min_confidence"])
    if cfg.p_stage1 > 0:
        frames = cal
    meta = {"dataset": str(dataset_url), "grid": ds.grid.to_attrs(), "range_bins": ds.range_bins.to_attrs(),
            "downsample": f, "stage1": str(src_file), "stage1_epoch": int(ck1.get("epoch", 0)),
            "train_frames": len(frames), **({"init": str(init_file)} if init_file else {})}
    return fit_stage2(frames, out, cfg, float(ds.range_bins.max_range), grid,
                      RunOptions(quiet=quiet, init=init_ck, meta=meta), confidence_gate=gate, calibration=cal)
