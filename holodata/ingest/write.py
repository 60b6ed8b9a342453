"""The write pass: :func:`write_plan` decodes the matched messages and writes the scene shard by
shard (a background writer pool), then its poses, TF, extrinsics and attributes."""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from ..dataset.layout import (
    LIDAR_POINT_TIME_NS,
    LIDAR_RANGE,
    POINTS_OF,
    POSE_T_WORLD_RADAR,
    RADAR_CYCLE_NS,
    RADAR_HEATMAP,
    RADAR_IQ,
    RADAR_IQ_MOTION,
    RADAR_IQ_SPAN,
    RADAR_IQ_STATIC,
    STAMPS_OF,
    TF_T_WORLD_LIDAR,
    TIME_TIMESTAMP_NS,
)
from ..dataset.writer import FrameStorage
from ..errors import DatasetError, HolodataError, RecordingError, one_line
from ..readers.base import DecodeError
from .plan import SOURCE_HASH, Plan, _head_topics, _limit_malloc_arenas, file_digests, file_sha256
from .roles import BULK_CODEC, SHARD_TARGET_BYTES
from .sensors import extrinsics, sensor_attrs, sensor_frame, world_frame


class _Background:
    """Shard writes (Blosc compression, sha256, file put) on ``workers`` threads, overlapping the
    main thread's reading and decoding (Blosc, hashlib and file writes release the GIL). Shard
    data queued or in flight is bounded by ``budget`` bytes (a larger shard waits until nothing
    else is in flight), so memory stays flat whatever the recording size. Jobs with the same
    ``key`` (one ragged array: shards append in order) run in submit order: each waits for its
    predecessor, which was submitted, and so dequeued, earlier (FIFO), so the wait cannot
    deadlock. Errors surface on the next submit or on :meth:`join`; :meth:`close` always waits for
    the writes in progress."""

    def __init__(self, workers: int = 2, budget: int = SHARD_TARGET_BYTES + (SHARD_TARGET_BYTES >> 1)):
        import threading
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(workers, thread_name_prefix="holodata-ingest-writer")
        self.cond = threading.Condition()
        self.budget, self.inflight = int(budget), 0
        self.futures: list = []
        self.last: dict = {}
        self.seconds = 0.0    # busy time summed over the workers

    def _run(self, fn, prev, nbytes: int) -> None:
        try:
            if prev is not None:
                prev.result()
            t = time.perf_counter()
            fn()
            with self.cond:
                self.seconds += time.perf_counter() - t
        finally:
            with self.cond:
                self.inflight -= nbytes
                self.cond.notify_all()

    def _raise(self) -> None:
        pending = []
        for f in self.futures:
            if f.done():
                f.result()
            else:
                pending.append(f)
        self.futures = pending

    def submit(self, fn, key=None, nbytes: int = 0) -> None:
        self._raise()
        with self.cond:
            while self.inflight and self.inflight + nbytes > self.budget:
                self.cond.wait()
            self.inflight += nbytes
        fut = self.pool.submit(self._run, fn, self.last.get(key) if key is not None else None, nbytes)
        if key is not None:
            self.last[key] = fut
        self.futures.append(fut)

    def join(self) -> None:
        for f in self.futures:
            f.result()
        self.futures = []

    def close(self) -> None:
        self.pool.shutdown(wait=True)


