"""``holodata demo``: the whole pipeline, end to end, on synthetic corners.

    synth (real MCAP recordings + hidden truth/)  →  ingest  →  mapping  →  raytrace-gt
    →  splits  →  validate  →  train  →  evaluate (metrics.json + report.html)

Mapping gives each scene its radar poses, the static mesh and the per-frame human surfaces that
raytrace-gt needs. ``mapping="slam"`` runs holodata's own stages (``holodata slam`` then
``holodata register``) on the ingested LiDAR and camera data; ``mapping="truth"`` copies them from
the recordings' hidden ``truth/`` folders (an oracle: the ground truth is then exact, which
separates mapping errors from learning errors).

Every stage is resumable: rerunning ``demo`` on the same ``out_dir`` skips finished recordings,
shards and epochs.
"""
from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .conventions import Grid, RangeBins
from .dataset.layout import HUMAN_FACES, HUMAN_VERTICES, MESH_FACE_CLASS, MESH_FACES, MESH_VERTICES, POSE_T_WORLD_RADAR
from .errors import InputError
from .ownership import claim_folder, remove_folder

# (corner kind, seed): every kind of the reference dataset is represented; the last ones are held out
DEMO_CORNERS: tuple[tuple[str, int], ...] = (
    ("T", 11), ("L", 12), ("cross", 13), ("oblique", 14), ("T", 15), ("L", 16), ("cross", 17), ("oblique", 18),
)


@dataclass
class DemoConfig:
    """Sizes of one demo run. ``corners``: (kind, seed) per scene, the last ``n_test`` form the test
    split; ``frames``: radar rotations per corner (2 Hz); ``grid``: radar beam grid (H×W);
    ``lidar_shape`` (beams, columns); ``lidar_vertical_fov_deg`` 90 (OS0-like: the SLAM mesh then
    covers the floor and ceiling the radar sees); ``mapping_pass``: each corner is mapped first by a
    LiDAR-only drive through its legs (scene ``<id>_map``, ``mapping_scan_hz`` scans/s) and slam
    localises the data pass in that map; ``mesh_poisson_depth``: the SLAM mesh's Poisson octree depth
    (None: from the scene's extent, 8 for a corner); ``camera_shape`` (rows, cols); ``epochs``, ``depth``,
    ``base_channels``, ``max_channels``, ``range_pool``: the model and its training (TrainConfig);
    ``stage2``: the learned stage two's settings (holodata.torch.stage2_train.Stage2Config fields;
    None: the demo stops at stage one and evaluate un-mirrors analytically); ``radar_output``:
    "heatmap" records the direct heatmaps; "iq" every rotation's raw samples (``radar_chirps`` chirp
    positions, default 1024) which ingest beamforms onto ``grid``, as a real rig's data goes;
    ``beamform_focus``: the beamformer's focus for ``"iq"`` ("near": every range bin focused with the
    exact antenna distances; "far": PanoRadar's far-field compensation; docs/design/radar.md);
    ``range_loss``: stage one's range term (TrainConfig.range_loss: "l1" or "ce"); ``lr``: stage
    one's AdamW learning rate (TrainConfig.lr; stage two's is ``stage2``'s ``lr``); ``init``: the run
    directory both stages fine-tune from (``"pretrained"``: the weights holodata ships; its model
    settings must be these, else one InputError line), None: trained from scratch."""

    corners: tuple[tuple[str, int], ...]
    n_test: int
    frames: int
    grid: Grid
    lidar_shape: tuple[int, int]
    camera_shape: tuple[int, int]
    epochs: int
    depth: int
    batch_size: int = 4
    base_channels: int = 16
    max_channels: int = 128
    range_pool: int = 1
    lidar_vertical_fov_deg: float = 90.0
    range_bins: RangeBins = field(default_factory=RangeBins)
    mapping_pass: bool = True
    mapping_scan_hz: float = 2.0
    mesh_poisson_depth: int | None = None
    stage2: dict | None = None
    radar_output: str = "heatmap"
    radar_chirps: int | None = None
    beamform_focus: str = "near"
    range_loss: str = "l1"
    lr: float = 2e-3
    init: str | None = None

    def beamform(self):
        """The ingest beamformer's parameters for ``radar_output="iq"`` (None otherwise): the grid's rows,
        columns and elevations, the range bins kept."""
        if self.radar_output != "iq":
            return None
        from .radar.beam_geometry import BeamformParams

        return BeamformParams(grid=self.grid, n_range=self.range_bins.n, focus=self.beamform_focus)


