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
from .radar_streams import RadarStream, RawRadarStream, radar_stream
from .roles import DEFAULT_TOLERANCE_MS, IMAGE, OUSTER_PACKETS, OUSTER_SCAN, PC2, TopicMap, map_topics
from .streams import (
    CameraCloudStream,
    CloudStream,
    DepthStream,
    GridStream,
    OusterPacketStream,
    OusterScanStream,
    PointsStream,
    StereoStream,
    _Stream,
)


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
    from concurrent.futures import ThreadPoolExecutor

    from ..progress import track

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
    """The index and sync passes of :func:`plan_recording` (its arguments; ``track``: the progress
    wrapper), without the checksums."""
    return _Planner(rec, topics, scene_id, tolerance_ms, beamform).run(quiet, track)


class _Planner:
    """:func:`_plan` as named steps sharing their state: the topics mapped and their streams opened
    (:meth:`open_streams`), every message indexed with the TF read along (:meth:`index`), the
    counts and drops (:meth:`count`), the frames (:meth:`frames`) and every other sensor matched to
    them (:meth:`match`). ``warnings`` collects what the passes meet, in the order they meet it."""

    def __init__(self, rec: Recording, topics, scene_id: str | None, tolerance_ms: float | None, beamform=None):
        self.rec, self.topics, self.scene_id, self.tolerance_ms, self.beamform = rec, topics, scene_id, tolerance_ms, beamform
        self.warnings: list[str] = list(rec.problems)
        self.dropped: dict[str, dict] = {}

    def run(self, quiet: bool, track) -> Plan:
        self.open_streams()
        self.index(quiet, track)
        self.count()
        self.frames()
        self.match()
        return self.plan()

    # -- topics and streams
    def open_streams(self) -> None:
        rec = self.rec
        self.infos = rec.topics(frame_ids=True)
        self.tmap, self.notes = map_topics(rec, self.topics, self.infos)
        self.by = {t.name: t for t in self.infos}
        if not self.tmap.radar and not self.tmap.lidar:
            raise RecordingError(_reject_reason(rec, self.infos, self.tmap, self.notes))
        tmap = self.tmap
        streams: dict[str, _Stream] = {}
        if tmap.radar:
            streams["radar"] = radar_stream(rec, tmap.radar, tmap.time, self.by[tmap.radar].msgtype, self.beamform)
        if tmap.lidar:
            streams["lidar"] = self._lidar_stream()
        if tmap.camera:
            cam = self._camera_stream()
            if cam is not None:
                streams["camera"] = cam
        self.streams = streams
        self.frame_sensor = "radar" if "radar" in streams else "lidar"
        if self.frame_sensor == "lidar" and "lidar" not in streams:
            raise RecordingError(_reject_reason(rec, self.infos, tmap, self.notes))

    def _lidar_stream(self) -> _Stream:
        rec, tmap = self.rec, self.tmap
        ty = self.by[tmap.lidar].msgtype
        if ty == OUSTER_SCAN:
            return OusterScanStream(rec, tmap.lidar, tmap.time)
        if ty == RANGE_IMAGE_TYPE:
            return GridStream(rec, tmap.lidar, tmap.time)
        if ty == POINTS_TYPE:
            return PointsStream(rec, tmap.lidar, tmap.time, "lidar")
        if ty in OUSTER_PACKETS:
            text = _first_string(rec, tmap.lidar_metadata)
            try:
                from ..readers.ouster import load_info

                load_info(text)
            except HolodataError as err:
                raise RecordingError(f"{rec.path}: Ouster packets on {tmap.lidar} cannot be decoded: "
                                     f"{one_line(err)}") from err
            return OusterPacketStream(rec, tmap.lidar, tmap.time, text)
        if ty == PC2:
            return CloudStream(rec, tmap.lidar, tmap.time, "lidar")
        raise InputError(f"topics file: lidar {tmap.lidar} is a {ty}, not PointCloud2 / Ouster")

    def _camera_stream(self) -> _Stream | None:
        """The camera's stream, or None (with a warning) for an image topic whose camera info does not load."""
        rec, tmap = self.rec, self.tmap
        ty = self.by[tmap.camera].msgtype
        if ty == IMAGE:
            st: StereoStream | DepthStream
            if tmap.camera_right:
                st = StereoStream(rec, tmap.camera, tmap.time, tmap.camera_info, tmap.camera_stride, tmap.camera_right,
                                  tmap.camera_info_right)
            else:
                st = DepthStream(rec, tmap.camera, tmap.time, tmap.camera_info, tmap.camera_stride)
            try:
                st.load_first_info()
                return st
            except HolodataError as err:
                self.warnings.append(f"{one_line(err)}; camera not used")
                return None
        if ty == PC2:
            cst = CameraCloudStream(rec, tmap.camera, tmap.time, tmap.camera_info)
            note = cst.load_model()
            if note:
                self.warnings.append(note)
            return cst
        if ty == POINTS_TYPE:
            return PointsStream(rec, tmap.camera, tmap.time, "camera")
        raise InputError(f"topics file: camera {tmap.camera} is a {ty}, not Image / PointCloud2")

    # -- the index pass (TF read along: static + dynamic buffer)
    def index(self, quiet: bool, track) -> None:
        from ..readers.tf import TransformBuffer

        rec, streams = self.rec, self.streams
        self.tf = TransformBuffer()
        self.tf_static = set(self.tmap.tf_static)
        self.tf_topics = set(self.tmap.tf) | self.tf_static
        self.tf_bad = 0
        self.stamps: dict[str, list[tuple[int, int]]] = {r: [] for r in streams}
        self.failed: dict[str, dict[int, str]] = {r: {} for r in streams}
        self.by_topic = {tp: st for st in streams.values() for tp in st.topics}
        topics_read = list(self.by_topic) + sorted(self.tf_topics - set(self.by_topic))
        total = sum(self.by[t].count for t in topics_read if t in self.by)
        index_iter = rec.raw_messages(topics_read, with_xyz=False) if rec.kind == "ouster-pcap" \
            else rec.raw_heads(topics_read, _head_topics(streams))
        t_index = time.perf_counter()
        for raw in track(index_iter, total, f"ingest {self.scene_id or rec.path.name}: index", quiet, unit="messages"):
            self._index_message(raw)
        if self.tf_bad:
            self.warnings.append(f"{self.tf_bad} TF messages do not decode or hold NaN/inf transforms; skipped")
        self.index_seconds = time.perf_counter() - t_index
        for role, st in streams.items():
            self.stamps[role] += [(it.index, it.stamp) for it in st.flush(decode=False)]

    def _index_message(self, raw) -> None:
        if raw.topic in self.tf_topics:
            try:
                msg = self.rec.decode(raw)
                if self.tf.add_message(msg, static=raw.topic in self.tf_static) < len(msg.transforms):
                    self.tf_bad += 1     # a NaN/inf transform (damaged bytes) was left out
            except (HolodataError, AttributeError, ValueError):
                self.tf_bad += 1
            if raw.topic not in self.by_topic:
                return
        st = self.by_topic[raw.topic]
        try:
            items = st.feed(raw, decode=False, check=(st.role == self.frame_sensor))
        except HolodataError as err:
            self.failed[st.role][getattr(err, "item", -1)] = one_line(err)
            return
        if st.role != "radar" and st.layout is None:
            st.try_layout(raw)
        self.stamps[st.role] += [(it.index, it.stamp) for it in items]

    # -- counts, drops, frames, sync
    def count(self) -> None:
        streams, warnings = self.streams, self.warnings
        self.counts = {r: len(v) + len(self.failed[r]) for r, v in self.stamps.items()}
        self.dropped = {r: {} for r in streams}
        warnings += [p for p in self.rec.problems if p not in warnings]      # met during the index pass
        lost = self.rec.dropped_by_container()       # messages in damaged container blocks (MCAP chunk CRC)
        for role, st in streams.items():
            if n := sum(lost.get(t, 0) for t in st.topics):
                self.dropped[role]["damaged_chunk"] = n
        for role, f in self.failed.items():
            if f:
                self.dropped[role]["undecodable"] = len(f)
                first = next(iter(f.values()))
                warnings.append(f"{len(f)} of {self.counts[role]} {role} messages on {streams[role].topic} do not "
                                f"decode (first: {first}); skipped")

    def frames(self) -> None:
        fs = self.frame_sensor
        fr = np.array(sorted(self.stamps[fs], key=lambda x: (x[1], x[0])), np.int64).reshape(-1, 2)
        if len(fr) == 0:
            reason = next(iter(self.failed[fs].values()), "no messages")
            raise RecordingError(f"{self.rec.path}: no usable {fs} message on {self.streams[fs].topic} "
                                 f"({reason})")
        keep = np.r_[True, fr[1:, 1] > fr[:-1, 1]]
        if not keep.all():
            self.dropped[fs]["duplicate_stamp"] = int((~keep).sum())
            self.warnings.append(f"{int((~keep).sum())} {fs} messages repeat an earlier stamp; dropped")
        fr = fr[keep]
        self.frame_items, self.frame_stamps = fr[:, 0], fr[:, 1]

    def match(self) -> None:
        self.match_item: dict = {}
        self.match_stamp: dict = {}
        self.tolerance: dict = {}
        for role in self.streams:
            if role != self.frame_sensor:
                self._match_role(role)

    def _match_role(self, role: str) -> None:
        frame_stamps = self.frame_stamps
        arr = np.array(sorted(self.stamps[role], key=lambda x: (x[1], x[0])), np.int64).reshape(-1, 2)
        tol = _tolerance_ns(self.tolerance_ms, arr[:, 1])
        self.tolerance[role] = tol
        j, off = _nearest(frame_stamps, arr[:, 1], tol)
        m = self.match_item[role] = np.where(j >= 0, arr[np.clip(j, 0, None), 0] if len(arr) else -1, -1)
        self.match_stamp[role] = np.where(j >= 0, arr[np.clip(j, 0, None), 1] if len(arr) else 0, 0)
        used = len(set(m[m >= 0].tolist()))
        unmatched_frames = int((j < 0).sum())
        self.dropped[role]["not_near_a_frame"] = len(arr) - used
        if unmatched_frames:
            self.dropped[role]["frames_without"] = unmatched_frames
            self.warnings.append(f"{unmatched_frames} of {len(frame_stamps)} frames have no {role} message within "
                                 f"{tol / 1e6:g} ms")

    def plan(self) -> Plan:
        rec, streams = self.rec, self.streams
        plan = Plan(rec, self.scene_id or _scene_id(rec.path), self.tmap, self.notes, self.frame_sensor, streams,
                    self.frame_stamps, self.frame_items, self.match_item, self.match_stamp, self.counts, self.dropped,
                    self.warnings, tf=self.tf, index_seconds=self.index_seconds, tolerance_ns=self.tolerance)
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