class _Out:
    """Buffers one array's frames and writes each shard once all its frames are in."""

    def __init__(self, writer, ragged: bool, default, expected: set[int], bg: _Background | None = None):
        self.bg = bg
        self.w, self.ragged, self.default = writer, ragged, default
        self.expected = expected
        self.buf: dict[int, object] = {}
        self.done = {k for k in range(writer.n_shards) if writer.is_done(k)}   # resumed: finished shards
        self.k = 0
        self.written = 0
        self.seconds = 0.0

    def shard_done(self, frame: int) -> bool:
        return frame // self.w.shard_frames in self.done

    def put(self, frame: int, data) -> None:
        if not self.shard_done(frame):
            self.buf[frame] = data

    def fail(self, frame: int) -> None:
        self.expected.discard(frame)

    def flush(self, final: bool = False) -> None:
        while self.k < self.w.n_shards:
            sl = self.w.frames(self.k)
            if self.k in self.done:
                self.k += 1
                continue
            frames = range(sl.start, sl.stop)
            if not final and any(f in self.expected and f not in self.buf for f in frames):
                return
            data = [self.buf.pop(f) if f in self.buf else self.default() for f in frames]
            # bound now: the job may run after this loop has moved on (frame arrays take the list: no stack copy)
            job = lambda k=self.k, w=self.w, data=data: w.write_shard(k, data)   # noqa: E731
            if self.bg is not None:
                self.bg.submit(job, key=id(self) if self.ragged else None,
                               nbytes=sum(getattr(a, "nbytes", 0) for a in data))
            else:
                t = time.perf_counter()
                job()
                self.seconds += time.perf_counter() - t
            self.done.add(self.k)
            self.written += 1
            self.k += 1


