"""``holodata ingest`` run over recordings (the package docstring says what each pass does):
:func:`ingest` expands synth output folders into their passes, reads each radar recording's grid in
a pre-pass when several recordings (or Dask) are given, and ingests each recording as one scene
(:func:`ingest_one`: plan, grid check, dataset created on the first success, write pass), locally
or one Dask task per recording (:func:`ingest_dask`). Each recording is opened once
(:func:`open_for_ingest`); whoever opened it closes it."""
from __future__ import annotations

import dataclasses
import uuid
from dataclasses import dataclass
from pathlib import Path

from ..conventions import Grid, RangeBins
from ..errors import HolodataError, InputError, RecordingError, one_line
from ..readers import open_recording
from ..readers.base import Recording
from ..safe_io import check_name
from .roles import RADAR_SUFFIX, load_topics_file, map_topics
from .radar_streams import radar_stream
from .plan import Plan, _grid_of, _limit_malloc_arenas, _scene_id, plan_recording
from .write import write_plan


def ingest(recordings, out, topics=None, scene_ids=None, msg_dir=None, tolerance_ms: float | None = None,
           quiet: bool = True, meta=None, codec: str | None = None, shard_frames: int | None = None,
           client=None, beamform=None, keep_iq: bool = False, motion: str | None = None) -> dict:
    """Ingest ``recordings`` (paths) into the dataset at ``out`` (created or resumed), one scene
    each. ``topics``: dict or YAML path (see :func:`load_topics_file`). Returns the summary
    {dataset, scenes: [...], failed: [{recording, error}], ok}; a recording that fails is reported
    there and the others are still ingested. Raises RecordingError when none could be ingested.
    ``client`` (a ``distributed.Client``): one Dask task per recording (:mod:`holodata.distributed`);
    the recordings must be readable at the same paths on the workers. ``beamform``:
    :class:`~holodata.radar.beam_geometry.BeamformParams` for recordings of raw radar samples (PanoRadar raw
    trajectories), default 64 x 512 beams, all range bins; ``keep_iq``: store their raw samples too
    (``radar/iq``), so that ``holodata beamform`` can re-image them with other parameters; ``motion``:
    "static" | "moving", the robot's motion in every PanoRadar raw trajectory given, instead of
    reading it from their folder names (:func:`holodata.readers.panoradar_raw.motion_rule`)."""
    recordings = [Path(r) for r in recordings]
    if not recordings:
        raise InputError("no recording given")
    if isinstance(topics, (str, Path)):
        topics = load_topics_file(topics)
    if scene_ids is not None:
        scene_ids = list(scene_ids)
        if len(scene_ids) != len(recordings):
            raise InputError(f"{len(scene_ids)} --scene-id for {len(recordings)} recordings (give one per recording)")
        for sid in scene_ids:   # a scene id names folders/keys under the output: never outside it
            check_name(sid, "--scene-id")
    recordings, scene_ids = _passes(recordings, scene_ids)
    if tolerance_ms is not None and tolerance_ms <= 0:
        raise InputError(f"--tolerance must be > 0 ms, got {tolerance_ms}")
    failed: list[dict] = []
    from ..dataset import open_dataset

    try:
        existing = open_dataset(out)
        # a LiDAR-only dataset has no radar grid yet: the first radar recording gives it one
        grid, rb = (existing.grid, existing.range_bins) if existing.meta.get("grid_source") != "default" else (None, None)
    except HolodataError:
        existing, grid, rb = None, None, None
    try:
        from .. import __version__ as version    # holodata's
    except ImportError:  # pragma: no cover
        version = "?"
    opts = IngestOptions(topics=topics, msg_dir=msg_dir, tolerance_ms=tolerance_ms, meta=meta, codec=codec,
                         beamform=beamform, keep_iq=keep_iq, motion=motion, shard_frames=shard_frames,
                         provenance={"tool": "holodata ingest", "version": version})
    opened: dict[int, Recording] = {}   # index -> recording opened by the pre-pass, until its scene is written
    try:
        todo = []
        if existing is None and (len(recordings) > 1 or client is not None):
            # cheap pre-pass: each radar recording's grid (the dataset has one grid for all scenes); the
            # local loop goes on with the recordings it opened, Dask workers open their own
            for i, r in enumerate(recordings):
                try:
                    rec = open_for_ingest(r, opts)
                except (HolodataError, OSError) as err:
                    failed.append({"recording": str(r), "error": one_line(err)})
                    continue
                try:
                    todo.append((i, r, radar_grid(rec, topics, beamform)))
                except (HolodataError, OSError) as err:
                    failed.append({"recording": str(r), "error": one_line(err)})
                    rec.close()
                    continue
                if client is None:
                    opened[i] = rec
                else:
                    rec.close()
            if not todo:
                raise RecordingError(_failures(failed))
            grids = {g for _, _, g in todo if g is not None}
            if len(grids) > 1:
                raise RecordingError(f"recordings have different radar grids "
                                     f"({sorted(str(g[0].to_attrs()) for g in grids)}); ingest them into separate datasets")
            grid, rb = next(iter(grids)) if grids else (None, None)
        else:
            todo = [(i, r, None) for i, r in enumerate(recordings)]
        ids = [scene_ids[i] if scene_ids else _scene_id(r) for i, r, _ in todo]
        ids = [f"{sid}_{k}" if ids.count(sid) > 1 else sid for k, sid in enumerate(ids)]  # same names: suffix
        scenes = []
        if client is not None:  # the dataset exists before the workers write their scenes into it
            made = _create(out, grid, rb, opts)
            scenes, more = ingest_dask(client, todo, ids, out, grid, rb, opts, quiet=quiet)
            failed += more
            todo = []
            if not scenes:   # nothing landed: leave no empty dataset, if (and only if) this run created it
                made.discard()
        for (i, r, _), sid in zip(todo, ids):
            try:
                rec = opened.pop(i) if i in opened else open_for_ingest(r, opts)
                with rec:
                    summary, radar = ingest_one(rec, sid, out, grid, rb, opts, quiet=quiet)
            except (HolodataError, OSError) as err:
                failed.append({"recording": str(r), "error": _error_line(r, out, err)})
                continue
            scenes.append(summary)
            if grid is None and radar is not None:   # the first radar recording sets the dataset's grid
                grid, rb = radar
    finally:
        for rec in opened.values():    # the pre-pass's recordings that were not reached (an error, Ctrl-C)
            rec.close()
    if not scenes:
        raise RecordingError(_failures(failed))
    return {"dataset": str(out), "scenes": scenes, "failed": failed, "ok": not failed}


