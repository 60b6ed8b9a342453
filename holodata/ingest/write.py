"""The write pass: :func:`write_plan` decodes the matched messages and writes the scene shard by
shard (a background writer pool), then its poses, TF, extrinsics and attributes."""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from ..dataset.layout import (LIDAR_POINT_TIME_NS, LIDAR_RANGE, POINTS_OF, POSE_T_WORLD_RADAR, RADAR_CYCLE_NS,
                              RADAR_HEATMAP, RADAR_IQ, RADAR_IQ_MOTION, RADAR_IQ_SPAN, RADAR_IQ_STATIC, STAMPS_OF,
                              TF_T_WORLD_LIDAR, TIME_TIMESTAMP_NS)
from ..errors import DatasetError, HolodataError, RecordingError
from ..readers.base import DecodeError
from .roles import BULK_CODEC, SHARD_TARGET_BYTES, _one_line
from .streams import (CameraCloudStream, CloudStream, DepthStream, OusterPacketStream, OusterScanStream, StereoStream,
                      radar_beam_origin)
from .plan import SOURCE_HASH, Plan, _head_topics, _limit_malloc_arenas, file_digests, file_sha256


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
    from ..progress import track

    rec, T = plan.rec, len(plan.frame_stamps)
    fs = plan.frame_sensor

    def digests() -> list[str]:
        """The recording files' BLAKE3 digests, hashed on a thread since plan_recording: waited for
        only when a resumed scene must be compared, else at the end (overlapping the write pass)."""
        if not plan.digests:
            plan.digests = plan.sha_future.result() if plan.sha_future is not None else file_digests(rec.files)
        return plan.digests

    def same_source(src: dict) -> bool | None:
        """Whether the scene's recorded digest (BLAKE3, or sha256 for scenes ingested before) is this
        recording's; None when it has none (an interrupted run: ``bytes`` decides)."""
        if src.get(SOURCE_HASH):
            return src[SOURCE_HASH] == digests()
        if src.get("sha256"):
            return src["sha256"] == file_sha256(rec.files)
        return None

    sizes = []
    for f in rec.files:
        try:
            sizes.append(Path(f).stat().st_size)
        except OSError:
            sizes.append(None)
    # the digest goes in with the final attributes (ingest.complete); "bytes" tells an interrupted run's
    # scene from another recording's before then
    source = {"recording": str(rec.path), "files": [str(f) for f in rec.files], "bytes": sizes,
              "reader": rec.kind, "truncated": bool(rec.truncated), **(getattr(rec, "attrs", None) or {}),
              **({"problems": rec.problems[:20]} if rec.problems else {}),
              **({"beamform": plan.streams["radar"].attrs} if getattr(plan.streams.get("radar"), "attrs", None) else {})}
    # what the frames and their contents depend on: a resumed run must agree
    fingerprint = hashlib.sha256(json.dumps(
        {"topics": plan.tmap.to_dict(), "tolerance_ns": plan.tolerance_ns, "frames": plan.frame_stamps.tolist(),
         "match": {r: v.tolist() for r, v in plan.match.items()}}, sort_keys=True).encode()).hexdigest()
    existing = ds.scene_ids()
    if plan.scene_id in existing:
        cur = ds.scene(plan.scene_id).attrs
        src = cur.get("source") if isinstance(cur.get("source"), dict) else {}
        same = same_source(src)
        if same is False or (same is None and src.get("bytes") not in (None, sizes)):
            raise DatasetError(f"{ds.url}: scene {plan.scene_id!r} was ingested from another recording "
                               f"({(cur.get('source') or {}).get('recording')}); choose another --scene-id")
        prev = (cur.get("ingest") or {}).get("fingerprint")
        if prev and prev != fingerprint:
            raise DatasetError(f"{ds.url}: scene {plan.scene_id!r} was started with other topics/tolerance; rerun with "
                               f"the same options or choose another --scene-id")
        if (cur.get("ingest") or {}).get("complete"):
            return {"scene": plan.scene_id, "frames": T, "skipped": "already ingested"}
    attrs = {"frame_sensor": fs, "source": source, "sensors": _sensor_attrs(plan),
             "extrinsics": _extrinsics(plan),
             "ingest": {"complete": False, "topics": plan.tmap.to_dict(), "fingerprint": fingerprint}}
    sc = ds.scene(plan.scene_id, n_frames=T, attrs=attrs)
    S = ds.shard_frames
    outs: dict[str, _Out] = {}
    arrays = []

    bulk = codec or BULK_CODEC

    def frame_arr(name, shape, dtype, dims, units, codec=codec, **kw):
        arrays.append(name)
        return sc.frame_array(name, per_frame_shape=shape, dtype=dtype, dims=dims, units=units, codec=codec, **kw)

    # small arrays known now
    ts = frame_arr(TIME_TIMESTAMP_NS, (), "int64", ["frame"], "ns")
    for k in range(ts.n_shards):
        ts.write_shard(k, plan.frame_stamps[ts.frames(k)])
    # per-role expected frames
    exp: dict[str, dict[int, list[int]]] = {}     # role -> item index -> frames
    for role in plan.streams:
        items = plan.frame_items if role == fs else plan.match[role]
        d: dict[int, list[int]] = {}
        for f, i in enumerate(items.tolist()):
            if i >= 0:
                d.setdefault(i, []).append(f)
        exp[role] = d
    if "radar" in plan.streams:
        rs = plan.streams["radar"]
        shape = rs.shape
        fb = int(np.prod(shape)) * rs.dtype.itemsize
        hm = frame_arr(RADAR_HEATMAP, shape, rs.dtype.newbyteorder("="), ["frame", "range", "elevation", "azimuth"],
                       "1", shard_frames=_shard_frames(fb, S), fill_value=float("nan"), codec=bulk,
                       attrs={"amplitude": "linear", "topic": rs.topic})
        outs[RADAR_HEATMAP] = _Out(hm, False, lambda: np.full(shape, np.nan, rs.dtype), set(range(T)), bg)
        cyc = frame_arr(RADAR_CYCLE_NS, (2,), "int64", ["frame", "start_end"], "ns")
        outs[RADAR_CYCLE_NS] = _Out(cyc, False, lambda: np.zeros(2, np.int64), set(range(T)), bg)
        if plan.keep_iq:
            _iq_outputs(plan, sc, frame_arr, outs, T, S, bg)
            if RADAR_IQ_STATIC in sc.arrays():
                arrays.append(RADAR_IQ_STATIC)
    for role in ("lidar", "camera"):
        if role not in plan.streams:
            continue
        frames_with = {f for fl in exp[role].values() for f in fl}
        pts = sc.ragged_array(POINTS_OF[role], width=3, dtype="float32", units="m", codec=bulk)
        arrays.append(POINTS_OF[role])
        outs[POINTS_OF[role]] = _Out(pts, True, lambda: np.zeros((0, 3), np.float32), set(frames_with), bg)
        pr = plan.probe.get(role) or {}
        if role == "lidar" and pr.get("time"):
            pt = sc.ragged_array(LIDAR_POINT_TIME_NS, width=1, dtype="int64", units="ns", dims=["point", "time"],
                                 codec=bulk)
            arrays.append(LIDAR_POINT_TIME_NS)
            outs[LIDAR_POINT_TIME_NS] = _Out(pt, True, lambda: np.zeros((0, 1), np.int64), set(frames_with), bg)
        if role == "lidar" and pr.get("grid"):
            gshape = tuple(pr["grid"])
            lr = frame_arr(LIDAR_RANGE, gshape, "float32", ["frame", "beam", "column"], "m",
                           shard_frames=_shard_frames(4 * int(np.prod(gshape)), S), codec=bulk)
            outs[LIDAR_RANGE] = _Out(lr, False, lambda g=gshape: np.full(g, np.nan, np.float32), set(frames_with), bg)
    # which items to decode: frames of unfinished shards only (resume)
    want: dict[str, set[int]] = {}
    for role, d in exp.items():
        names = [n for n in outs if n.startswith(role + "/")]
        w = set()
        for i, fl in d.items():
            if any(not outs[n].shard_done(f) for n in names for f in fl):
                w.add(i)
        want[role] = w
    stamp_out = [role for role in plan.streams if role != "radar"]
    decoded = {r: 0 for r in plan.streams}
    n_points = {r: 0 for r in plan.streams}
    failed = {r: 0 for r in plan.streams}
    fail_msg: dict[str, str] = {}
    grid_bad = 0

    def deliver(role, item):
        nonlocal grid_bad
        frames = exp[role].get(item.index)
        if not frames:
            return
        p = item.payload
        for f in frames:
            if role == "radar":
                outs[RADAR_HEATMAP].put(f, p.heatmap)
                outs[RADAR_CYCLE_NS].put(f, np.asarray(p.cycle, np.int64))
                if RADAR_IQ in outs:
                    _put_iq(outs, f, p.iq)
            else:
                outs[POINTS_OF[role]].put(f, p.points)
                n_points[role] += len(p.points)
                if role == "lidar" and LIDAR_POINT_TIME_NS in outs:
                    t = p.time_ns if p.time_ns is not None else np.zeros(len(p.points), np.int64)
                    outs[LIDAR_POINT_TIME_NS].put(f, np.asarray(t, np.int64).reshape(-1, 1))
                if role == "lidar" and LIDAR_RANGE in outs:
                    g = outs[LIDAR_RANGE]
                    if p.grid is not None and p.grid.shape == g.w.shape[1:]:
                        g.put(f, p.grid)
                    else:
                        grid_bad += 1
                        g.fail(f)

    def failed_item(role, idx, err):
        failed[role] += 1
        fail_msg.setdefault(role, _one_line(err))
        for f in exp[role].get(idx, []):
            for n, o in outs.items():
                if n.startswith(role + "/"):
                    o.fail(f)

    by_topic = {tp: st for st in plan.streams.values() for tp in st.topics}
    for st in plan.streams.values():
        st.reset()
    total = sum(t.count for t in rec.topics(frame_ids=False) if t.name in by_topic)
    t_pass = time.perf_counter()
    t_decode = 0.0
    heads = _head_topics(plan.streams)
    for raw in track(rec.raw_heads(list(by_topic), heads), total, f"ingest {plan.scene_id}: write", quiet,
                     unit="messages"):
        st = by_topic[raw.topic]
        t = time.perf_counter()
        try:
            items = st.feed(raw, decode=True, want=want[st.role])
        except HolodataError as err:
            failed_item(st.role, getattr(err, "item", -1), err)
            continue
        finally:
            t_decode += time.perf_counter() - t
        fresh = False
        for it in items:
            if it.payload is not None:
                decoded[st.role] += 1
                deliver(st.role, it)
                fresh = True
        if fresh:
            for o in outs.values():
                o.flush()
    for role, st in plan.streams.items():
        for it in st.flush(decode=True, want=want[role]):
            if it.payload is not None:
                decoded[role] += 1
                deliver(role, it)
    for o in outs.values():
        o.flush(final=True)
    bg.join()
    timings = {"index_pass_s": round(plan.index_seconds, 4), "write_pass_s": round(time.perf_counter() - t_pass, 4),
               "decode_s": round(t_decode, 4), "store_s": round(bg.seconds + sum(o.seconds for o in outs.values()), 4)}
    if failed.get(fs):
        raise RecordingError(f"{rec.path}: {failed[fs]} {fs} messages decoded in the index pass but not in the "
                             f"write pass ({fail_msg.get(fs)})")
    # per-frame stamps of the other sensors: the matched message's stamp, 0 = none (or it failed)
    for role in stamp_out:
        if role == fs:
            vals = plan.frame_stamps
        else:
            ok = np.zeros(T, bool)
            ok[sorted(outs[POINTS_OF[role]].expected)] = True
            vals = np.where(ok, plan.match_stamp[role], 0)
        w = frame_arr(STAMPS_OF[role], (), "int64", ["frame"], "ns")
        for k in range(w.n_shards):
            w.write_shard(k, vals[w.frames(k)])
    warnings = list(plan.warnings)
    for role, n in failed.items():
        if n and role != "radar":
            plan.dropped[role]["failed_in_write_pass"] = n
            warnings.append(f"{n} {role} messages on {plan.streams[role].topic} did not decode ({fail_msg[role]}); "
                            f"their frames have no {role} data")
    for role in ("lidar", "camera"):
        if decoded.get(role) and not n_points[role]:
            warnings.append(f"all {decoded[role]} decoded {role} messages on {plan.streams[role].topic} hold no valid "
                            f"point (non-finite or (0, 0, 0)); {role}/points is empty")
    if grid_bad:
        warnings.append(f"{grid_bad} LiDAR scans do not fit the {outs[LIDAR_RANGE].w.shape[1:]} grid; "
                        f"their lidar/range frames are NaN")
    # poses
    pose_note = _write_poses(plan, sc, frame_arr)
    if pose_note:
        warnings.append(pose_note)
    tf_note = _write_lidar_tf(plan, frame_arr)
    if tf_note:
        warnings.append(tf_note)
    sync = {}
    for role in plan.match:
        ok = plan.match[role] >= 0
        off = (plan.match_stamp[role] - plan.frame_stamps)[ok]
        sync[role] = {"matched_frames": int(ok.sum()), "tolerance_ns": int(plan.tolerance_ns.get(role, 0)),
                      "offset_ns_median": int(np.median(off)) if len(off) else None,
                      "offset_ns_max_abs": int(np.abs(off).max()) if len(off) else None}
    sc.set_attrs({"source": {**source, SOURCE_HASH: digests()},
                  "ingest": {"complete": True, "fingerprint": fingerprint, "topics": plan.tmap.to_dict(),
                             "time_source": plan.tmap.time,
                             "counts": plan.counts, "decoded": decoded, "dropped": plan.dropped, "sync": sync,
                             "notes": plan.notes[:20], "warnings": warnings[:50]}})
    return {"scene": plan.scene_id, "recording": str(rec.path), "frames": T, "frame_sensor": fs,
            "arrays": sorted(set(arrays)), "counts": plan.counts, "decoded": decoded, "dropped": plan.dropped,
            "sync": sync, "truncated": bool(rec.truncated), "warnings": warnings, "notes": plan.notes,
            "timings": timings}