def _shard_frames(per_frame_bytes: int, default: int) -> int:
    return int(max(1, min(default, SHARD_TARGET_BYTES // max(1, per_frame_bytes))))


def write_plan(plan: Plan, ds, quiet: bool = True, codec: str | None = None) -> dict:
    """Pass 2: decode the matched messages and write scene ``plan.scene_id`` into writer ``ds``."""
    _limit_malloc_arenas()
    bg = _Background()
    try:
        return _write_plan(plan, ds, quiet, codec, bg)
    finally:
        bg.close()   # also on errors/interrupts: the shard write in progress finishes before we return


def _write_plan(plan: Plan, ds, quiet: bool, codec: str | None, bg: _Background) -> dict:
    """The write pass's steps: the source and the fingerprint a resumed scene must agree with, the
    scene and its outputs, the decoding pass, then the other sensors' stamps, poses, TF and the
    final attributes (``ingest.complete``)."""
    T, fs = len(plan.frame_stamps), plan.frame_sensor
    source, sizes = _source_attrs(plan)
    fingerprint = _fingerprint(plan)
    if plan.scene_id in ds.scene_ids() and _resumed_scene_done(plan, ds, sizes, fingerprint):
        return {"scene": plan.scene_id, "frames": T, "skipped": "already ingested"}
    from ..dataset.splits import scene_role

    attrs = {"frame_sensor": fs, "role": scene_role({"frame_sensor": fs}), "source": source,
             "sensors": sensor_attrs(plan),
             "extrinsics": extrinsics(plan),
             "ingest": {"complete": False, "topics": plan.tmap.to_dict(), "fingerprint": fingerprint}}
    # marked unfinished in the put that makes (or reopens) the scene; finished with the final attributes
    sc = ds.scene(plan.scene_id, n_frames=T, attrs=attrs, stage="ingest",
                  rerun="rerun holodata ingest with the same recording and --scene-id to finish it")
    arrays: list[str] = []

    def frame_arr(name, shape, dtype=None, codec=codec, shard_frames=None, **kw):
        """Frame array ``name`` (its dtype, dims and units the layout's), listed in the summary."""
        arrays.append(name)
        return sc.frame_array(name, per_frame_shape=shape, dtype=dtype, storage=FrameStorage(shard_frames, codec), **kw)

    _write_stamps(frame_arr(TIME_TIMESTAMP_NS, ()), plan.frame_stamps)
    exp = _expected_frames(plan)
    outs = _outputs(plan, sc, frame_arr, arrays, exp, codec or BULK_CODEC, ds.shard_frames, bg)
    dec = _Decoded(plan, exp, outs)
    t_pass = time.perf_counter()
    _decode_pass(plan, dec, _wanted_items(exp, outs), quiet)
    for o in outs.values():
        o.flush(final=True)
    bg.join()
    timings = {"index_pass_s": round(plan.index_seconds, 4), "write_pass_s": round(time.perf_counter() - t_pass, 4),
               "decode_s": round(dec.seconds, 4),
               "store_s": round(bg.seconds + sum(o.seconds for o in outs.values()), 4)}
    if dec.failed.get(fs):
        raise RecordingError(f"{plan.rec.path}: {dec.failed[fs]} {fs} messages decoded in the index pass but not in "
                             f"the write pass ({dec.fail_msg.get(fs)})")
    _write_sensor_stamps(plan, outs, frame_arr)
    warnings = list(plan.warnings) + _decode_warnings(plan, dec, outs)
    for note in (_write_poses(plan, sc, frame_arr), _write_lidar_tf(plan, frame_arr)):
        if note:
            warnings.append(note)
    sync = _sync_summary(plan)
    sc.finish("ingest", {"source": {**source, SOURCE_HASH: _digests(plan)},
                         "ingest": {"complete": True, "fingerprint": fingerprint, "topics": plan.tmap.to_dict(),
                                    "time_source": plan.tmap.time,
                                    "counts": plan.counts, "decoded": dec.decoded, "dropped": plan.dropped,
                                    "sync": sync, "notes": plan.notes[:20], "warnings": warnings[:50]}})
    return {"scene": plan.scene_id, "recording": str(plan.rec.path), "frames": T, "frame_sensor": fs,
            "arrays": sorted(set(arrays)), "counts": plan.counts, "decoded": dec.decoded, "dropped": plan.dropped,
            "sync": sync, "truncated": bool(plan.rec.truncated), "warnings": warnings, "notes": plan.notes,
            "timings": timings}


def _digests(plan: Plan) -> list[str]:
    """The recording files' BLAKE3 digests, hashed on a thread since plan_recording: waited for only
    when a resumed scene must be compared, else at the end (overlapping the write pass)."""
    if not plan.digests:
        plan.digests = plan.sha_future.result() if plan.sha_future is not None else file_digests(plan.rec.files)
    return plan.digests


def _source_attrs(plan: Plan) -> tuple[dict, list]:
    """(the scene attribute ``source`` without the digest, the recording files' sizes in bytes (None
    where unreadable)). The digest goes in with the final attributes (``ingest.complete``);
    ``bytes`` tells an interrupted run's scene from another recording's before then."""
    rec = plan.rec
    sizes = []
    for f in rec.files:
        try:
            sizes.append(Path(f).stat().st_size)
        except OSError:
            sizes.append(None)
    source = {"recording": str(rec.path), "files": [str(f) for f in rec.files], "bytes": sizes,
              "reader": rec.kind, "truncated": bool(rec.truncated), **(getattr(rec, "attrs", None) or {}),
              **({"problems": rec.problems[:20]} if rec.problems else {}),
              **({"beamform": plan.streams["radar"].attrs} if getattr(plan.streams.get("radar"), "attrs", None) else {})}
    return source, sizes


def _fingerprint(plan: Plan) -> str:
    """sha256 of what the frames and their contents depend on (topics, tolerances, frame stamps,
    matches): a resumed run must agree."""
    return hashlib.sha256(json.dumps(
        {"topics": plan.tmap.to_dict(), "tolerance_ns": plan.tolerance_ns, "frames": plan.frame_stamps.tolist(),
         "match": {r: v.tolist() for r, v in plan.match.items()}}, sort_keys=True).encode()).hexdigest()


def _same_source(plan: Plan, src: dict) -> bool | None:
    """Whether the scene's recorded digest (BLAKE3, or sha256 for scenes ingested before) is this
    recording's; None when it has none (an interrupted run: ``bytes`` decides)."""
    if src.get(SOURCE_HASH):
        return src[SOURCE_HASH] == _digests(plan)
    if src.get("sha256"):
        return src["sha256"] == file_sha256(plan.rec.files)
    return None


def _resumed_scene_done(plan: Plan, ds, sizes: list, fingerprint: str) -> bool:
    """For a scene that exists: True when it was ingested completely from this recording; a
    :class:`DatasetError` when it came from another recording or other topics/tolerances; False
    when it is an interrupted run of this one (resumed)."""
    cur = ds.scene(plan.scene_id).attrs
    src = cur.get("source") if isinstance(cur.get("source"), dict) else {}
    same = _same_source(plan, src)
    if same is False or (same is None and src.get("bytes") not in (None, sizes)):
        raise DatasetError(f"{ds.url}: scene {plan.scene_id!r} was ingested from another recording "
                           f"({(cur.get('source') or {}).get('recording')}); choose another --scene-id")
    prev = (cur.get("ingest") or {}).get("fingerprint")
    if prev and prev != fingerprint:
        raise DatasetError(f"{ds.url}: scene {plan.scene_id!r} was started with other topics/tolerance; rerun with "
                           f"the same options or choose another --scene-id")
    return bool((cur.get("ingest") or {}).get("complete")) and "ingest" not in (cur.get("unfinished") or {})


def _write_stamps(w, values: np.ndarray) -> None:
    """Write the (T,) per-frame array ``values`` shard by shard into frame-array writer ``w``."""
    for k in range(w.n_shards):
        w.write_shard(k, values[w.frames(k)])


def _expected_frames(plan: Plan) -> dict[str, dict[int, list[int]]]:
    """{role: {item index: the frames it fills}}: the frame sensor's items fill their own frames,
    another sensor's matched items the frames they were matched to."""
    exp: dict[str, dict[int, list[int]]] = {}
    for role in plan.streams:
        items = plan.frame_items if role == plan.frame_sensor else plan.match[role]
        d: dict[int, list[int]] = {}
        for f, i in enumerate(items.tolist()):
            if i >= 0:
                d.setdefault(i, []).append(f)
        exp[role] = d
    return exp


def _outputs(plan: Plan, sc, frame_arr, arrays: list, exp: dict, bulk: str, S: int, bg) -> dict[str, _Out]:
    """The scene's decoded arrays, made (or reopened on a resume) and buffered shard by shard:
    ``radar/heatmap``, ``radar/cycle_ns`` (and the raw samples with ``keep_iq``), the point sensors'
    points, the LiDAR's point times and range image where the probe found them."""
    T = len(plan.frame_stamps)
    outs: dict[str, _Out] = {}
    if "radar" in plan.streams:
        rs = plan.streams["radar"]
        shape = rs.shape
        fb = int(np.prod(shape)) * rs.dtype.itemsize
        hm = frame_arr(RADAR_HEATMAP, shape, rs.dtype.newbyteorder("="), shard_frames=_shard_frames(fb, S), codec=bulk,
                       attrs={"amplitude": "linear", "topic": rs.topic})
        outs[RADAR_HEATMAP] = _Out(hm, False, lambda: np.full(shape, np.nan, rs.dtype), set(range(T)), bg)
        cyc = frame_arr(RADAR_CYCLE_NS, (2,))
        outs[RADAR_CYCLE_NS] = _Out(cyc, False, lambda: np.zeros(2, np.int64), set(range(T)), bg)
        if plan.keep_iq:
            _iq_outputs(plan, sc, frame_arr, outs, T, S, bg)
            if RADAR_IQ_STATIC in sc.arrays():
                arrays.append(RADAR_IQ_STATIC)
    for role in ("lidar", "camera"):
        if role not in plan.streams:
            continue
        frames_with = {f for fl in exp[role].values() for f in fl}
        pts = sc.ragged_array(POINTS_OF[role], codec=bulk)
        arrays.append(POINTS_OF[role])
        outs[POINTS_OF[role]] = _Out(pts, True, lambda: np.zeros((0, 3), np.float32), set(frames_with), bg)
        pr = plan.probe.get(role) or {}
        if role == "lidar" and pr.get("time"):
            pt = sc.ragged_array(LIDAR_POINT_TIME_NS, codec=bulk)
            arrays.append(LIDAR_POINT_TIME_NS)
            outs[LIDAR_POINT_TIME_NS] = _Out(pt, True, lambda: np.zeros((0, 1), np.int64), set(frames_with), bg)
        if role == "lidar" and pr.get("grid"):
            gshape = tuple(pr["grid"])
            lr = frame_arr(LIDAR_RANGE, gshape, shard_frames=_shard_frames(4 * int(np.prod(gshape)), S), codec=bulk)
            outs[LIDAR_RANGE] = _Out(lr, False, lambda g=gshape: np.full(g, np.nan, np.float32), set(frames_with), bg)
    return outs


def _wanted_items(exp: dict, outs: dict) -> dict[str, set[int]]:
    """{role: the item indices to decode}: the items filling a frame of an unfinished shard of one of
    the role's arrays (a resumed scene decodes only what is missing)."""
    want: dict[str, set[int]] = {}
    for role, d in exp.items():
        names = [n for n in outs if n.startswith(role + "/")]
        w = set()
        for i, fl in d.items():
            if any(not outs[n].shard_done(f) for n in names for f in fl):
                w.add(i)
        want[role] = w
    return want


class _Decoded:
    """Hands the decoded items of the write pass to the outputs (``exp``: {role: {item index: frames}})
    and counts, per role, the items decoded and failed, the points written and the first failure;
    ``grid_bad``: LiDAR scans that do not fit ``lidar/range``'s grid; ``seconds``: decoding time."""

    def __init__(self, plan: Plan, exp: dict, outs: dict):
        self.exp, self.outs = exp, outs
        self.decoded = {r: 0 for r in plan.streams}
        self.n_points = {r: 0 for r in plan.streams}
        self.failed = {r: 0 for r in plan.streams}
        self.fail_msg: dict[str, str] = {}
        self.grid_bad = 0
        self.seconds = 0.0

    def deliver(self, role: str, item) -> None:
        """Put a decoded item's payload into the frames it fills."""
        frames = self.exp[role].get(item.index)
        if not frames:
            return
        outs, p = self.outs, item.payload
        for f in frames:
            if role == "radar":
                outs[RADAR_HEATMAP].put(f, p.heatmap)
                outs[RADAR_CYCLE_NS].put(f, np.asarray(p.cycle, np.int64))
                if RADAR_IQ in outs:
                    _put_iq(outs, f, p.iq)
            else:
                outs[POINTS_OF[role]].put(f, p.points)
                self.n_points[role] += len(p.points)
                if role == "lidar" and LIDAR_POINT_TIME_NS in outs:
                    t = p.time_ns if p.time_ns is not None else np.zeros(len(p.points), np.int64)
                    outs[LIDAR_POINT_TIME_NS].put(f, np.asarray(t, np.int64).reshape(-1, 1))
                if role == "lidar" and LIDAR_RANGE in outs:
                    g = outs[LIDAR_RANGE]
                    if p.grid is not None and p.grid.shape == g.w.shape[1:]:
                        g.put(f, p.grid)
                    else:
                        self.grid_bad += 1
                        g.fail(f)

    def fail(self, role: str, idx: int, err) -> None:
        """Item ``idx`` did not decode: its frames expect nothing from the role's arrays."""
        self.failed[role] += 1
        self.fail_msg.setdefault(role, one_line(err))
        for f in self.exp[role].get(idx, []):
            for n, o in self.outs.items():
                if n.startswith(role + "/"):
                    o.fail(f)


def _decode_pass(plan: Plan, dec: _Decoded, want: dict, quiet: bool) -> None:
    """Read the matched topics' messages once more, decode the ``want``-ed items and hand them to
    ``dec``; the outputs write every shard whose frames are all in."""
    from ..progress import track

    rec, outs = plan.rec, dec.outs
    by_topic = {tp: st for st in plan.streams.values() for tp in st.topics}
    for st in plan.streams.values():
        st.reset()
    total = sum(t.count for t in rec.topics(frame_ids=False) if t.name in by_topic)
    heads = _head_topics(plan.streams)
    for raw in track(rec.raw_heads(list(by_topic), heads), total, f"ingest {plan.scene_id}: write", quiet,
                     unit="messages"):
        st = by_topic[raw.topic]
        t = time.perf_counter()
        try:
            items = st.feed(raw, decode=True, want=want[st.role])
        except HolodataError as err:
            dec.fail(st.role, getattr(err, "item", -1), err)
            continue
        finally:
            dec.seconds += time.perf_counter() - t
        fresh = False
        for it in items:
            if it.payload is not None:
                dec.decoded[st.role] += 1
                dec.deliver(st.role, it)
                fresh = True
        if fresh:
            for o in outs.values():
                o.flush()
    for role, st in plan.streams.items():
        for it in st.flush(decode=True, want=want[role]):
            if it.payload is not None:
                dec.decoded[role] += 1
                dec.deliver(role, it)


def _write_sensor_stamps(plan: Plan, outs: dict, frame_arr) -> None:
    """Per-frame stamps of the sensors other than the radar (``lidar/timestamp_ns``, ...): the
    matched message's stamp, 0 = none (or it failed); the frame sensor's are the frame stamps."""
    T = len(plan.frame_stamps)
    for role in [r for r in plan.streams if r != "radar"]:
        if role == plan.frame_sensor:
            vals = plan.frame_stamps
        else:
            ok = np.zeros(T, bool)
            ok[sorted(outs[POINTS_OF[role]].expected)] = True
            vals = np.where(ok, plan.match_stamp[role], 0)
        _write_stamps(frame_arr(STAMPS_OF[role], ()), vals)


def _decode_warnings(plan: Plan, dec: _Decoded, outs: dict) -> list[str]:
    """Warnings of the write pass: messages that did not decode (recorded in ``plan.dropped``), point
    sensors without a valid point, LiDAR scans off ``lidar/range``'s grid."""
    warnings = []
    for role, n in dec.failed.items():
        if n and role != "radar":
            plan.dropped[role]["failed_in_write_pass"] = n
            warnings.append(f"{n} {role} messages on {plan.streams[role].topic} did not decode ({dec.fail_msg[role]}); "
                            f"their frames have no {role} data")
    for role in ("lidar", "camera"):
        if dec.decoded.get(role) and not dec.n_points[role]:
            warnings.append(f"all {dec.decoded[role]} decoded {role} messages on {plan.streams[role].topic} hold no "
                            f"valid point (non-finite or (0, 0, 0)); {role}/points is empty")
    if dec.grid_bad:
        warnings.append(f"{dec.grid_bad} LiDAR scans do not fit the {outs[LIDAR_RANGE].w.shape[1:]} grid; "
                        f"their lidar/range frames are NaN")
    return warnings


def _sync_summary(plan: Plan) -> dict:
    """{role: matched frames, tolerance, median and largest |offset| to the frame stamps (ns)}."""
    sync = {}
    for role in plan.match:
        ok = plan.match[role] >= 0
        off = (plan.match_stamp[role] - plan.frame_stamps)[ok]
        sync[role] = {"matched_frames": int(ok.sum()), "tolerance_ns": int(plan.tolerance_ns.get(role, 0)),
                      "offset_ns_median": int(np.median(off)) if len(off) else None,
                      "offset_ns_max_abs": int(np.abs(off).max()) if len(off) else None}
    return sync


def _iq_outputs(plan: Plan, sc, frame_arr, outs: dict, T: int, S: int, bg) -> None:
    """``radar/iq`` (T, L, V, S) complex64: each rotation's raw chirp frames, the neighbouring ones its
    beams use first and last (``radar/iq_span`` (T, 3) int32 = before, rotation, after; zero-padded
    to L); ``radar/iq_motion`` (T, 2) float64: travel per chirp (m) and heading (rad) it was imaged
    with; ``radar/iq_static`` (V, S) complex64: the trajectory's static reflection, subtracted before
    imaging. ``holodata beamform`` re-images them (:mod:`holodata.reimage`)."""
    src = plan.rec if hasattr(plan.rec, "iq_shape") else plan.streams["radar"]   # a raw reader, or raw messages
    L, V, Sm = src.iq_shape()
    if hasattr(src, "static_refl"):    # a trajectory mean exists only where the reader sees every chirp
        sc.write_array(RADAR_IQ_STATIC, src.static_refl())
    iq = frame_arr(RADAR_IQ, (L, V, Sm), shard_frames=_shard_frames(8 * L * V * Sm, S), codec=BULK_CODEC,
                   attrs={"scale": "unit (the recording's int16 scale divided out)",
                          "layout": "chirp frames [before | rotation | after] as radar/iq_span says, then zeros"})
    span = frame_arr(RADAR_IQ_SPAN, (3,))
    mot = frame_arr(RADAR_IQ_MOTION, (2,), attrs={"columns": "travel per chirp (m), heading counter-clockwise from beam 0 (rad)"})
    outs[RADAR_IQ] = _Out(iq, False, lambda: np.zeros((L, V, Sm), np.complex64), set(range(T)), bg)
    outs[RADAR_IQ_SPAN] = _Out(span, False, lambda: np.zeros(3, np.int32), set(range(T)), bg)
    outs[RADAR_IQ_MOTION] = _Out(mot, False, lambda: np.zeros(2, np.float64), set(range(T)), bg)


def _put_iq(outs: dict, f: int, raw) -> None:
    L = outs[RADAR_IQ].w.shape[1]
    parts = (raw.before, raw.rotation, raw.after)
    n = [int(len(p)) for p in parts]
    if sum(n) > L:
        raise DecodeError(f"rotation {f}: {sum(n)} chirp frames exceed the {L} radar/iq was made for")
    cube = np.zeros(outs[RADAR_IQ].w.shape[1:], np.complex64)
    cube[:sum(n)] = np.concatenate(parts, axis=0)
    outs[RADAR_IQ].put(f, cube)
    outs[RADAR_IQ_SPAN].put(f, np.asarray(n, np.int32))
    outs[RADAR_IQ_MOTION].put(f, np.asarray(raw.motion, np.float64))


def _write_poses(plan: Plan, sc, frame_arr) -> str | None:
    tf = plan.tf
    if "radar" not in plan.streams or tf is None or not tf.frames:
        return None
    radar_frame = str(plan.streams["radar"].first.header.frame_id).lstrip("/")
    world = plan.tmap.world_frame or world_frame(tf, radar_frame)
    if world is None:
        return f"TF does not connect radar frame {radar_frame!r} to a world frame; no pose/T_world_radar"
    res = tf.lookup_many(world, radar_frame, plan.frame_stamps)
    if res is None:
        return f"TF does not connect radar frame {radar_frame!r} to {world!r}; no pose/T_world_radar"
    poses, ok = res
    if not ok.all():
        return (f"TF covers only {int(ok.sum())} of {len(ok)} radar frames ({world} -> {radar_frame}); "
                f"no pose/T_world_radar")
    w = frame_arr(POSE_T_WORLD_RADAR, (4, 4), attrs={"world_frame": world, "sensor_frame": radar_frame, "source": "tf"})
    for k in range(w.n_shards):
        w.write_shard(k, poses[w.frames(k)])
    return None


def _write_lidar_tf(plan: Plan, frame_arr) -> str | None:
    """``tf/T_world_lidar`` (T,4,4): TF's pose of the LiDAR frame in the world frame at each frame's
    scan stamp, NaN where the frame has no scan or TF does not cover it (drivers start at different
    times). slam anchors its map to it (the first covered scan), so slam's world is TF's world and a
    camera TF pose in that world is a guess register can use."""
    tf = plan.tf
    if "lidar" not in plan.streams or tf is None or not tf.frames:
        return None
    frame = sensor_frame(plan, "lidar")
    if not frame:
        return None
    from ..readers.tf import BASE_FRAMES

    world = plan.tmap.world_frame or world_frame(tf, frame)
    if world is None or world == frame or (world in BASE_FRAMES and not plan.tmap.world_frame):
        return None     # (the robot's own base frame is no world: no odometry/localisation in TF)
    stamps = plan.frame_stamps if plan.frame_sensor == "lidar" else np.where(
        plan.match["lidar"] >= 0, plan.match_stamp["lidar"], 0)
    res = tf.lookup_many(world, frame, stamps)
    if res is None:
        return f"TF does not connect LiDAR frame {frame!r} to {world!r}; no tf/T_world_lidar"
    poses, ok = res
    ok &= np.asarray(stamps) > 0
    poses = np.where(ok[:, None, None], poses, np.nan)
    w = frame_arr(TF_T_WORLD_LIDAR, (4, 4), attrs={"world_frame": world, "sensor_frame": frame, "source": "tf",
                         "covered_frames": int(ok.sum()), "time": "the frame's LiDAR scan stamp"})
    for k in range(w.n_shards):
        w.write_shard(k, poses[w.frames(k)])
    if not ok.any():
        return f"TF ({world} -> {frame}) covers none of the LiDAR scans; tf/T_world_lidar is NaN"
    return None
