"""Training corners at scale: ``holodata synth --corners N --frames K --out DS.zarr``.

A model that reconstructs the hidden side of corners it never saw needs many corners, not many
frames of a few (16 training corners beat 4 at equal steps, benchmarks/results/nlos.md). A corpus is
one dataset of ``N`` procedurally varied corners × ``K`` radar rotations, written straight from the
simulation, without the recordings, LiDAR, camera or mapping pass that ``holodata demo`` goes
through:

* **corner** ``i``: kind ``CORNER_TYPES[i % 4]`` (every kind equally often), its world drawn from
  its own seed (:func:`holodata.synth.worlds.make_world`: widths 1.3-4.7 m, hidden-branch width,
  height, lengths, mirroring, materials and their RF losses, recesses, pillars, boxes); a hidden
  person (height, walk, speed, pose) in ``hidden_person`` of the corners, 1-2 people walking in the
  robot's corridor in ``visible_walkers`` of them; the radar's mounting (height 0.38-0.5 m, yaw) and
  the robot's path from the scenario's seed, its stop point drawn 0.4-2.5 m short of the junction
  in half of the corners (else the world's 0.6-1.2 m). Corner ``i``'s draws depend only on
  ``(seed, i)``: the first 16 corners of a 256-corner corpus are the 16-corner corpus.
* **heatmaps**: the demo's radar model (:meth:`holodata.synth.scene.Sensors.radar_frame`: specular
  multi-bounce paths, the beamformer's point-spread function, noise), direct heatmaps; or, with
  ``radar_output="iq"``, every rotation's raw FMCW samples (:meth:`~holodata.synth.scene.Sensors.radar_rotation`)
  beamformed as ``holodata ingest`` beamforms a rig's (:func:`holodata.radar.beamform.beamform_recorded`,
  near-field focus, the odometry's motion): the road a rig records, its ground truth the same.
* **ground truth**: ``holodata raytrace-gt``'s own code (:func:`holodata.groundtruth.raytrace_dataset`)
  on the true mesh and the per-frame people, from the beam origins the scene states (the rotation
  centre, each column at its own time within ``radar/cycle_ns``). The radar is simulated at exactly
  the column poses raytrace-gt derives from the stored frame poses (linear/SLERP between the frames'
  mid-rotation poses, held at the ends), so heatmap and ground truth agree to the bit, wherever the
  robot is.

Each corner is one scene ``c<i>_<kind>``, written by one task (a local process, or a Dask task):
the scene is marked unfinished by stage ``synth`` (scene attribute ``unfinished``, which ``validate``
rejects) in the put that creates it and finished after its GT; a rerun skips finished scenes and
redoes the others (same seed, same bytes). Splits: the last ``n_test`` corners are the test split,
the rest train; the dataset root is marked unfinished by ``synth`` from the start of the command to
after the splits, so a corpus whose command did not finish never validates either.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..conventions import Grid, LogCode, RangeBins
from ..errors import InputError
from .topics import RADAR_OUTPUTS
from .worlds import CORNER_TYPES

CREATED_BY = "holodata synth --corners"
RERUN = "rerun the same holodata synth --corners command (same --out and settings) to finish it"
SCENE_TRIES = 8  # draws of a corner's seed until the person can hide from the robot's whole path


@dataclass(frozen=True)
class CorpusConfig:
    """A corpus: ``corners`` N ≥ 1 scenes of ``frames`` K ≥ 1 radar rotations (2 Hz) on ``grid`` ×
    ``range_bins``; ``seed`` the corpus seed; ``n_test`` the last corners form the test split;
    ``hidden_person`` / ``visible_walkers`` the fractions of corners with a hidden person / people
    in the robot's corridor; ``heatmap_dtype`` float16 or float32 (linear amplitude) or uint8
    (log-amplitude codes, :class:`holodata.conventions.LogCode`); ``radar_output`` "heatmap" (the
    direct heatmaps) or "iq" (raw samples of ``radar_chirps`` chirp positions per rotation, None:
    the radar's 1024, beamformed on the way in)."""

    corners: int
    frames: int = 4
    grid: Grid = field(default_factory=lambda: Grid(32, 128))
    range_bins: RangeBins = field(default_factory=RangeBins)
    seed: int = 0
    n_test: int = 0
    hidden_person: float = 0.85
    visible_walkers: float = 0.35
    heatmap_dtype: str = "float16"
    radar_output: str = "heatmap"
    radar_chirps: int | None = None

    def check(self) -> None:
        if self.corners < 1:
            raise InputError(f"--corners must be >= 1, got {self.corners}")
        if self.frames < 1:
            raise InputError(f"--frames must be >= 1, got {self.frames}")
        if self.heatmap_dtype not in ("float16", "float32", "uint8"):
            raise InputError(f"heatmap dtype must be float16, float32 or uint8, got {self.heatmap_dtype!r}")
        if self.radar_output not in RADAR_OUTPUTS:
            raise InputError(f"unknown radar output {self.radar_output!r} (choose from {', '.join(RADAR_OUTPUTS)})")
        if not 0 <= self.n_test <= self.corners:
            raise InputError(f"--test must be within 0..{self.corners} corners, got {self.n_test}")


@dataclass(frozen=True)
class CornerSpec:
    """What corner ``index`` of a corpus is: its kind, the scenario seed actually used (after
    redraws), whether a person hides, the visible walkers, the robot's stop (m along the approach
    corridor; None: the world's own)."""

    index: int
    corner: str
    seed: int
    human: bool
    visible_walkers: int
    robot_stop_x: float | None


def corner_kind(index: int) -> str:
    """Corner ``index``'s kind: the kinds in turn, so every kind is equally represented."""
    return CORNER_TYPES[index % len(CORNER_TYPES)]


def scene_id(index: int) -> str:
    return f"c{index:04d}_{corner_kind(index)}"


def draw_corner(cfg: CorpusConfig, index: int, attempt: int = 0) -> CornerSpec:
    """Corner ``index``'s draws, from ``(cfg.seed, index, attempt)`` alone."""
    rng = np.random.default_rng([int(cfg.seed) % 2**32, index, attempt, 0x42])
    seed = int(rng.integers(2**31))
    human = bool(rng.random() < cfg.hidden_person)
    walkers = int(rng.integers(1, 3)) if rng.random() < cfg.visible_walkers else 0
    stop = float(rng.uniform(-2.5, -0.4)) if rng.random() < 0.5 else None
    return CornerSpec(index, corner_kind(index), seed, human, walkers, stop)


def build_corner(cfg: CorpusConfig, index: int):
    """(CornerSpec, Scenario) of corner ``index``: the first draw whose person can hide from the robot."""
    from .scene import build_scenario
    from .spec import SceneSpec

    err: Exception | None = None
    for attempt in range(SCENE_TRIES):
        spec = draw_corner(cfg, index, attempt)
        try:
            sc = build_scenario(SceneSpec(corner=spec.corner, frames=cfg.frames, seed=spec.seed, human=spec.human,
                                          grid=cfg.grid, range_bins=cfg.range_bins, visible_walkers=spec.visible_walkers,
                                          robot_stop_x=spec.robot_stop_x, radar_output=cfg.radar_output,
                                          radar_chirps=cfg.radar_chirps))
        except InputError as e:
            err = e
            continue
        return spec, sc
    raise InputError(f"corpus corner {index}: no draw in {SCENE_TRIES} lets the person hide ({err})")


def frame_timing(sc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame stamps (K,) int64 ns (the middle of each rotation), rotation cycles (K,2) int64 ns and
    T_world_radar (K,4,4) at the stamps (true trajectory), for the scenario's K rotations."""
    cycles = np.array([sc.radar_cycle(k) for k in range(sc.frames)], np.int64)
    mid = (cycles[:, 0] + cycles[:, 1]) // 2
    poses = sc.truth.interpolate(mid) @ sc.T_base_radar
    return mid, cycles, poses


def synth_corner(url: str, cfg: CorpusConfig, index: int) -> dict:
    """Write corner ``index`` of the corpus into scene :func:`scene_id` of dataset ``url`` (which
    must exist): inputs, then ground truth, then the finished mark. A finished scene is left as it
    is. Returns the corner's summary (:func:`corner_summary`)."""
    from ..beams import OriginModel, column_poses
    from ..dataset import create_dataset, open_dataset
    from ..dataset.heatmap import ENCODING_ATTR
    from ..dataset.layout import (
        HUMAN_FACES,
        HUMAN_VERTICES,
        MESH_FACE_CLASS,
        MESH_FACES,
        MESH_VERTICES,
        POSE_T_WORLD_RADAR,
        RADAR_CYCLE_NS,
        RADAR_HEATMAP,
        TIME_TIMESTAMP_NS,
    )
    from ..groundtruth import GTConfig, raytrace_dataset
    from ..radar.beamform import beamform_attrs
    from ..trajectory import Trajectory
    from .scene import Sensors, attenuation_db, drop_medians

    sid = scene_id(index)
    ds = open_dataset(url)
    if sid in ds.scenes and not ds.scene(sid).unfinished:
        return ds.scene(sid).attrs["synth"]
    spec, sc = build_corner(cfg, index)
    w = create_dataset(url, grid=cfg.grid, range_bins=cfg.range_bins, created_by=CREATED_BY)
    world = sc.world
    origin = OriginModel()
    info = corner_summary(spec, sc)
    s = w.scene(sid, n_frames=cfg.frames, attrs={
        "frame_sensor": "radar", "corner_type": world.corner, "width_m": float(world.width), "building": "synthetic",
        "source": f"{CREATED_BY} (seed {cfg.seed}, corner {index})",
        "sensors": {"radar": {"beam_origin": origin.to_attrs()}},
        "class_names": {str(k): v for k, v in world.class_names.items()}, "synth": info,
        **({"beamform": beamform_attrs(sc.radar_cfg.imaging()[0], beamform_params(cfg), sc.radar_cfg.chirps_per_rotation,
                                       motion_compensation="the odometry's travel over each rotation",
                                       padding="neighbouring rotations' chirps, the first and last rotation's own")}
           if cfg.radar_output == "iq" else {})},
        stage="synth", rerun=RERUN)
    t, cycles, poses = frame_timing(sc)
    traj = Trajectory(t, poses)
    sensors = Sensors(sc)
    heat, humans, stats = [], [], []
    code = LogCode() if cfg.heatmap_dtype == "uint8" else None
    for k in range(cfg.frames):
        if cfg.radar_output == "iq":
            hm, st = _beamformed_rotation(sensors, cfg, k, cycles[k])
        else:
            T_cols = column_poses(traj, k, cfg.grid, origin, cycles[k])   # the poses raytrace-gt will trace from
            hm, st = sensors.radar_frame(k, T_cols)
        heat.append(code.encode(hm) if code is not None else hm.astype(cfg.heatmap_dtype))
        stats.append(st)
        humans.append(sc.dynamic_mesh(int(t[k]))[0])   # None without anybody
    for name, shape, data in ((TIME_TIMESTAMP_NS, (), t), (RADAR_CYCLE_NS, (2,), cycles),
                              (POSE_T_WORLD_RADAR, (4, 4), poses)):
        _write_frames(s.frame_array(name, per_frame_shape=shape), data)
    _write_frames(s.frame_array(RADAR_HEATMAP, per_frame_shape=heat[0].shape, dtype=cfg.heatmap_dtype,
                                attrs={ENCODING_ATTR: code.to_attrs()} if code is not None else None), heat)
    s.write_array(MESH_VERTICES, world.vertices.astype(np.float32))
    s.write_array(MESH_FACES, world.faces.astype(np.int32))
    s.write_array(MESH_FACE_CLASS, world.face_class.astype(np.uint8))
    hv, hf = s.ragged_array(HUMAN_VERTICES), s.ragged_array(HUMAN_FACES)
    for k in range(hv.n_shards):
        fr = range(*hv.frames(k).indices(cfg.frames))
        hv.write_shard(k, [np.zeros((0, 3), np.float32) if humans[f] is None else humans[f][0].astype(np.float32)
                           for f in fr])
        hf.write_shard(k, [np.zeros((0, 3), np.int32) if humans[f] is None else humans[f][1].astype(np.int32)
                           for f in fr])
    att = attenuation_db(drop_medians(stats))
    if att is not None:
        s.set_attrs({"attenuation_db": att})
    raytrace_dataset(url, [sid], GTConfig(nthreads=1), quiet=True, processes=1, unfinished_ok=True)
    # (a scene begun by an older holodata carries ingest.complete false as its mark: finished here too)
    s.finish("synth", {"ingest": {"complete": True, "by": CREATED_BY}} if "ingest" in s.attrs else None)
    return info


def _beamformed_rotation(sensors, cfg: CorpusConfig, k: int, cycle: np.ndarray) -> tuple[np.ndarray, dict]:
    """Rotation ``k``'s raw samples beamformed as ingest beamforms a rig's: ((n_range, H, W) float32, stats)."""
    from ..radar.beamform import beamform_recorded

    r, st = sensors.radar_rotation(k)
    hm = beamform_recorded(r["chirps"], (r["n_before"], r["n_rotation"], r["n_after"]),
                           (r["travel_per_chirp"], r["heading"]), (int(cycle[1]) - int(cycle[0])) * 1e-9,
                           sensors.sc.radar_cfg.imaging()[0], beamform_params(cfg))
    return hm, st


def beamform_params(cfg: CorpusConfig):
    """The beamformer's parameters of a ``radar_output="iq"`` corpus: its grid and range bins, near-field
    focus (``holodata demo``'s, :class:`holodata.demo.DemoConfig`)."""
    from ..radar.beam_geometry import BeamformParams

    return BeamformParams(grid=cfg.grid, n_range=cfg.range_bins.n, focus="near")


def _write_frames(arr, data) -> None:
    """All shards of frame array writer ``arr`` from ``data`` (K frames, stacked or a list)."""
    for k in range(arr.n_shards):
        arr.write_shard(k, data[arr.frames(k)])


def corner_summary(spec: CornerSpec, sc) -> dict:
    """JSON-able facts of one corner (scene attrs ``synth``; what :func:`span_lines` sums up)."""
    w = sc.world
    walk = sc.walk
    feats = [f["kind"] for f in w.features]
    origin, u, L, bw = w.hidden_axis
    robot = sc.truth.poses[-1][:2, 3]
    return {**asdict(spec), "scene": scene_id(spec.index), "width_m": round(float(w.width), 3),
            "hidden_width_m": round(float(w.hidden_width), 3), "height_m": round(float(w.height), 3),
            "mirrored": bool(w.mirrored), "hidden_length_m": round(float(L), 3),
            "materials": sorted({w.materials[int(m)].name for m in np.unique(w.face_material)}),
            "features": {k: feats.count(k) for k in sorted(set(feats))},
            "radar_height_m": round(float(sc.T_base_radar[2, 3]), 3),
            "robot_to_junction_m": round(float(-robot[0]), 3),
            "person_height_m": round(float(walk.height), 3) if walk is not None else None,
            "person_speed_mps": round(float(walk.speed), 3) if walk is not None else None}


def span_lines(rows: list[dict]) -> list[str]:
    """What a corpus spans, a few lines: kinds, widths, heights, lengths, mirroring, materials,
    clutter, people, the radar's height and the robot's distance to the junction."""
    def rng_(key, unit="m", fmt=".2f"):
        v = [r[key] for r in rows if r.get(key) is not None]
        return f"{min(v):{fmt}}-{max(v):{fmt}} {unit}" if v else "none"

    kinds = {k: sum(r["corner"] == k for r in rows) for k in CORNER_TYPES}
    mats = sorted({m for r in rows for m in r["materials"]})
    feats: dict = {}
    for r in rows:
        for k, n in r["features"].items():
            feats[k] = feats.get(k, 0) + n
    people = sum(r["human"] for r in rows)
    standing = sum(r["human"] and r.get("person_speed_mps") == 0 for r in rows)
    empty = sum(not r["human"] and not r["visible_walkers"] for r in rows)
    return [
        f"corners {len(rows)}: " + ", ".join(f"{k} {n}" for k, n in kinds.items()) +
        f"; mirrored {sum(r['mirrored'] for r in rows)}",
        f"width {rng_('width_m')}, hidden branch {rng_('hidden_width_m')} wide and {rng_('hidden_length_m')} long, "
        f"height {rng_('height_m')}",
        f"materials {', '.join(mats)}; clutter " + (", ".join(f"{k} {n}" for k, n in sorted(feats.items())) or "none"),
        f"hidden person in {people} corners ({standing} standing still, {people - standing} walking; height "
        f"{rng_('person_height_m')}, speed {rng_('person_speed_mps', 'm/s')}), visible walkers in "
        f"{sum(r['visible_walkers'] > 0 for r in rows)}, nobody in {empty}",
        f"radar height {rng_('radar_height_m')}, robot {rng_('robot_to_junction_m')} short of the junction",
    ]


def synth_corpus(url: str, cfg: CorpusConfig, processes: int = 0, client=None, quiet: bool = False) -> dict:
    """Write (or finish) the corpus ``cfg`` into dataset ``url``: one task per corner, in
    ``processes`` local processes (0: one per CPU) or on a Dask ``client``; then the splits.
    Returns {"dataset", "corners": [summary...], "span": [lines], "seconds"}."""
    import time

    from ..dataset import create_dataset, open_dataset
    from ..errors import DatasetError

    cfg.check()
    t0 = time.perf_counter()
    mine = corpus_attrs(cfg)
    try:
        theirs = (open_dataset(url).meta.get("provenance") or {}).get("corpus")
    except DatasetError:
        theirs = None   # no dataset there yet (create_dataset names any other problem)
    default = corpus_attrs(CorpusConfig(corners=1))   # a field newer than the corpus: its default then
    diff = [k for k in mine if k not in ("corners", "n_test") and theirs is not None
            and theirs.get(k, default.get(k)) != mine[k]]
    if diff:
        def text(k, v):
            if k == "grid" and isinstance(v, dict):
                return f"{v.get('H')}x{v.get('W')}"
            if k == "range_bins" and isinstance(v, dict):
                return f"{v.get('n')} x {v.get('dr')} m"
            return str(v)

        what = ", ".join(f"{k} {text(k, theirs.get(k))} (asked: {text(k, mine[k])})" for k in diff)
        raise InputError(f"{url}: holds a corpus made with other settings: {what}; choose a new --out")
    try:
        w = create_dataset(url, grid=cfg.grid, range_bins=cfg.range_bins, created_by=CREATED_BY,
                           provenance={"corpus": mine})
        have = open_dataset(url)
    except DatasetError as err:
        raise InputError(str(err)) from err
    w.begin("synth", rerun=RERUN)   # the root: until the splits are written
    todo = [i for i in range(cfg.corners)
            if not (scene_id(i) in have.scenes and not have.scene(scene_id(i)).unfinished)]
    rows = _run(url, cfg, todo, processes, client, quiet)
    done = {r["index"]: r for r in rows}
    for i in set(range(cfg.corners)) - set(todo):
        done[i] = have.scene(scene_id(i)).attrs["synth"]
    ids = [scene_id(i) for i in range(cfg.corners)]
    w.set_splits(train=ids[: cfg.corners - cfg.n_test], test=ids[cfg.corners - cfg.n_test:])
    w.finish("synth")
    rows = [done[i] for i in range(cfg.corners)]
    return {"dataset": str(url), "corners": rows, "written": len(todo), "span": span_lines(rows),
            "seconds": round(time.perf_counter() - t0, 2)}


def corpus_attrs(cfg: CorpusConfig) -> dict:
    """JSON form of ``cfg`` (the dataset's provenance ``corpus``)."""
    return {**asdict(cfg), "grid": cfg.grid.to_attrs(), "range_bins": cfg.range_bins.to_attrs()}


def _run(url: str, cfg: CorpusConfig, todo: list[int], processes: int, client, quiet: bool) -> list[dict]:
    from ..progress import track

    if not todo:
        return []
    if client is not None:
        from ..distributed import run_tasks, worker_path

        u = worker_path(url)
        return run_tasks(client, synth_corner, [(u, cfg, i) for i in todo], [f"corpus-{scene_id(i)}" for i in todo],
                         description="synth corners", quiet=quiet)
    from ..parallel import cpus

    n = min(processes or cpus(), len(todo))
    if n <= 1:
        return [synth_corner(url, cfg, i) for i in track(todo, total=len(todo), description="synth corners", quiet=quiet)]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    # spawned, not forked: the tracing (open3d, TBB/OpenMP threads) must not inherit a parent's thread state
    with ProcessPoolExecutor(n, mp_context=mp.get_context("spawn")) as ex:
        futs = [ex.submit(synth_corner, url, cfg, i) for i in todo]
        return [f.result() for f in track(futs, total=len(futs), description="synth corners", quiet=quiet)]


__all__ = ["CorpusConfig", "CornerSpec", "draw_corner", "build_corner", "synth_corner", "synth_corpus", "span_lines",
           "scene_id"]
