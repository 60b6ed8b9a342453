"""The index and sync passes: :func:`plan_recording` takes an opened recording, maps its topics, indexes
the messages and matches every sensor to the frames (:class:`Plan`; nothing written)."""
from __future__ import annotations

import hashlib
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..conventions import Grid, RangeBins
from ..errors import HolodataError, InputError, RecordingError, one_line
from ..readers import SYNTH_MAPPING, synth_output_folder
from ..readers.base import POINTS_TYPE, RANGE_IMAGE_TYPE, Recording, TopicInfo
from .roles import DEFAULT_TOLERANCE_MS, IMAGE, OUSTER_PACKETS, OUSTER_SCAN, PC2, TopicMap, map_topics
from .radar_streams import RadarStream, RawRadarStream, radar_stream
from .streams import (CameraCloudStream, CloudStream, DepthStream, GridStream, OusterPacketStream, OusterScanStream,
                      PointsStream, StereoStream, _Stream)


@dataclass
class Plan:
    rec: Recording
    scene_id: str
    tmap: TopicMap
    notes: list[str]
    frame_sensor: str
    streams: dict           # role -> stream
    frame_stamps: np.ndarray  # (T,) int64
    frame_items: np.ndarray   # (T,) item index of the frame sensor
    match: dict               # role -> (T,) item index or -1
    match_stamp: dict         # role -> (T,) stamp or 0
    counts: dict
    dropped: dict
    warnings: list[str]
    grid: Grid | None = None
    range_bins: RangeBins | None = None
    tf: object = None
    probe: dict = field(default_factory=dict)
    digests: list = field(default_factory=list)    # SOURCE_HASH of each file
    sha_future: object = None
    index_seconds: float = 0.0
    tolerance_ns: dict = field(default_factory=dict)
    keep_iq: bool = False     # also store the raw radar samples (readers of raw radar only)


def _reject_reason(rec: Recording, infos: list[TopicInfo], tmap: TopicMap, notes: list[str]) -> str:
    with_msgs = [t for t in infos if t.count]
    summary = ", ".join(f"{t.name} {t.msgtype.split('/')[-1]} x{t.count}" for t in with_msgs[:5])
    if len(with_msgs) > 5:
        summary += f", ... ({len(with_msgs)} topics)"
    types = {t.msgtype for t in with_msgs}
    if tmap.camera:
        return (f"{rec.path}: camera-only recording (camera {tmap.camera}, no radar or LiDAR topic); holodata frames "
                f"are radar rotations or LiDAR scans, so there is nothing to ingest")
    if any(ty.endswith("/Imu") for ty in types) and not types & {PC2, IMAGE}:
        return (f"{rec.path}: IMU/odometry-only recording ({summary}); ingest needs a radar, point cloud, depth "
                f"image or Ouster topic")
    missing = [t for t in with_msgs if not t.decodable and "--msg-dir" in t.note]
    if missing:
        names = ", ".join(f"{t.name} ({t.msgtype})" for t in missing[:3])
        return (f"{rec.path}: no usable sensor topic; {len(missing)} topic(s) have no message definition ({names}"
                f"{' ...' if len(missing) > 3 else ''}): pass --msg-dir with their .msg files")
    if with_msgs and all(not t.decodable for t in with_msgs):
        why = next((t.note for t in with_msgs if t.note), "")
        return f"{rec.path}: no decodable topic ({why}); nothing to ingest"
    extra = f"; {notes[0]}" if notes else ""
    return (f"{rec.path}: no radar, point cloud, depth image or Ouster topic ({summary or 'no messages'}){extra}; "
            f"nothing to ingest")


def _scene_id(path: Path) -> str:
    """Scene id from a recording's file or folder name; a synth recording (``OUT/recording``
    beside ``OUT/truth/``) or a synth output folder is named after ``OUT``."""
    p = Path(path)
    if p.name in SYNTH_MAPPING and (p.parent / "truth").is_dir():   # a synth mapping pass: <OUT>_map
        return f"{_scene_id(p.parent)}_map"
    p = synth_output_folder(path) or p
    name = p.name if p.is_dir() else p.stem
    sid = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "scene"
    return sid