def _iq_outputs(plan: Plan, sc, frame_arr, outs: dict, T: int, S: int, bg) -> None:
    """``radar/iq`` (T, L, V, S) complex64: each rotation's raw chirp frames, the neighbouring ones its
    beams use first and last (``radar/iq_span`` (T, 3) int32 = before, rotation, after; zero-padded
    to L); ``radar/iq_motion`` (T, 2) float64: travel per chirp (m) and heading (rad) it was imaged
    with; ``radar/iq_static`` (V, S) complex64: the trajectory's static reflection, subtracted before
    imaging. ``holodata beamform`` re-images them (:mod:`holodata.beamforming`)."""
    src = plan.rec if hasattr(plan.rec, "iq_shape") else plan.streams["radar"]   # a raw reader, or raw messages
    L, V, Sm = src.iq_shape()
    if hasattr(src, "static_refl"):    # a trajectory mean exists only where the reader sees every chirp
        sc.write_array(RADAR_IQ_STATIC, np.asarray(src.static_refl(), np.complex64), ["antenna", "sample"])
    iq = frame_arr(RADAR_IQ, (L, V, Sm), "complex64", ["frame", "chirp", "antenna", "sample"], "1",
                   shard_frames=_shard_frames(8 * L * V * Sm, S), fill_value=0, codec=BULK_CODEC,
                   attrs={"scale": "unit (the recording's int16 scale divided out)",
                          "layout": "chirp frames [before | rotation | after] as radar/iq_span says, then zeros"})
    span = frame_arr(RADAR_IQ_SPAN, (3,), "int32", ["frame", "before_rotation_after"], "chirp frames")
    mot = frame_arr(RADAR_IQ_MOTION, (2,), "float64", ["frame", "ds0_heading"], "m, rad",
                    attrs={"columns": "travel per chirp (m), heading counter-clockwise from beam 0 (rad)"})
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
    world = plan.tmap.world_frame or _world_frame(tf, radar_frame)
    if world is None:
        return f"TF does not connect radar frame {radar_frame!r} to a world frame; no pose/T_world_radar"
    res = tf.lookup_many(world, radar_frame, plan.frame_stamps)
    if res is None:
        return f"TF does not connect radar frame {radar_frame!r} to {world!r}; no pose/T_world_radar"
    poses, ok = res
    if not ok.all():
        return (f"TF covers only {int(ok.sum())} of {len(ok)} radar frames ({world} -> {radar_frame}); "
                f"no pose/T_world_radar")
    w = frame_arr(POSE_T_WORLD_RADAR, (4, 4), "float64", ["frame", "row", "col"], "m",
                  attrs={"world_frame": world, "sensor_frame": radar_frame, "source": "tf"})
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
    frame = _sensor_frame(plan, "lidar")
    if not frame:
        return None
    from ..readers.tf import BASE_FRAMES

    world = plan.tmap.world_frame or _world_frame(tf, frame)
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
    w = frame_arr(TF_T_WORLD_LIDAR, (4, 4), "float64", ["frame", "row", "col"], "m", fill_value=float("nan"),
                  attrs={"world_frame": world, "sensor_frame": frame, "source": "tf",
                         "covered_frames": int(ok.sum()), "time": "the frame's LiDAR scan stamp"})
    for k in range(w.n_shards):
        w.write_shard(k, poses[w.frames(k)])
    if not ok.any():
        return f"TF ({world} -> {frame}) covers none of the LiDAR scans; tf/T_world_lidar is NaN"
    return None