def default_radar_output(quick: bool) -> str:
    """What ``holodata demo`` records by default: raw samples beamformed by ingest with near-field
    focusing for the quick demo (it then scores like the direct heatmaps, docs/design/radar.md
    §"Synthetic raw samples"), the direct heatmaps for the full one (320 full-size rotations of raw
    samples are slow to synthesise: docs/design/radar.md). :func:`demo_config` itself keeps
    ``"heatmap"`` (the benchmarks that build on it measure that road)."""
    return "iq" if quick else "heatmap"


# the quick demo fine-tunes the shipped weights (holodata.torch.pretrained, trained at its 32x128 grid):
# stage one 2 epochs at a quarter of the from-scratch learning rate (2e-3 for 1-2 epochs undoes part
# of what they learnt), stage two one refiner epoch on 2 frames per corner with the shipped ray
# tracer kept (ray-tracer epochs bought nothing on the held-out corner); the operating points (stage
# one's confidence gate, stage two's keep and human thresholds) are calibrated anew on the demo's
# training corners. The measurements behind the choice: benchmarks/results/demo-finetune.md
QUICK_FINETUNE = {"epochs": 2, "lr": 5e-4, "range_loss": "ce", "init": "pretrained",
                  "stage2": {"epochs_rt": 0, "epochs_refine": 1, "channels": 16, "lr": 5e-4, "frames_per_scene": 2}}


def demo_config(quick: bool, from_scratch: bool = False) -> DemoConfig:
    """``quick``: small grids and few frames (its run time: README), both stages fine-tuned from the
    shipped weights (:data:`QUICK_FINETUNE`) unless ``from_scratch``; else the paper's 64×512 grid
    (which the shipped weights do not fit: trained from scratch)."""
    if quick:
        # a 2.4 m wide cross for DEMO_CORNERS' 4 m one: at the quick demo's 32x128 beams the radar
        # reaches the hidden side of the 4 m cross with few GT NLOS points (docs/design/synth.md)
        corners = tuple(("cross", 21) if c == ("cross", 13) else c for c in DEMO_CORNERS[:6])
        cfg = DemoConfig(corners=corners, n_test=1, frames=12, grid=Grid(32, 128),
                         lidar_shape=(32, 512), camera_shape=(376, 672), epochs=15, depth=6,
                         base_channels=8, max_channels=64, range_pool=2,
                         stage2={"epochs_rt": 3, "epochs_refine": 2, "channels": 16}, radar_chirps=512)
        if from_scratch:
            return cfg
        import dataclasses

        return dataclasses.replace(cfg, **QUICK_FINETUNE)
    return DemoConfig(corners=DEMO_CORNERS, n_test=2, frames=40, grid=Grid(), lidar_shape=(64, 1024),
                      camera_shape=(376, 672), epochs=30, depth=7,
                      stage2={"epochs_rt": 12, "epochs_refine": 10, "channels": 32})


@dataclass
class DemoResult:
    """Where the demo's outputs are and what it measured. ``metrics``: the metrics.json document;
    ``timings``: seconds per stage; ``mapping``: "slam" or "truth"; ``warnings``: one line per
    scene whose mapping was incomplete; ``pretrained``: the metrics document of the shipped weights on
    the same test split (:func:`evaluate_pretrained`), or None."""

    out_dir: Path
    dataset: Path
    run_dir: Path
    report: Path
    mapping: str
    metrics: dict
    timings: dict
    validation: dict
    warnings: list = field(default_factory=list)
    pretrained: dict | None = None