SOURCE_HASH = "blake3"   # the digest ingest writes into a scene's source attrs (source.blake3)


def file_sha256(paths: list[Path]) -> list[str]:
    """sha256 (hex) of each file: the source digest of scenes ingested before BLAKE3 (source.sha256),
    still computed to compare a recording with such a scene."""
    return file_digests(paths, "sha256")


def file_digests(paths: list[Path], algo: str = SOURCE_HASH) -> list[str]:
    """Hex digest of each file, read in 4 MB blocks into one reused buffer (a fresh 4 MB bytes object
    per block is a fresh mapping whose pages fault in every time): ``blake3`` (the BLAKE3 reference
    hash, multi-threaded within each block; less CPU than sha256 even with SHA-NI, measured in
    benchmarks/results/ingest.md) or ``sha256``."""
    out = []
    buf = bytearray(4 << 20)
    view = memoryview(buf)
    for p in paths:
        if algo == "blake3":
            import blake3

            h = blake3.blake3(max_threads=blake3.blake3.AUTO)
        else:
            h = hashlib.new(algo)
        with open(p, "rb", buffering=0) as f:
            while n := f.readinto(buf):
                h.update(view[:n])
        out.append(h.hexdigest())
    return out


def _tolerance_ns(tolerance_ms: float | None, stamps: np.ndarray) -> int:
    """``tolerance_ms`` if given; else auto: half the sensor's median period, at least 50 ms (every
    frame then gets the nearest message of a sensor that kept publishing)."""
    if tolerance_ms is not None:
        return int(round(tolerance_ms * 1e6))
    auto = int(round(DEFAULT_TOLERANCE_MS * 1e6))
    if len(stamps) > 1:
        d = np.diff(np.sort(stamps))
        d = d[d > 0]
        if len(d):
            auto = max(auto, int(np.median(d)) // 2 + 1)
    return auto


def _nearest(frame_t: np.ndarray, item_t: np.ndarray, tol_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """For each frame time the index (into item_t, sorted) of the nearest item within tol, else -1;
    and the offset item - frame (0 where none)."""
    idx = np.full(len(frame_t), -1, np.int64)
    off = np.zeros(len(frame_t), np.int64)
    if len(item_t) == 0 or len(frame_t) == 0:
        return idx, off
    j = np.searchsorted(item_t, frame_t)
    lo = np.clip(j - 1, 0, len(item_t) - 1)
    hi = np.clip(j, 0, len(item_t) - 1)
    d_lo = np.abs(item_t[lo] - frame_t)
    d_hi = np.abs(item_t[hi] - frame_t)
    best = np.where(d_hi < d_lo, hi, lo)
    d = np.abs(item_t[best] - frame_t)
    ok = d <= tol_ns
    idx[ok] = best[ok]
    off[ok] = (item_t[best] - frame_t)[ok]
    return idx, off


def plan_recording(rec: Recording, topics: dict | None = None, scene_id: str | None = None,
                   tolerance_ms: float | None = None, quiet: bool = True, beamform=None,
                   keep_iq: bool = False, motion: str | None = None) -> Plan:
    """Map, index and sync one opened recording ``rec`` (:func:`holodata.readers.open_recording`;
    nothing written). RecordingError if unusable. The plan reads ``rec`` again when it is written
    (``plan.rec``): whoever opened it closes it, after :func:`~holodata.ingest.write.write_plan`.
    ``beamform``: :class:`~holodata.radar.beam_geometry.BeamformParams` for recordings of raw radar
    samples (the one ``rec`` was opened with); ``keep_iq``: also store those samples (``radar/iq``,
    for ``holodata beamform``); ``motion``: the override ``rec`` was opened with (a warning when
    the recording has no folder-name rule for it to override)."""
    from ..progress import track

    from concurrent.futures import ThreadPoolExecutor

    _limit_malloc_arenas()
    pool = ThreadPoolExecutor(1)   # checksums overlap the index pass (hashlib releases the GIL)
    sha = pool.submit(file_digests, rec.files)
    pool.shutdown(wait=False)
    try:
        plan = _plan(rec, topics, scene_id, tolerance_ms, quiet, track, beamform)
    except BaseException:
        sha.cancel()
        raise
    plan.sha_future = sha
    if motion is not None and "motion" not in rec.decisions:
        plan.warnings.append(f"{rec.path}: the robot's motion is not read from folder names in this recording; "
                             f"--beamform-motion has nothing to override")
    if keep_iq and "radar" in plan.streams and (hasattr(rec, "iq_shape") or hasattr(plan.streams["radar"], "iq_shape")):
        plan.keep_iq = True
    elif keep_iq:
        plan.warnings.append(f"{rec.path}: no raw radar samples in this recording; --keep-iq has nothing to keep")
    return plan


def _plan(rec, topics, scene_id, tolerance_ms, quiet, track, beamform=None) -> Plan:
    infos = rec.topics(frame_ids=True)
    tmap, notes = map_topics(rec, topics, infos)
    by = {t.name: t for t in infos}
    warnings: list[str] = list(rec.problems)
    if not tmap.radar and not tmap.lidar:
        raise RecordingError(_reject_reason(rec, infos, tmap, notes))
    streams: dict[str, _Stream] = {}
    if tmap.radar:
        streams["radar"] = radar_stream(rec, tmap.radar, tmap.time, by[tmap.radar].msgtype, beamform)
    if tmap.lidar:
        ty = by[tmap.lidar].msgtype
        if ty == OUSTER_SCAN:
            streams["lidar"] = OusterScanStream(rec, tmap.lidar, tmap.time)
        elif ty == RANGE_IMAGE_TYPE:
            streams["lidar"] = GridStream(rec, tmap.lidar, tmap.time)
        elif ty == POINTS_TYPE:
            streams["lidar"] = PointsStream(rec, tmap.lidar, tmap.time, "lidar")
        elif ty in OUSTER_PACKETS:
            text = _first_string(rec, tmap.lidar_metadata)
            try:
                from ..readers.ouster import load_info

                load_info(text)
            except HolodataError as err:
                raise RecordingError(f"{rec.path}: Ouster packets on {tmap.lidar} cannot be decoded: "
                                     f"{one_line(err)}") from err
            streams["lidar"] = OusterPacketStream(rec, tmap.lidar, tmap.time, text)
        elif ty == PC2:
            streams["lidar"] = CloudStream(rec, tmap.lidar, tmap.time, "lidar")
        else:
            raise InputError(f"topics file: lidar {tmap.lidar} is a {ty}, not PointCloud2 / Ouster")
    if tmap.camera:
        ty = by[tmap.camera].msgtype
        if ty == IMAGE and tmap.camera_right:
            st = StereoStream(rec, tmap.camera, tmap.time, tmap.camera_info, tmap.camera_stride, tmap.camera_right,
                              tmap.camera_info_right)
            try:
                st.load_first_info()
                streams["camera"] = st
            except HolodataError as err:
                warnings.append(f"{one_line(err)}; camera not used")
        elif ty == IMAGE:
            st = DepthStream(rec, tmap.camera, tmap.time, tmap.camera_info, tmap.camera_stride)
            try:
                st.load_first_info()
                streams["camera"] = st
            except HolodataError as err:
                warnings.append(f"{one_line(err)}; camera not used")
        elif ty == PC2:
            st = CameraCloudStream(rec, tmap.camera, tmap.time, tmap.camera_info)
            note = st.load_model()
            if note:
                warnings.append(note)
            streams["camera"] = st
        elif ty == POINTS_TYPE:
            streams["camera"] = PointsStream(rec, tmap.camera, tmap.time, "camera")
        else:
            raise InputError(f"topics file: camera {tmap.camera} is a {ty}, not Image / PointCloud2")
    frame_sensor = "radar" if "radar" in streams else "lidar"
    if frame_sensor == "lidar" and "lidar" not in streams:
        raise RecordingError(_reject_reason(rec, infos, tmap, notes))
    # ---- index pass (TF read along: static + dynamic buffer)
    from ..readers.tf import TransformBuffer

    tf = TransformBuffer()
    tf_static = set(tmap.tf_static)
    tf_topics = set(tmap.tf) | tf_static
    tf_bad = 0
    stamps: dict[str, list[tuple[int, int]]] = {r: [] for r in streams}
    failed: dict[str, dict[int, str]] = {r: {} for r in streams}
    by_topic = {}
    for st in streams.values():
        for tp in st.topics:
            by_topic[tp] = st
    topics_read = list(by_topic) + sorted(tf_topics - set(by_topic))
    total = sum(by[t].count for t in topics_read if t in by)
    heads = _head_topics(streams)
    index_iter = rec.raw_messages(topics_read, with_xyz=False) if rec.kind == "ouster-pcap" \
        else rec.raw_heads(topics_read, heads)
    t_index = time.perf_counter()
    for raw in track(index_iter, total, f"ingest {scene_id or rec.path.name}: index", quiet, unit="messages"):
        if raw.topic in tf_topics:
            try:
                msg = rec.decode(raw)
                if tf.add_message(msg, static=raw.topic in tf_static) < len(msg.transforms):
                    tf_bad += 1     # a NaN/inf transform (damaged bytes) was left out
            except (HolodataError, AttributeError, ValueError):
                tf_bad += 1
            if raw.topic not in by_topic:
                continue
        st = by_topic[raw.topic]
        try:
            items = st.feed(raw, decode=False, check=(st.role == frame_sensor))
        except HolodataError as err:
            failed[st.role][getattr(err, "item", -1)] = one_line(err)
            continue
        if st.role != "radar" and st.layout is None:
            st.try_layout(raw)
        stamps[st.role] += [(it.index, it.stamp) for it in items]
    if tf_bad:
        warnings.append(f"{tf_bad} TF messages do not decode or hold NaN/inf transforms; skipped")
    t_index = time.perf_counter() - t_index
    for role, st in streams.items():
        stamps[role] += [(it.index, it.stamp) for it in st.flush(decode=False)]

    counts = {r: len(v) + len(failed[r]) for r, v in stamps.items()}
    dropped: dict[str, dict] = {r: {} for r in streams}
    warnings += [p for p in rec.problems if p not in warnings]      # met during the index pass
    lost = rec.dropped_by_container()       # messages in damaged container blocks (MCAP chunk CRC)
    for role, st in streams.items():
        if n := sum(lost.get(t, 0) for t in st.topics):
            dropped[role]["damaged_chunk"] = n
    for role, f in failed.items():
        if f:
            dropped[role]["undecodable"] = len(f)
            first = next(iter(f.values()))
            warnings.append(f"{len(f)} of {counts[role]} {role} messages on {streams[role].topic} do not decode "
                            f"(first: {first}); skipped")
    # ---- frames
    fr = np.array(sorted(stamps[frame_sensor], key=lambda x: (x[1], x[0])), np.int64).reshape(-1, 2)
    if len(fr) == 0:
        reason = next(iter(failed[frame_sensor].values()), "no messages")
        raise RecordingError(f"{rec.path}: no usable {frame_sensor} message on {streams[frame_sensor].topic} "
                             f"({reason})")
    keep = np.r_[True, fr[1:, 1] > fr[:-1, 1]]
    if not keep.all():
        dropped[frame_sensor]["duplicate_stamp"] = int((~keep).sum())
        warnings.append(f"{int((~keep).sum())} {frame_sensor} messages repeat an earlier stamp; dropped")
    fr = fr[keep]
    frame_items, frame_stamps = fr[:, 0], fr[:, 1]
    match, match_stamp, tolerance = {}, {}, {}
    for role in streams:
        if role == frame_sensor:
            continue
        arr = np.array(sorted(stamps[role], key=lambda x: (x[1], x[0])), np.int64).reshape(-1, 2)
        tol = _tolerance_ns(tolerance_ms, arr[:, 1])
        tolerance[role] = tol
        j, off = _nearest(frame_stamps, arr[:, 1], tol)
        match[role] = np.where(j >= 0, arr[np.clip(j, 0, None), 0] if len(arr) else -1, -1)
        match_stamp[role] = np.where(j >= 0, arr[np.clip(j, 0, None), 1] if len(arr) else 0, 0)
        used = len(set(match[role][match[role] >= 0].tolist()))
        unmatched_frames = int((j < 0).sum())
        dropped[role]["not_near_a_frame"] = len(arr) - used
        if unmatched_frames:
            dropped[role]["frames_without"] = unmatched_frames
            warnings.append(f"{unmatched_frames} of {len(frame_stamps)} frames have no {role} message within "
                            f"{tol / 1e6:g} ms")
    plan = Plan(rec, scene_id or _scene_id(rec.path), tmap, notes, frame_sensor, streams, frame_stamps, frame_items,
                match, match_stamp, counts, dropped, warnings, tf=tf, index_seconds=t_index, tolerance_ns=tolerance)
    if "radar" in streams:
        plan.grid, plan.range_bins = _grid_of(rec, streams["radar"])
    plan.probe = {r: st.layout for r, st in streams.items() if r != "radar" and st.layout is not None}
    return plan


def _head_topics(streams: dict) -> set[str]:
    """Topics whose messages both passes may read header-only (``Recording.raw_heads``): one
    message = one item, stamped from its header; ``Recording.decode`` reads the rest of a message
    that is decoded after all (the frame sensor's check, a matched scan or image, a layout probe).
    Unmatched LiDAR scans and camera images are then never read whole."""
    return {st.topic for st in streams.values() if type(st) in (RadarStream, RawRadarStream, CloudStream, DepthStream)}


def _first_string(rec: Recording, topic: str | None) -> str:
    if not topic:
        raise RecordingError(f"{rec.path}: Ouster packets need the sensor metadata (a String topic)")
    for raw in rec.raw_messages([topic]):
        try:
            return str(rec.decode(raw).data)
        except HolodataError:
            continue
    raise RecordingError(f"{rec.path}: metadata topic {topic} has no readable String message")


def _limit_malloc_arenas(n: int = 1) -> None:
    """glibc gives each thread that allocates under contention its own malloc arena (up to 8 per
    core); the writer threads free many ~1-2 MB buffers (message payloads, Blosc chunks) that then
    fragment those arenas, so peak RSS crept up with recording length; one arena for the threads
    started from here on keeps it nearly flat (docs/design/performance.md, benchmarks/results/ingest.md).
    No-op off glibc."""
    global _ARENAS_LIMITED
    if _ARENAS_LIMITED:
        return
    _ARENAS_LIMITED = True
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-8, int(n))   # M_ARENA_MAX
    except (OSError, AttributeError, TypeError):
        pass


_ARENAS_LIMITED = False


def _grid_of(rec, st: RadarStream) -> tuple[Grid, RangeBins]:
    msg = st.first
    R, H, W = st.shape
    emax, emin = math.degrees(float(msg.elevation_max)), math.degrees(float(msg.elevation_min))
    try:
        return Grid(H, W, round(emax, 5), round(emin, 5)), RangeBins(R, round(float(msg.range_resolution), 7))
    except ValueError as err:
        raise RecordingError(f"{rec.path}: radar topic {st.topic} has an unusable grid ({err})") from err
