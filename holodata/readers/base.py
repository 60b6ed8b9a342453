"""What every recording reader provides: :class:`Recording`, :class:`TopicInfo`, :class:`RawMessage`,
and the typestore that decodes ROS messages (:class:`MessageDecoder`).

Readers only parse containers (rosbags, mcap, ouster-sdk do the work); they yield
:class:`RawMessage` records (topic, type, log time, undecoded bytes) so that callers filter first
and decode later. Decoding goes through one rosbags typestore per recording, built from

1. the definitions embedded in the file (ROS 1 connection headers, rosbag2 ``message_definitions``,
   MCAP schemas),
2. ``.msg`` files from ``msg_dir`` (for bags recorded without definitions, e.g. rosbag2 < Iron
   with custom types),
3. rosbags' ROS 2 Humble / ROS 1 Noetic store plus holodata's own ``RadarHeatmap``.

Type hashes (rosbag2 ``type_description_hash``, ROS 1 md5sum) are not checked: real bags carry
placeholder or stale hashes and the definitions above are what decoding needs.
"""
from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import RecordingError


class DecodeError(RecordingError):
    """A message that cannot be decoded (unknown type, corrupt or truncated payload)."""


@dataclass
class TopicInfo:
    """One topic as ``ros2 bag info`` shows it. ``rate_hz`` from the first and last log times;
    ``frame_id`` from the first message's header (None if the type has none or it was not read)."""

    name: str
    msgtype: str
    count: int
    rate_hz: float | None = None
    frame_id: str | None = None
    encoding: str = "cdr"          # cdr | ros1 | other serialisation (listed, not decoded)
    decodable: bool = True
    note: str = ""
    first_ns: int | None = None
    last_ns: int | None = None

    def to_dict(self) -> dict:
        return {"name": self.name, "type": self.msgtype, "count": self.count, "rate_hz": self.rate_hz,
                "frame_id": self.frame_id, "encoding": self.encoding, "decodable": self.decodable,
                **({"note": self.note} if self.note else {})}


@dataclass(slots=True)
class RawMessage:
    """An undecoded message: ``data`` is the serialised payload (CDR, ROS 1, or whatever
    ``encoding`` says); ``log_ns`` the recorder's receive time (int64 ns). ``obj`` carries an
    already-decoded object for containers that have no separate wire format (Ouster pcap scans)."""

    topic: str
    msgtype: str
    log_ns: int
    data: bytes | memoryview | None
    encoding: str = "cdr"
    obj: object = None
    ref: object = None   # set when ``data`` is only a header prefix: Recording.full() reads the rest


def rate_of(count: int, first_ns: int | None, last_ns: int | None) -> float | None:
    if count < 2 or first_ns is None or last_ns is None or last_ns <= first_ns:
        return None
    return (count - 1) / ((last_ns - first_ns) / 1e9)