def scene_id(corner: str, seed: int) -> str:
    return f"{corner}_{seed}"


def map_scene_id(sid: str) -> str:
    """The scene id of a corner's mapping pass (``<scene id>_map``)."""
    return f"{sid}_map"


def run_demo(out_dir, quick: bool = False, mapping: str = "slam", quiet: bool = False,
             config: DemoConfig | None = None, log=None, keep_recordings: bool = False) -> DemoResult:
    """Run the demo into ``out_dir`` (created; reused when rerun). ``log(str)`` receives one line
    per stage (default: silent). Once a corner's recordings are ingested they are removed (the MCAP
    files, ~0.3 GB a quick-demo corner; its ``truth/`` stays), unless ``keep_recordings``: only
    the ones this demo's synth wrote (:func:`remove_ingested_recordings`); a rerun then takes those
    corners from the dataset."""
    import importlib

    # every stage's package before any work: a missing extra (torch: train) stops the demo before it
    # claims out_dir, not after its first stages (each stage imports its entry points where it runs)
    for package in ("dataset", "evaluate", "groundtruth", "ingest", "torch"):
        importlib.import_module(f"holodata.{package}")
    cfg = config or demo_config(quick)
    mapping = resolve_mapping(mapping)
    say = log or (lambda _msg: None)
    out = Path(out_dir)
    claim_folder(out, "holodata demo")   # a new or empty folder, or an earlier demo's (holodata.ownership)
    return _Demo(cfg, mapping, out, quiet, say, keep_recordings).run()