def _world_frame(tf, frame: str) -> str | None:
    """``map``/``world``/``odom`` if TF connects it to ``frame``, else the root of ``frame``'s tree
    when a moving (non-static) transform leads from it to ``frame`` — a tree of static transforms only
    is the rig's own (``base_link → radar``), not a world the sensor moves in."""
    from ..readers.tf import WORLD_FRAMES

    for cand in WORLD_FRAMES:
        if cand in tf.frames and tf._path(cand, frame, False) is not None:
            return cand
    root = tf.root(frame)
    return None if root == frame or tf._path(root, frame, True) is not None else root


def _sensor_frame(plan: Plan, role: str) -> str | None:
    st = plan.streams.get(role)
    if st is None:
        return None
    if role == "radar":
        return str(st.first.header.frame_id).lstrip("/")
    pr = plan.probe.get(role) or {}
    return (pr.get("frame_id") or "").lstrip("/") or None


def _extrinsics(plan: Plan) -> dict:
    tf = plan.tf
    if tf is None or not tf.frames:
        return {}
    from ..readers.tf import BASE_FRAMES, find_frame

    base = plan.tmap.base_frame or find_frame(tf.frames, BASE_FRAMES)
    out = {}
    if base is None:
        return out
    for role in ("radar", "lidar", "camera"):
        fr = _sensor_frame(plan, role)
        if not fr:
            continue
        T = tf.lookup(base, fr, None, static_only=True)
        if T is not None:
            out[role] = T.tolist()
    return out