class Recording:
    """A recording opened by one of the registered readers (see :func:`holodata.readers.open_recording`).

    Attributes: ``path`` (what the user gave), ``kind`` (reader name), ``files`` (the files holding
    the data, for checksums), ``truncated`` (True when only a readable prefix could be read — the
    reason is in ``problems``), ``problems`` (one-line warnings met while reading), ``decisions``
    ({what: how the reader decided it}, e.g. {"motion": "static: parent folder 'bldg_static'"}: what
    the reader read into the recording that no file states; ``ingest --list`` shows them).
    """

    kind = "recording"

    def __init__(self, path: Path):
        self.path = Path(path)
        self.files: list[Path] = []
        self.truncated = False
        self.problems: list[str] = []
        self.decisions: dict[str, str] = {}
        self.decoder: MessageDecoder | None = None

    # -- to implement -----------------------------------------------------------------------------
    def _topics(self) -> list[TopicInfo]:
        raise NotImplementedError

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Messages of ``topics`` (all if None) in log-time order, undecoded."""
        raise NotImplementedError

    def raw_heads(self, topics: Iterable[str], heads: Iterable[str]) -> Iterator[RawMessage]:
        """Like :meth:`raw_messages`, but a reader that can seek to each message may give only a
        header prefix (enough for :meth:`stamp_ns`/``frame_id``) of messages on ``heads``, with
        ``ref`` set; :meth:`full` reads the rest when the message is needed after all. The
        default reads everything."""
        return self.raw_messages(topics)

    def full(self, raw: RawMessage) -> RawMessage:
        """``raw`` with its whole payload (itself unless it came header-only from :meth:`raw_heads`)."""
        return raw

    def dropped_by_container(self) -> dict[str, int]:
        """{topic: messages} the reader left out because the container's own checks failed (an MCAP
        chunk's CRC); counted by ingest in the scene's ``ingest.dropped``."""
        return {}

    def mark_truncated(self, problem: str) -> None:
        """The recording breaks off here: ``truncated`` set, ``problem`` (one line) noted once."""
        self.truncated = True
        if problem not in self.problems:
            self.problems.append(problem)

    def close(self) -> None:
        pass

    # -- shared -----------------------------------------------------------------------------------
    def topics(self, frame_ids: bool = True) -> list[TopicInfo]:
        """Topics with type, count, rate and (``frame_ids``) the first message's header frame id."""
        infos = self._topics()
        if frame_ids and self.decoder is not None:
            want = {t.name: t for t in infos if t.count > 0 and t.decodable and self.decoder.has_header(t.msgtype)}
            if want:
                try:     # header prefixes where the reader can seek to each message (raw_heads)
                    for raw in self.raw_heads(list(want), want):
                        info = want.pop(raw.topic, None)
                        if info is not None:
                            fid = self.decoder.frame_id(raw)
                            info.frame_id = fid if fid is not None or raw.ref is None else \
                                self.decoder.frame_id(self.full(raw))
                        if not want:
                            break
                except RecordingError:
                    pass
        return infos

    def topic(self, name: str) -> TopicInfo | None:
        return next((t for t in self._topics() if t.name == name), None)

    def decode(self, raw: RawMessage):
        """The decoded message (rosbags message object, or the reader's own object)."""
        if raw.obj is not None:
            return raw.obj
        if raw.ref is not None:   # header-only (raw_heads): read the whole payload now
            raw = self.full(raw)
        if self.decoder is None:
            raise DecodeError(f"{self.path}: topic {raw.topic}: messages of this recording cannot be decoded")
        return self.decoder.decode(raw)

    def stamp_ns(self, raw: RawMessage) -> int:
        """Header stamp when the type has a header and it is non-zero, else the log time."""
        if self.decoder is not None and raw.data is not None:
            s = self.decoder.header_stamp(raw)
            if s:
                return s
        return raw.log_ns

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, object]]:
        """(topic, log time ns, decoded message), lazily; undecodable messages raise DecodeError."""
        for raw in self.raw_messages(topics):
            yield raw.topic, raw.log_ns, self.decode(raw)

    def duration_ns(self) -> tuple[int | None, int | None]:
        infos = [t for t in self._topics() if t.first_ns is not None]
        if not infos:
            return None, None
        return min(t.first_ns for t in infos), max(t.last_ns for t in infos)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        return f"<{self.__class__.__name__} {self.kind} {self.path}>"


# --------------------------------------------------------------------------------------------------
# typestore

def _msg_dir_types(msg_dir: Path) -> dict:
    """Types from ``.msg`` files under ``msg_dir``: ``<pkg>/msg/<Name>.msg`` -> ``pkg/msg/Name``
    (a file directly in a folder named ``pkg`` gives the same)."""
    from rosbags.typesys import get_types_from_msg

    msg_dir = Path(msg_dir)
    if not msg_dir.is_dir():
        raise RecordingError(f"{msg_dir}: --msg-dir is not a folder")
    typs: dict = {}
    files = sorted(msg_dir.rglob("*.msg"))
    if not files:
        raise RecordingError(f"{msg_dir}: --msg-dir holds no .msg files")
    for f in files:
        parent = f.parent
        pkg = parent.parent.name if parent.name == "msg" else parent.name
        name = f"{pkg}/msg/{f.stem}"
        try:
            typs.update(get_types_from_msg(f.read_text(), name))
        except Exception as err:  # noqa: BLE001 - rosbags raises several kinds
            raise RecordingError(f"{f}: not a valid .msg definition ({' '.join(str(err).split())})") from err
    return typs