@dataclass
class _Demo:
    """One demo run into the claimed folder ``out``: ``cfg``, ``mapping`` ("slam" or "truth"),
    ``quiet``, ``say`` and ``keep_recordings`` as :func:`run_demo`'s; ``timings``: the seconds each
    finished stage took (said one line each through ``say``)."""

    cfg: DemoConfig
    mapping: str
    out: Path
    quiet: bool
    say: Callable[[str], None]
    keep_recordings: bool
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def url(self) -> Path:
        """The demo's dataset."""
        return self.out / "dataset.zarr"

    def run(self) -> DemoResult:
        """synth → ingest → mapping → raytrace-gt (+ the splits) → validate → train → evaluate."""
        cfg, url = self.cfg, self.url
        with self._stage("synth"):
            recs = synthesize_corners(self.out / "recordings", cfg, quiet=self.quiet, ingested=ingested_scenes(url))
        with self._stage("ingest"):
            ids, maps, w = self._ingest(recs)
        with self._stage(f"mapping:{self.mapping}"):
            warnings = self._map(recs, ids, maps, w)
        with self._stage("raytrace-gt"):
            self._raytrace(ids, w)
        with self._stage("validate"):
            report = self._validate()
        run_dir = self._train()
        doc, pretrained = self._evaluate(run_dir)
        (self.out / "demo.json").write_text(json.dumps({"mapping": self.mapping, "timings": self.timings,
                                                        "warnings": warnings, "scenes": ids,
                                                        "test": ids[-cfg.n_test:]}, indent=2))
        return DemoResult(out_dir=self.out, dataset=url, run_dir=run_dir, report=self.out / "report" / "report.html",
                          mapping=self.mapping, metrics=doc, timings=self.timings, validation=report,
                          warnings=warnings, pretrained=pretrained)

    @contextmanager
    def _stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name`` (not recorded when it raises)."""
        t0 = time.perf_counter()
        yield
        self._record(name, t0)

    def _record(self, name: str, t0: float) -> None:
        self.timings[name] = round(time.perf_counter() - t0, 2)
        self.say(f"{name:<12} {self.timings[name]:6.1f} s")

    def _ingest(self, recs: dict) -> tuple[list[str], dict, object]:
        """Ingest the recordings synth wrote (each corner's data pass, and its mapping pass as scene
        ``<id>_map``); mark the dataset unfinished until the splits; give each scene its truth's
        attrs; remove the ingested recordings unless ``keep_recordings``. Returns (scene ids,
        mapping scene per scene, the dataset writer)."""
        from .dataset import create_dataset
        from .ingest import IngestOptions, ingest

        cfg, url, quiet = self.cfg, self.url, self.quiet
        ids = list(recs)
        maps = {s: map_scene_id(s) for s in ids if cfg.mapping_pass}
        todo = [(str(recs[s].recording), s) for s in ids if recs[s].recording is not None] + \
               [(str(recs[s].mapping_recording), maps[s]) for s in maps if recs[s].mapping_recording is not None]
        if todo:   # (a rerun after the recordings were ingested and removed has none left)
            ingest([r for r, _ in todo], str(url), IngestOptions(beamform=cfg.beamform()), scene_ids=[s for _, s in todo],
                   quiet=quiet)
        w = create_dataset(str(url), grid=cfg.grid, range_bins=cfg.range_bins, created_by="holodata demo")
        w.begin("demo", rerun="rerun holodata demo with the same --out to finish it")   # the root: until the splits
        for sid in ids:
            w.scene(sid).set_attrs(truth_scene_attrs(recs[sid].truth_dir))
        if not self.keep_recordings:
            remove_ingested_recordings(self.out / "recordings", ids, maps, url, self.say)
        return ids, maps, w

    def _map(self, recs: dict, ids: list[str], maps: dict, w) -> list[str]:
        """Poses, mesh and humans per scene: holodata slam + register, or the synthetic truth. Returns
        the warnings (one line per scene whose mapping was incomplete)."""
        warnings: list[str] = []
        if self.mapping == "slam":
            for note in map_scenes_with_slam(str(self.url), ids, maps, quiet=self.quiet,
                                             mesh_poisson_depth=self.cfg.mesh_poisson_depth):
                if note:
                    warnings.append(note)
                    self.say(f"warning: {note}")
        else:
            for sid in ids:
                map_from_truth(w.scene(sid), recs[sid].truth_dir)
        return warnings

    def _raytrace(self, ids: list[str], w) -> None:
        """The ground truth of every scene, then the splits (the last ``n_test`` corners held out),
        which finish the dataset."""
        from .groundtruth import GTConfig, raytrace_dataset

        # the beams the recordings state (synth: from the rotation centre, each column at its own time)
        raytrace_dataset(str(self.url), ids, GTConfig(), quiet=self.quiet)
        w.set_splits(train=ids[: -self.cfg.n_test], test=ids[-self.cfg.n_test:])
        w.finish("demo")

    def _validate(self) -> dict:
        """The dataset's validation report; InputError naming its first problems when it fails."""
        from .dataset import validate_dataset

        url = self.url
        report = validate_dataset(str(url), quiet=self.quiet)
        if not report["ok"]:
            lines = "; ".join(p["line"] for p in report["problems"][:3])
            raise InputError(f"{url}: the demo dataset does not validate ({report['n_problems']} problems: {lines})")
        return report

    def _train(self) -> Path:
        """Stage one (fine-tuned from ``cfg.init`` when set) and, with ``cfg.stage2``, stage two into
        ``out``/run; returns that run directory."""
        from .torch import TrainConfig, train

        cfg, url, quiet = self.cfg, self.url, self.quiet
        run_dir = self.out / "run"
        with self._stage("train"):
            init = None
            if cfg.init is not None:
                from .torch.pretrained import resolve

                try:
                    init = resolve(cfg.init, cfg.grid)
                except InputError as err:
                    raise InputError(f"{err}; or train the demo's model from scratch (holodata demo --from-scratch)") \
                        from err
            train(str(url), run_dir, TrainConfig(epochs=cfg.epochs, depth=cfg.depth, batch_size=cfg.batch_size,
                                                 base_channels=cfg.base_channels, max_channels=cfg.max_channels,
                                                 range_pool=cfg.range_pool, range_loss=cfg.range_loss, lr=cfg.lr),
                  quiet=quiet, init=init)
        if cfg.stage2 is not None:
            from .torch.stage2_train import Stage2Config, train_stage2

            with self._stage("train:stage2"):
                train_stage2(str(url), run_dir, Stage2Config.from_dict(cfg.stage2), quiet=quiet, init=init)
        return run_dir

    def _evaluate(self, run_dir: Path) -> tuple[dict, dict | None]:
        """The run scored on the test split (report in ``out``/report), then the shipped weights
        where they fit (:func:`evaluate_pretrained`). Returns both metrics documents (the second
        None when the weights were not scored)."""
        from .evaluate import Evaluation

        with self._stage("evaluate"):
            doc = Evaluation(str(self.url), run_dir, self.out / "report", split="test", quiet=self.quiet).run()
        t0 = time.perf_counter()
        pretrained = evaluate_pretrained(self.url, self.out / "report_pretrained", self.quiet, self.say, report=False)
        if pretrained is not None:
            self._record("evaluate:pretrained", t0)
        return doc, pretrained