def _error_line(recording, out, err: BaseException) -> str:
    """One line for a recording that failed: holodata's own errors name their file already; a bare
    OSError (the disk filled up under a writer thread, a permission) gets the recording and dataset."""
    if isinstance(err, OSError) and not isinstance(err, HolodataError):
        where = f" ({err.filename})" if getattr(err, "filename", None) else ""
        return f"{recording}: ingest into {out} failed{where}: {err.strerror or one_line(err)}"
    return one_line(err)


def _failures(failed: list[dict]) -> str:
    if len(failed) == 1:
        return failed[0]["error"]
    return f"none of {len(failed)} recordings can be ingested: " + "; ".join(f["error"] for f in failed)


def open_for_ingest(path, opts: IngestOptions) -> Recording:
    """``path`` opened the way ingest reads it (``opts.msg_dir``, ``opts.meta``, ``opts.beamform``, ``opts.motion``);
    the caller closes it (``with``). The one open of a recording per ingest."""
    _limit_malloc_arenas()   # before any reader or ingest thread allocates
    return open_recording(path, msg_dir=opts.msg_dir, meta=opts.meta, beamform=opts.beamform, motion=opts.motion)


def radar_grid(rec: Recording, topics=None, beamform=None) -> tuple[Grid, RangeBins] | None:
    """The radar grid of the opened recording ``rec`` (from its first decodable radar message), None
    without radar. ``rec`` stays open (it is planned and written next)."""
    infos = rec.topics(frame_ids=False)
    if not any(t.msgtype.endswith(RADAR_SUFFIX) and t.count for t in infos) and not (topics or {}).get("radar"):
        return None
    tmap, _ = map_topics(rec, topics, rec.topics(frame_ids=True))
    if not tmap.radar:
        return None
    st = radar_stream(rec, tmap.radar, tmap.time, next(t.msgtype for t in infos if t.name == tmap.radar), beamform)
    last = None
    msgs = rec.raw_messages([tmap.radar])
    try:
        for n, raw in enumerate(msgs):
            try:
                st.convert(raw, keep=False)
                return _grid_of(rec, st)
            except HolodataError as err:
                last = err
            if n >= 20:
                break
    finally:
        close = getattr(msgs, "close", None)   # leave no reader generator suspended mid-file
        if close is not None:
            close()
    raise RecordingError(f"{rec.path}: no decodable radar message on {tmap.radar} ({one_line(last) if last else 'none'})")


def check_grid(recording, plan: Plan, grid, range_bins) -> None:
    """RecordingError unless the radar recording's grid and range bins (``plan``) are the dataset's
    (``grid``, ``range_bins``); a recording without radar fits any dataset."""
    if plan.grid is not None and (plan.grid, plan.range_bins) != (grid, range_bins):
        raise RecordingError(f"{recording}: radar grid {plan.grid}, {plan.range_bins} differs from the dataset's "
                             f"{grid}, {range_bins}")