def _closure(typs: dict, roots) -> set[str]:
    """Names in ``typs`` reachable from ``roots`` through field types."""
    out: set[str] = set()
    todo = [r for r in roots if r in typs]

    def names(desc):
        if isinstance(desc, str):
            if desc in typs:
                yield desc
        elif isinstance(desc, (tuple, list)):
            for d in desc:
                yield from names(d)

    while todo:
        t = todo.pop()
        if t in out:
            continue
        out.add(t)
        for _, desc in typs[t][1]:
            todo.extend(n for n in names(desc) if n not in out)
    return out


class MessageDecoder:
    """Decodes raw messages of one recording with a rosbags typestore (see module docstring).

    ``definitions``: (msgtype, format 'msg'|'idl'|None, text) per connection.
    """

    def __init__(self, ros_version: int, definitions: Iterable[tuple[str, str | None, str]] = (),
                 msg_dir: Path | None = None, path: Path | None = None, needed: Iterable[str] | None = None):
        from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

        from ..messages import typestore_for

        self.path = path
        self.problems: list[str] = []
        typs: dict = {}
        seen = set()
        definitions = list(definitions)
        for msgtype, fmt, text in definitions:
            if not fmt or not text or (msgtype, text) in seen:
                continue
            seen.add((msgtype, text))
            try:
                if fmt == "msg":
                    typs.update(get_types_from_msg(text, msgtype))
                else:
                    sep = "=" * 80 + "\n"
                    if text.startswith(f"{sep}IDL: "):
                        for part in text.split(sep)[1:]:
                            typs.update(get_types_from_idl(part.split("\n", 1)[1]))
                    else:
                        typs.update(get_types_from_idl(text))
            except Exception as err:  # noqa: BLE001
                self.problems.append(f"embedded definition of {msgtype} unreadable "
                                     f"({' '.join(str(err).split())[:120]}); using defaults")
        if msg_dir is not None:
            for k, v in _msg_dir_types(Path(msg_dir)).items():
                typs.setdefault(k, v)
        default = typestore_for(ros_version)
        for k, v in default.fielddefs.items():
            typs.setdefault(k, v)
        # register only what the recording's types need (building every default class is slow:
        # docs/design/performance.md)
        roots = set(needed) if needed is not None else {m for m, _, _ in definitions}
        roots |= {"std_msgs/msg/Header", "std_msgs/msg/String", "tf2_msgs/msg/TFMessage"}
        keep = _closure(typs, roots)
        store = get_typestore(Stores.EMPTY)
        store.register({k: typs[k] for k in keep})
        self.store = store
        self.ros_version = ros_version
        self._header_cache: dict[str, bool] = {}

    def known(self, msgtype: str) -> bool:
        return msgtype in self.store.fielddefs

    def has_header(self, msgtype: str) -> bool:
        h = self._header_cache.get(msgtype)
        if h is None:
            try:
                fields = self.store.fielddefs[msgtype][1]
                h = bool(fields) and fields[0][0] == "header" and fields[0][1][1] == "std_msgs/msg/Header"
            except (KeyError, IndexError, TypeError):
                h = False
            self._header_cache[msgtype] = h
        return h

    def decode(self, raw: RawMessage):
        if raw.encoding not in ("cdr", "ros1"):
            raise DecodeError(f"topic {raw.topic}: message encoding {raw.encoding!r} is not a ROS encoding")
        if not self.known(raw.msgtype):
            raise DecodeError(f"topic {raw.topic}: no definition for message type {raw.msgtype} "
                              f"(pass --msg-dir with its .msg files)")
        try:
            if raw.encoding == "ros1":
                return self.store.deserialize_ros1(raw.data, raw.msgtype)
            if raw.encoding == "cdr":   # a view: rosbags slices off the 4-byte encapsulation, a copy of bytes
                return self.store.deserialize_cdr(memoryview(raw.data), raw.msgtype)
        except Exception as err:  # noqa: BLE001 - rosbags raises SerdeError, struct/index/value errors
            why = " ".join(str(err).split())[:100]     # the exception class stays in the cause (--debug)
            raise DecodeError(f"topic {raw.topic}: {raw.msgtype} message at {raw.log_ns} ns ({len(raw.data)} bytes) "
                              f"does not decode (damaged bytes?{': ' + why if why else ''})") from err

    # header fields straight from the bytes (no full decode): ROS 1 = seq u32, sec u32, nsec u32,
    # frame_id (u32 length + chars); CDR = 4-byte encapsulation, sec i32, nanosec u32, frame_id
    def _header_at(self, raw: RawMessage):
        if raw.encoding not in ("cdr", "ros1") or raw.data is None or not self.has_header(raw.msgtype):
            return None
        b = raw.data
        if len(b) < 16:
            return None
        if raw.encoding == "ros1":
            return "<", 4, 12
        endian = "<" if b[1] == 1 else ">"
        return endian, 4, 12

    def header_stamp(self, raw: RawMessage) -> int | None:
        at = self._header_at(raw)
        if at is None:
            return None
        endian, o, _ = at
        sec, nsec = struct.unpack_from(endian + ("iI" if raw.encoding == "cdr" else "II"), raw.data, o)
        return sec * 1_000_000_000 + nsec

    def frame_id(self, raw: RawMessage) -> str | None:
        at = self._header_at(raw)
        if at is None:
            return None
        endian, _, o = at
        (n,) = struct.unpack_from(endian + "I", raw.data, o)
        if n > 4096 or o + 4 + n > len(raw.data):
            return None
        s = bytes(raw.data[o + 4:o + 4 + n])
        return s.rstrip(b"\0").decode("utf-8", "replace")