def evaluate_pretrained(url, out_dir: Path, quiet: bool, say, report: bool = True) -> dict | None:
    """The shipped weights (holodata.torch.pretrained, trained on hundreds of other corners) scored
    on the demo's test split beside the model the demo trains, when the dataset has the grid and range
    bins they were trained for (the quick demo's); None otherwise (said in one line). ``report``:
    also their report.html, figures and ``oracle_stage1`` row (the demo prints their model rows and
    writes their metrics.json only)."""
    from .dataset import open_dataset
    from .evaluate import Evaluation
    from .torch.checkpoint import load_checkpoint
    from .torch.pretrained import resolve
    from .torch.train import check_stage1

    try:
        ds = open_dataset(str(url))
        weights = resolve("pretrained", ds.grid)
        check_stage1(load_checkpoint(weights), ds, weights)
    except InputError as err:
        say(f"pretrained weights not evaluated: {err}")
        return None
    return Evaluation(str(url), "pretrained", out_dir, split="test", quiet=quiet, report=report,
                      oracle_row=report).run()


# the shipped weights' rows in the demo's tables (format_tables pads a row's name to 15 characters)
PRETRAINED_ROWS = {"model": "pretrained", "model_no_refine": "pretr_no_refine", "model_analytic": "pretr_analytic"}


def combined_metrics(doc: dict, pretrained: dict | None) -> dict:
    """The metrics document ``doc`` of the demo's model with the shipped weights' rows of
    ``pretrained`` (same split; None: ``doc`` as it is) after the model's: the model's rows, the
    shipped weights' (:data:`PRETRAINED_ROWS`), then the rest (``baseline``, ``oracle_stage1``: the
    model's run). For :func:`holodata.evaluate.format_tables`."""
    if pretrained is None:
        return doc
    methods = doc["methods"]
    own = [m for m in methods if m.startswith("model")]
    rows = {m: methods[m] for m in own}
    rows.update({PRETRAINED_ROWS[m]: r for m, r in pretrained["methods"].items() if m in PRETRAINED_ROWS})
    rows.update({m: r for m, r in methods.items() if m not in own})
    return {**doc, "methods": rows}


MAPPINGS = ("slam", "truth")


def resolve_mapping(mapping: str) -> str:
    if mapping not in MAPPINGS:
        raise InputError(f"unknown mapping {mapping!r} (choose {' or '.join(MAPPINGS)})")
    return mapping