@dataclass(frozen=True)
class IngestOptions:
    """What :func:`ingest` was asked besides the recordings (its parameters of the same names), as
    one picklable value for :func:`ingest_one` and the Dask task. ``provenance``: the dataset's
    ``provenance`` root attribute."""
    topics: dict | None = None
    msg_dir: str | Path | None = None
    tolerance_ms: float | None = None
    meta: str | Path | None = None
    codec: str | None = None
    beamform: object = None
    keep_iq: bool = False
    motion: str | None = None
    shard_frames: int | None = None
    provenance: dict = dataclasses.field(default_factory=dict)


def _passes(recordings: list[Path], scene_ids: list[str] | None) -> tuple[list[Path], list[str] | None]:
    """Each ``holodata synth`` output folder given as its recordings: the data pass, then its mapping
    pass (scene id ``<id>_map``, the id given or the folder's); other recordings as given."""
    from ..readers import synth_passes

    out, ids = [], []
    for i, r in enumerate(recordings):
        passes = synth_passes(r)
        out += passes
        if scene_ids is not None:
            ids += [scene_ids[i]] + [f"{scene_ids[i]}_map"] * (len(passes) - 1)
    return out, (ids if scene_ids is not None else None)


def _create(out, grid, range_bins, opts: IngestOptions):
    """The dataset writer at ``out``, created when missing (its root records ``opts.provenance``)."""
    from ..dataset import create_dataset

    kw = {"shard_frames": opts.shard_frames} if opts.shard_frames else {}
    return create_dataset(out, grid=grid, range_bins=range_bins, created_by="holodata ingest",
                          provenance=opts.provenance, **kw)


def ingest_one(rec: Recording, scene_id: str, out, grid: Grid | None, range_bins: RangeBins | None,
               opts: IngestOptions, quiet: bool = True) -> tuple[dict, tuple[Grid, RangeBins] | None]:
    """The opened recording ``rec`` (:func:`open_for_ingest`; left open, its opener closes it) as
    scene ``scene_id`` of the dataset at ``out``: plan it (index and sync passes),
    check its radar grid against the dataset's (``grid`` None: none is known yet, and a radar
    recording's grid becomes the dataset's), create or reopen the dataset (only now, so a recording
    that fails leaves no empty dataset) and write the scene. The local loop of :func:`ingest` and the
    Dask task both call it. Returns (the scene summary, the recording's (grid, range bins) or None
    without radar); raises HolodataError/OSError naming the recording."""
    p = plan_recording(rec, opts.topics, scene_id, opts.tolerance_ms, quiet, opts.beamform, opts.keep_iq, opts.motion)
    if grid is not None:
        check_grid(rec.path, p, grid, range_bins)
    radar = (p.grid, p.range_bins) if p.grid is not None else None
    ds = _create(out, *(radar or (grid, range_bins)), opts)
    return write_plan(p, ds, quiet=quiet, codec=opts.codec), radar   # source digest: waited for at its end


# -- Dask task (holodata.distributed runs it): one per recording -----------------------------------------
def _ingest_task(path: str, scene_id: str, out: str, grid, range_bins, opts: IngestOptions) -> dict:
    """Worker side: :func:`ingest_one` into the dataset ``out`` (which exists). Returns
    {"scene": summary} or {"failed": {recording, error}}."""
    from ..distributed import tune_malloc

    tune_malloc()
    try:
        with open_for_ingest(path, opts) as rec:
            return {"scene": ingest_one(rec, scene_id, out, grid, range_bins, opts)[0]}
    except (HolodataError, OSError) as err:
        return {"failed": {"recording": str(path), "error": _error_line(path, out, err)}}


def ingest_dask(client, todo: list, ids: list[str], out: str, grid, range_bins, opts: IngestOptions,
                quiet: bool = True) -> tuple[list[dict], list[dict]]:
    """One Dask task per recording ``todo`` [(index, path, _)] → scenes ``ids`` of the existing
    dataset ``out``. Returns (scene summaries, failures) in recording order."""
    from ..distributed import run_tasks, worker_path

    token = uuid.uuid4().hex[:8]
    opts = dataclasses.replace(opts, **{k: worker_path(getattr(opts, k)) for k in ("msg_dir", "meta") if getattr(opts, k)})
    calls = [(worker_path(r), sid, worker_path(out), grid, range_bins, opts) for (_, r, _), sid in zip(todo, ids)]
    keys = [f"ingest-{sid}-{token}" for sid in ids]
    res = run_tasks(client, _ingest_task, calls, keys, description="ingest", quiet=quiet)
    return [r["scene"] for r in res if "scene" in r], [r["failed"] for r in res if "failed" in r]
