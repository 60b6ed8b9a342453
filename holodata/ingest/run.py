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
from .plan import Plan, _grid_of, _limit_malloc_arenas, _scene_id, plan_recording
from .radar_streams import radar_stream
from .roles import RADAR_SUFFIX, load_topics_file, map_topics
from .write import write_plan


def ingest(recordings, out, options: IngestOptions | None = None, scene_ids=None, quiet: bool = True,
           client=None) -> dict:
    """Ingest ``recordings`` (paths) into the dataset at ``out`` (created or resumed), one scene
    each, as ``options`` asks (:class:`IngestOptions`; None: its defaults). ``scene_ids``: one per
    recording (default: from the file or folder names). Returns the summary
    {dataset, scenes: [...], failed: [{recording, error}], ok}; a recording that fails is reported
    there and the others are still ingested. Raises RecordingError when none could be ingested.
    ``client`` (a ``distributed.Client``): one Dask task per recording (:mod:`holodata.distributed`);
    the recordings must be readable at the same paths on the workers."""
    recordings, scene_ids, opts = _request(recordings, scene_ids, options or IngestOptions())
    return _IngestRun(out, opts, quiet, client).run(recordings, scene_ids)


def _request(recordings, scene_ids, opts: IngestOptions) -> tuple[list[Path], list[str] | None, IngestOptions]:
    """:func:`ingest`'s arguments checked (InputError, one line): the recordings as paths with synth
    output folders expanded into their passes (:func:`_passes`), their scene ids, and ``opts`` with
    its topics file read and its provenance (holodata's version unless given)."""
    recordings = [Path(r) for r in recordings]
    if not recordings:
        raise InputError("no recording given")
    topics = load_topics_file(opts.topics) if isinstance(opts.topics, (str, Path)) else opts.topics
    if scene_ids is not None:
        scene_ids = list(scene_ids)
        if len(scene_ids) != len(recordings):
            raise InputError(f"{len(scene_ids)} --scene-id for {len(recordings)} recordings (give one per recording)")
        for sid in scene_ids:   # a scene id names folders/keys under the output: never outside it
            check_name(sid, "--scene-id")
    recordings, scene_ids = _passes(recordings, scene_ids)
    if opts.tolerance_ms is not None and opts.tolerance_ms <= 0:
        raise InputError(f"--tolerance must be > 0 ms, got {opts.tolerance_ms}")
    try:
        from .. import __version__ as version  # holodata's
    except ImportError:  # pragma: no cover
        version = "?"
    provenance = opts.provenance or {"tool": "holodata ingest", "version": version}
    return recordings, scene_ids, dataclasses.replace(opts, topics=topics, provenance=provenance)


def _dataset_grid(out) -> tuple[object, Grid | None, RangeBins | None]:
    """(the dataset at ``out`` or None when there is none yet, its radar grid and range bins or
    (None, None) when it has none: a LiDAR-only dataset gets the first radar recording's)."""
    from ..dataset import open_dataset

    try:
        existing = open_dataset(out)
    except HolodataError:
        return None, None, None
    if existing.meta.get("grid_source") != "default":
        return existing, existing.grid, existing.range_bins
    return existing, None, None