def synthesize_corners(rec_dir: Path, cfg: DemoConfig, quiet: bool = True, ingested=frozenset()) -> dict:
    """One MCAP recording per corner under ``rec_dir/<scene id>/`` (with ``cfg.mapping_pass`` also its
    mapping pass, ``mapping/``); existing ones of the same kind (mapping pass, radar output) are
    reused, and so are corners whose recordings the demo removed once ``ingested`` (scene ids
    complete in the dataset) held them (their ``truth/`` is kept; .recording and .mapping_recording
    are then None). Returns {scene id: SynthResult-like object with .recording, .truth_dir and
    .mapping_recording (None without a mapping pass)}, in corner
    order. On two or more CPUs every other corner is synthesised in a forked process (synth is
    single-threaded; the recordings are the same either way)."""
    from .parallel import cpus, fork_call

    out, jobs = {}, []
    for corner, seed in cfg.corners:
        sid = scene_id(corner, seed)
        d = rec_dir / sid
        sj = d / "truth" / "scene.json"
        scene = json.loads(sj.read_text()) if sj.is_file() else None
        same = scene is not None and ("mapping_pass" in scene) == bool(cfg.mapping_pass) \
            and ("radar_output" in scene) == (cfg.radar_output == "iq")   # synth records it for raw I/Q only
        if same and (d / "recording").exists():
            out[sid] = _Existing(recording=d / "recording", truth_dir=d / "truth",
                                 mapping_recording=d / "mapping" if cfg.mapping_pass else None)
            continue
        if same and sid in ingested and (not cfg.mapping_pass or map_scene_id(sid) in ingested):
            out[sid] = _Existing(recording=None, truth_dir=d / "truth")   # ingested, then removed
            continue
        if d.exists():  # a recording cut off half-way: start that corner again
            remove_folder(d, "holodata demo")
        jobs.append((sid, d, corner, seed))
    if len(jobs) > 1 and cpus() >= 2:
        other = fork_call(_synth_jobs, jobs[1::2], cfg, True, 1, label="demo: synth (second process)")
        try:
            out.update(_synth_jobs(jobs[0::2], cfg, quiet, 1))
        finally:
            done = other()
        out.update(done)
    else:
        out.update(_synth_jobs(jobs, cfg, quiet))
    return {scene_id(c, s): out[scene_id(c, s)] for c, s in cfg.corners}


def _synth_jobs(jobs: list, cfg: DemoConfig, quiet: bool, threads: int | None = None) -> dict:
    """{scene id: SynthResult} of ``jobs`` [(scene id, folder, corner, seed)], one after the other, the
    compiled kernels on ``threads`` threads (:func:`holodata.parallel.kernel_threads`)."""
    from .parallel import kernel_threads
    from .synth import SynthSpec, synthesize

    with kernel_threads(threads):
        return {sid: synthesize(d, SynthSpec(corner=corner, frames=cfg.frames, seed=seed, grid=cfg.grid,
                                             range_bins=cfg.range_bins, lidar_shape=cfg.lidar_shape,
                                             camera_shape=cfg.camera_shape,
                                             lidar_vertical_fov_deg=cfg.lidar_vertical_fov_deg,
                                             mapping_pass=cfg.mapping_pass, mapping_scan_hz=cfg.mapping_scan_hz,
                                             radar_output=cfg.radar_output, radar_chirps=cfg.radar_chirps),
                                quiet=quiet)
            for sid, d, corner, seed in jobs}


@dataclass
class _Existing:
    recording: Path | None
    truth_dir: Path
    mapping_recording: Path | None = None


def ingested_scenes(url) -> set[str]:
    """The scene ids the dataset at ``url`` holds completely ingested (none when there is no dataset yet)."""
    from .dataset import open_dataset
    from .errors import HolodataError

    try:
        ds = open_dataset(str(url))
    except HolodataError:
        return set()
    done = set()
    for sid in ds.scenes:
        a = ds.scene(sid).attrs
        if (a.get("ingest") or {}).get("complete") and "ingest" not in (a.get("unfinished") or {}):
            done.add(sid)
    return done


def remove_ingested_recordings(rec_dir: Path, ids: list[str], maps: dict, url, say=None) -> int:
    """Remove the MCAP recordings (``recording/``, ``mapping/``) of the corners ``ids`` whose scenes
    (and mapping passes, ``maps``) the dataset at ``url`` holds completely ingested; ``truth/`` stays.
    Only what the demo's synth wrote goes: an entry of the corner folder's manifest that still matches
    what synth recorded (:meth:`holodata.ownership.OutputDir.owns`); anything else (a user's file
    added, a symlink) is left alone and named in one line to ``say``. Returns the bytes removed."""
    from .ownership import OutputDir

    done, freed = ingested_scenes(url), 0
    for sid in ids:
        d = Path(rec_dir) / sid
        if sid not in done or (sid in maps and maps[sid] not in done) or not d.is_dir():
            continue
        od = OutputDir(d, "holodata demo")
        for name in ("recording", "mapping"):
            if not ((d / name).is_dir() or (d / name).is_symlink()):
                continue
            if od.owns(name):
                freed += sum(f.stat().st_size for f in (d / name).rglob("*") if f.is_file() and not f.is_symlink())
                od.remove(name)
            elif say is not None:
                say(f"kept {d / name}: not as holodata's synth wrote it (a symlink or changed since); remove it yourself")
    return freed