@dataclass
class ReaderSpec:
    """A registered reader: ``name``, ``detect(path) -> bool`` and ``open(path, msg_dir)``."""

    name: str
    detect: object
    open: object
    description: str = ""
    extensions: tuple = field(default_factory=tuple)


# --------------------------------------------------------------------------------------------------
# message-like objects for containers that are not ROS (HDF5, PanoRadar folders): they carry the
# fields ingest reads from the ROS messages they stand in for

RADAR_MSG = "holodata_msgs/msg/RadarHeatmap"
MCAP_MAGIC = b"\x89MCAP0\r\n"   # the first 8 bytes of every MCAP file
RANGE_IMAGE_TYPE = "holodata/msg/RangeImage"
POINTS_TYPE = "holodata/msg/PointCloud"


class _Stamp:
    __slots__ = ("sec", "nanosec")

    def __init__(self, t_ns: int):
        self.sec, self.nanosec = int(t_ns) // 1_000_000_000, int(t_ns) % 1_000_000_000


class Header:
    __slots__ = ("stamp", "frame_id")

    def __init__(self, t_ns: int, frame_id: str):
        self.stamp, self.frame_id = _Stamp(t_ns), frame_id


@dataclass
class RadarHeatmapMsg:
    """Stands in for holodata_msgs/msg/RadarHeatmap (same field names and units)."""

    __msgtype__ = RADAR_MSG
    header: Header
    cycle_start_ns: int
    cycle_end_ns: int
    n_range: int
    n_elevation: int
    n_azimuth: int
    range_resolution: float
    elevation_max: float      # radians
    elevation_min: float
    rotation_radius: float
    encoding: str             # float16 | float32
    data: object              # (n_range*n_elevation*n_azimuth*itemsize,) uint8
    range_origin: str = "rotation_centre"  # or "antenna" (holodata.messages.RANGE_ORIGINS)
    iq: object = None         # readers of raw samples: the RawRotation the heatmap was formed from


@dataclass
class RawRotation:
    """The raw samples of one radar rotation (readers of raw radar; ``ingest --keep-iq`` stores them):
    ``before``/``rotation``/``after`` (n, V, S) complex64 unit-scale chirp frames (the rotation's own
    and the neighbouring ones its beams use; ``before``/``after`` empty when the rotation is padded
    circularly) and ``motion`` = (travel per chirp m, heading rad) the heatmap was formed with."""

    before: object
    rotation: object
    after: object
    motion: tuple = (0.0, 0.0)


@dataclass
class RangeImageMsg:
    """An organised range image: ``range_m`` (H, W) float32 metres (NaN none), ``xyz`` (H, W, 3)
    float32 in the sensor frame (0 where none)."""

    __msgtype__ = RANGE_IMAGE_TYPE
    range_m: object
    xyz: object
    frame_id: str = ""


@dataclass
class PointsMsg:
    """A plain point cloud: ``xyz`` (N, 3) float32 sensor frame; ``time_ns`` (N,) int64 or None."""

    __msgtype__ = POINTS_TYPE
    xyz: object
    time_ns: object = None
    frame_id: str = ""