class _IngestRun:
    """:func:`ingest` of checked arguments as named steps sharing their state: the radar grid pre-pass
    (:meth:`grid_prepass`), the scene ids (:func:`_unique_ids`), then the scenes locally
    (:meth:`local`) or one Dask task each (:meth:`dask`). ``failed`` collects the recordings that
    failed, ``scenes`` the summaries; ``opened``: index -> recording opened by the pre-pass, until its
    scene is written."""

    def __init__(self, out, opts: IngestOptions, quiet: bool, client):
        self.out, self.opts, self.quiet, self.client = out, opts, quiet, client
        self.failed: list[dict] = []
        self.scenes: list[dict] = []
        self.opened: dict[int, Recording] = {}
        self.existing, self.grid, self.rb = _dataset_grid(out)

    def run(self, recordings: list[Path], scene_ids: list[str] | None) -> dict:
        try:
            if self.existing is None and (len(recordings) > 1 or self.client is not None):
                todo = self.grid_prepass(recordings)
            else:
                todo = [(i, r, None) for i, r in enumerate(recordings)]
            ids = _unique_ids(todo, scene_ids)
            if self.client is not None:
                self.dask(todo, ids)
            else:
                self.local(todo, ids)
        finally:
            for rec in self.opened.values():    # the pre-pass's recordings that were not reached (an error, Ctrl-C)
                rec.close()
        if not self.scenes:
            raise RecordingError(_failures(self.failed))
        return {"dataset": str(self.out), "scenes": self.scenes, "failed": self.failed, "ok": not self.failed}

    def grid_prepass(self, recordings: list[Path]) -> list:
        """Cheap pre-pass: each radar recording's grid (the dataset has one grid for all scenes), which
        becomes the run's. Returns [(index, path, (grid, range bins) or None)] of the recordings that
        opened; the local loop goes on with the recordings it opened, Dask workers open their own."""
        todo = []
        for i, r in enumerate(recordings):
            try:
                rec = open_for_ingest(r, self.opts)
            except (HolodataError, OSError) as err:
                self.failed.append({"recording": str(r), "error": one_line(err)})
                continue
            try:
                todo.append((i, r, radar_grid(rec, self.opts.topics, self.opts.beamform)))
            except (HolodataError, OSError) as err:
                self.failed.append({"recording": str(r), "error": one_line(err)})
                rec.close()
                continue
            if self.client is None:
                self.opened[i] = rec
            else:
                rec.close()
        self.grid, self.rb = self._one_grid(todo)
        return todo

    def _one_grid(self, todo: list) -> tuple[Grid | None, RangeBins | None]:
        """The recordings' one radar grid ((None, None) without radar); RecordingError when none opened
        or their grids differ."""
        if not todo:
            raise RecordingError(_failures(self.failed))
        grids = {g for _, _, g in todo if g is not None}
        if len(grids) > 1:
            raise RecordingError(f"recordings have different radar grids "
                                 f"({sorted(str(g[0].to_attrs()) for g in grids)}); ingest them into separate datasets")
        return next(iter(grids)) if grids else (None, None)

    def dask(self, todo: list, ids: list[str]) -> None:
        """One Dask task per recording; the dataset exists before the workers write their scenes into it."""
        made = _create(self.out, self.grid, self.rb, self.opts)
        self.scenes, more = ingest_dask(self.client, todo, ids, self.out, self.grid, self.rb, self.opts,
                                        quiet=self.quiet)
        self.failed += more
        if not self.scenes:   # nothing landed: leave no empty dataset, if (and only if) this run created it
            made.discard()

    def local(self, todo: list, ids: list[str]) -> None:
        """Each recording in turn (:func:`ingest_one`); the first radar recording sets the dataset's grid."""
        for (i, r, _), sid in zip(todo, ids):
            try:
                rec = self.opened.pop(i) if i in self.opened else open_for_ingest(r, self.opts)
                with rec:
                    summary, radar = ingest_one(rec, sid, self.out, self.grid, self.rb, self.opts, quiet=self.quiet)
            except (HolodataError, OSError) as err:
                self.failed.append({"recording": str(r), "error": _error_line(r, self.out, err)})
                continue
            self.scenes.append(summary)
            if self.grid is None and radar is not None:
                self.grid, self.rb = radar


def _unique_ids(todo: list, scene_ids: list[str] | None) -> list[str]:
    """The scene id of each recording of ``todo`` [(index, path, _)]: ``scene_ids``' or from its name,
    ids given to several recordings suffixed with the recording's place (``<id>_<k>``)."""
    ids = [scene_ids[i] if scene_ids else _scene_id(r) for i, r, _ in todo]
    return [f"{sid}_{k}" if ids.count(sid) > 1 else sid for k, sid in enumerate(ids)]  # same names: suffix


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
    """How :func:`ingest` reads and writes the recordings, as one picklable value for
    :func:`ingest_one` and the Dask task.

    ``topics``: the topic mapping, a dict or a YAML path (see :func:`load_topics_file`; :func:`ingest`
    reads the file); ``msg_dir``: folder of ``.msg`` definitions for types the recording lacks;
    ``tolerance_ms``: sync tolerance (None: per sensor, half its median period, at least 50 ms);
    ``meta``: sensor metadata file for readers that need one; ``codec``: the arrays' compressor;
    ``beamform``: :class:`~holodata.radar.beam_geometry.BeamformParams` for recordings of raw radar
    samples (PanoRadar raw trajectories), default 64 x 512 beams, all range bins; ``keep_iq``: store
    their raw samples too (``radar/iq``), so that ``holodata beamform`` can re-image them with other
    parameters; ``motion``: "static" | "moving", the robot's motion in every PanoRadar raw trajectory
    given, instead of reading it from their folder names
    (:func:`holodata.readers.panoradar_raw.motion_rule`); ``shard_frames``: frames per shard of a
    dataset created here; ``provenance``: the dataset's ``provenance`` root attribute (empty: holodata
    ingest's, with its version)."""
    topics: dict | str | Path | None = None
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