def truth_scene_attrs(truth_dir: Path) -> dict:
    """Scene attributes a user would know about a recorded corner (kind, width, building), taken
    from the synthetic scene description; the evaluation breaks results down by them."""
    d = json.loads((Path(truth_dir) / "scene.json").read_text())
    attrs = {"corner_type": d["corner_type"], "width_m": float(d["width_m"]), "building": "synthetic"}
    from .synth.scene import attenuation_db

    att = attenuation_db(d.get("stats") or {})
    if att is not None:
        attrs["attenuation_db"] = att
    return attrs


def map_from_truth(sc, truth_dir: Path) -> None:
    """Oracle mapping: radar poses, static mesh (with classes) and per-frame human meshes of a
    scene from its synthetic ``truth/`` folder, written as slam/register would write them."""
    from .trajectory import read_tum

    truth_dir = Path(truth_dir)
    traj = read_tum(truth_dir / "trajectory_radar.tum")
    if len(traj) != sc.n_frames:
        raise InputError(f"{truth_dir / 'trajectory_radar.tum'}: {len(traj)} poses for {sc.n_frames} frames")
    with sc.stage("demo", rerun="rerun holodata demo --mapping truth with the same --out to finish it"):
        _write_truth_mapping(sc, truth_dir, traj)


def _write_truth_mapping(sc, truth_dir: Path, traj) -> None:
    """:func:`map_from_truth`'s writes."""
    from .meshio import read_mesh

    sc.remove(POSE_T_WORLD_RADAR)  # ingest's odometry poses drift; the oracle replaces them
    poses = sc.frame_array(POSE_T_WORLD_RADAR, (4, 4), attrs={"source": "truth (oracle mapping)"})
    for k in range(poses.n_shards):
        poses.write_shard(k, traj.poses[poses.frames(k)])

    mesh = read_mesh(truth_dir / "mesh.ply")
    sc.write_array(MESH_VERTICES, mesh.vertices)
    sc.write_array(MESH_FACES, mesh.faces)
    if mesh.face_class is not None:
        sc.write_array(MESH_FACE_CLASS, mesh.face_class)
    if mesh.class_names:
        sc.set_attrs({"class_names": {str(k): v for k, v in dict(mesh.class_names).items()}})

    human_dir = truth_dir / "human"
    if not human_dir.is_dir():
        return
    hv = sc.ragged_array(HUMAN_VERTICES)
    hf = sc.ragged_array(HUMAN_FACES)
    for k in range(hv.n_shards):
        verts, faces = [], []
        for f in range(*hv.frames(k).indices(sc.n_frames)):
            p = human_dir / f"{f:06d}.ply"
            if p.is_file():
                m = read_mesh(p)
                verts.append(m.vertices.astype(np.float32))
                faces.append(m.faces.astype(np.int32))
            else:
                verts.append(np.zeros((0, 3), np.float32))
                faces.append(np.zeros((0, 3), np.int32))
        hv.write_shard(k, verts)
        hf.write_shard(k, faces)