def _sensor_attrs(plan: Plan) -> dict:
    out: dict = {}
    tf = plan.tf
    for role, st in plan.streams.items():
        d = {"topic": st.topic, "frame_id": _sensor_frame(plan, role)}
        if role == "radar":
            m = st.first
            d.update({"type": m.__class__.__name__ if not hasattr(m, "__msgtype__") else m.__msgtype__,
                      "encoding": str(m.encoding), "shape": list(st.shape),
                      "rotation_radius_m": float(m.rotation_radius), "range_resolution_m": float(m.range_resolution),
                      "elevation_max_rad": float(m.elevation_max), "elevation_min_rad": float(m.elevation_min),
                      "beam_origin": radar_beam_origin(m, st.topic).to_attrs()})
        if isinstance(st, (OusterScanStream, OusterPacketStream)):
            meta = st.rec.meta if isinstance(st, OusterScanStream) else None
            if meta is None:
                from ..readers.ouster import load_info, sensor_meta

                info, text = load_info(st.metadata_text)
                meta = sensor_meta(info, text)
            d["ouster"] = meta.to_attrs()
            d["ouster_metadata_json"] = meta.json_text
            d["range_definition"] = "Ouster RANGE channel (beam origin), destaggered"
        elif role == "lidar":
            pr = plan.probe.get("lidar") or {}
            d["organised_grid"] = list(pr["grid"]) if pr.get("grid") else None
            if pr.get("grid"):
                d["range_definition"] = ("norm of xyz (sensor origin), grid as published" if isinstance(st, CloudStream)
                                         else "range image as stored in the recording (m)")
            if getattr(st, "time_field", None):
                d["time_field"] = st.time_field
                d["time_reference"] = st.time_reference
        if isinstance(st, StereoStream):
            d["stereo"] = {"right_topic": st.right_topic, "right_camera_info_topic": st.right_info_topic,
                           "baseline_m": st.baseline, "matcher": "OpenCV StereoSGBM (3-way), block 5",
                           "depth": "fx * baseline / disparity"}
        if isinstance(st, DepthStream):
            d["camera_info_topic"] = st.info_topic
            d["intrinsics"] = st.model.to_attrs()
            d["stride"] = st.stride
            d["points_frame"] = "optical (x right, y down, z forward)"
        T_frame_points = np.eye(4)
        if isinstance(st, CameraCloudStream) and st.model is not None:
            d["camera_info_topic"] = st.info_topic
            d["intrinsics"] = {**st.model.to_attrs(), "source": st.model_source}
            d["points_frame"] = ("optical (x right, y down, z forward)" + (
                "" if np.array_equal(st.R_opt, np.eye(3)) else f", rotated from the cloud's frame {d['frame_id']!r}"))
            T_frame_points[:3, :3] = st.R_opt.T      # the points' optical axes in the cloud's frame
        fr = d.get("frame_id")
        if tf is not None and fr and tf.frames:
            from ..readers.tf import WORLD_FRAMES, find_frame

            world = plan.tmap.world_frame or find_frame(tf.frames, WORLD_FRAMES)
            if world:
                T = tf.lookup(world, fr, None, static_only=True)
                if T is not None:
                    d[f"T_{world}_sensor"] = (T @ T_frame_points).tolist()   # the frame camera/points are in
        out[role] = d
    return out