def map_scenes_with_slam(url: str, ids: list[str], maps: dict, quiet: bool = True,
                         mesh_poisson_depth: int | None = None, processes: int | None = None) -> list[str | None]:
    """:func:`map_with_slam` of every scene of ``ids`` (``maps``: {scene id: its mapping pass}); returns
    the warning lines (or None) in the order of ``ids``. With ``processes`` >= 2 (default: 2 on two or
    more CPUs) that many Python processes started fresh (``spawn``) map the scenes: one scene's mapping
    leaves the second core mostly idle (the Poisson reconstruction runs on one thread, and open3d holds
    the GIL, so threads would not help; ``docs/design/performance.md``, the quick demo). Each scene is
    two tasks, its slam and then its register (queued when its slam is done, behind the slams still
    waiting), so the two processes end within about one register of each other rather than one whole
    scene. Not forked: slam's open3d runs worker threads, and a process forked from one that ran them
    can hang (:mod:`holodata.parallel`). Scenes are independent: a task writes only its scene (slam also
    the scene's mapping pass)."""
    from .parallel import cpus

    procs = min(processes if processes is not None else 2, cpus(), len(ids))
    if procs < 2:
        return [map_with_slam(url, sid, quiet, maps.get(sid), mesh_poisson_depth) for sid in ids]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(max_workers=procs, mp_context=mp.get_context("spawn"), initializer=_mapping_worker)
    try:
        slams = {pool.submit(_slam, url, sid, quiet, maps.get(sid), mesh_poisson_depth): sid for sid in ids}
        registers = {}
        for f in as_completed(slams):
            f.result()
            registers[slams[f]] = pool.submit(_register, url, slams[f], quiet)
        return [registers[sid].result() for sid in ids]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _mapping_worker() -> None:
    """Start of a mapping process (:func:`map_scenes_with_slam`): import what slam and register use,
    then freeze those objects out of the garbage collector's generations (``gc.freeze``): the
    collections the stages start with (:func:`holodata.parallel.release_free_memory`) and the
    automatic ones then skip the objects the imports made (the time it saves:
    docs/design/performance.md, the quick demo)."""
    import gc

    from .mapping import register, slam  # noqa: F401  (imported for their objects)

    gc.collect()
    gc.freeze()


def map_with_slam(url: str, sid: str, quiet: bool = True, map_scene: str | None = None,
                  mesh_poisson_depth: int | None = None) -> str | None:
    """holodata's own mapping: ``slam`` (LiDAR poses, radar poses, static mesh; with ``map_scene``
    the mesh from that mapping pass and the scene localised in it) then ``register`` (camera
    extrinsic, per-frame human surfaces). When the camera cannot be registered the scene keeps its
    mesh and poses but has no human: returns that as a warning line (else None). ``mesh_poisson_depth``:
    :class:`~holodata.mapping.mesh.MeshConfig` ``poisson_depth``."""
    _slam(url, sid, quiet, map_scene, mesh_poisson_depth)
    return _register(url, sid, quiet)


def _slam(url: str, sid: str, quiet: bool, map_scene: str | None, mesh_poisson_depth: int | None) -> None:
    """:func:`map_with_slam`'s first half: ``holodata slam`` of the scene."""
    from .mapping.mesh import MeshConfig
    from .mapping.slam import slam_scene

    slam_scene(url, sid, quiet=quiet, map_scene=map_scene, mesh_config=MeshConfig(poisson_depth=mesh_poisson_depth))


def _register(url: str, sid: str, quiet: bool) -> str | None:
    """:func:`map_with_slam`'s second half: ``holodata register`` of the scene (after its slam); the
    warning line or None."""
    from .mapping.register import RegisterConfig, RegistrationError, register_scene

    try:
        # the synth recordings' TF camera pose is the true one (holodata.synth writes truth/extrinsics.json's
        # pose as TF): along a direction the camera's view leaves open, the guess is good to 1 cm
        register_scene(url, sid, cfg=RegisterConfig(guess_std_m=0.01), quiet=quiet)
    except RegistrationError as err:
        return f"{sid}: no human in its ground truth ({' '.join(str(err).split())})"
    return None


__all__ = ["DemoConfig", "DemoResult", "demo_config", "run_demo", "combined_metrics", "QUICK_FINETUNE",
           "map_from_truth", "map_with_slam", "map_scenes_with_slam", "map_scene_id", "synthesize_corners",
           "truth_scene_attrs", "ingested_scenes", "remove_ingested_recordings", "DEMO_CORNERS"]
