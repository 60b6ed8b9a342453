"""The one adapter around Ouster's ``ouster-sdk`` (written against 1.0.x; 0.1x names are tried
as fallbacks). Nothing else in holodata imports ``ouster``.

- :class:`OusterPcapRecording`: a ``.pcap`` with its sensor metadata ``.json`` (same stem next to it,
  or given); one virtual topic ``/ouster/lidar_scans`` of type ``ouster/LidarScan`` whose messages
  are :class:`OusterScan` objects. A pcap that decodes to zero scans raises a :class:`RecordingError`
  saying what the pcap holds (UDP ports, payload sizes) against what the metadata expects.
- :class:`PacketAssembler`: raw lidar packets (``ouster_ros/PacketMsg`` ``buf``) + the metadata
  JSON string from the bag -> :class:`OusterScan` per complete frame.

Scans are destaggered onto the native grid with the SDK (``pixel_shift_by_row`` of the metadata):
row ``i`` = beam ``i`` (``beam_altitude_angles[i]``), column ``j`` = azimuth bin ``j``.

Install: :data:`INSTALL_COMMAND` (``scripts/setup.sh`` runs it; ``python -m holodata.readers.ouster``
prints the requirements it installs). It goes in with ``--no-deps``: a plain ``pip install
ouster-sdk`` pins ``rosbags==0.9.23`` and downgrades the rosbags >= 0.11 holodata needs (bare MCAP
files); pcap and packet decoding use none of it, and the two helpers listed are all its readers import.
"""
from __future__ import annotations

import contextlib
import json
import struct
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from .base import RawMessage, Recording, TopicInfo, rate_of
from .sizes import open_bounded

SCAN_TOPIC = "/ouster/lidar_scans"
SCAN_TYPE = "ouster/LidarScan"
PACKET_TYPE = "ouster_ros/msg/PacketMsg"
TESTED_SDK = "1.0"


# the one list of what Ouster support installs (scripts/setup.sh reads it through ``python -m``)
SDK_REQUIREMENTS = ("ouster-sdk==1.0.1", "more-itertools>=8.6", "threadpoolctl>=3.5")
INSTALL_COMMAND = "pip install --no-deps " + " ".join(f'"{r}"' for r in SDK_REQUIREMENTS)
SDK_TYPES = (SCAN_TYPE, PACKET_TYPE)  # message types only the SDK decodes


def sdk_missing() -> str | None:
    """None when ouster-sdk imports, else the one-line reason with the command that fixes it."""
    try:
        from ouster.sdk import core  # noqa: F401
    except ImportError as err:
        return f"reading Ouster data needs ouster-sdk ({err}): run `{INSTALL_COMMAND}` (scripts/setup.sh does)"
    return None


def _sdk():
    missing = sdk_missing()
    if missing:
        raise RecordingError(missing)
    from ouster.sdk import core

    return core


def sdk_version() -> str | None:
    try:
        from importlib.metadata import version

        return version("ouster-sdk")
    except Exception:  # noqa: BLE001
        return None


def _frame_cls(core):
    return getattr(core, "LidarFrame", None) or core.LidarScan


def _batcher_cls(core):
    return getattr(core, "FrameBatcher", None) or core.ScanBatcher


@dataclass
class SensorMeta:
    """What holodata keeps of an Ouster sensor's metadata (and the JSON itself)."""

    H: int
    W: int
    prod_line: str
    serial: str
    firmware: str
    lidar_mode: str
    udp_profile_lidar: str
    beam_altitude_deg: list
    beam_azimuth_deg: list
    pixel_shift_by_row: list
    udp_port_lidar: int | None
    lidar_packet_size: int
    json_text: str = field(repr=False, default="")

    def to_attrs(self) -> dict:
        d = {k: v for k, v in vars(self).items() if k != "json_text"}
        d["sdk_version"] = sdk_version()
        return d


def load_info(text_or_path):
    """SensorInfo from a metadata JSON string or file; RecordingError naming the source if unusable."""
    core = _sdk()
    src = "metadata"
    text = text_or_path
    if isinstance(text_or_path, Path) or (isinstance(text_or_path, str) and not text_or_path.lstrip().startswith("{")):
        src = str(text_or_path)
        try:
            text = Path(text_or_path).read_text()
        except OSError as err:
            raise RecordingError(f"{src}: cannot read Ouster metadata ({err.strerror})") from err
    try:
        json.loads(text)
        info = core.SensorInfo(text)
    except Exception as err:  # noqa: BLE001
        raise RecordingError(f"{src}: not valid Ouster sensor metadata ({' '.join(str(err).split())[:120]})") from err
    return info, text


def sensor_meta(info, text: str = "") -> SensorMeta:
    core = _sdk()
    pf = core.PacketFormat(info)
    fmt = info.format
    return SensorMeta(
        H=int(fmt.pixels_per_column), W=int(fmt.columns_per_frame), prod_line=str(info.prod_line),
        serial=str(info.sn), firmware=str(info.fw_rev), lidar_mode=str(info.config.lidar_mode),
        udp_profile_lidar=str(fmt.udp_profile_lidar), beam_altitude_deg=[float(a) for a in info.beam_altitude_angles],
        beam_azimuth_deg=[float(a) for a in info.beam_azimuth_angles],
        pixel_shift_by_row=[int(s) for s in fmt.pixel_shift_by_row],
        udp_port_lidar=int(info.config.udp_port_lidar) if info.config.udp_port_lidar else None,
        lidar_packet_size=int(pf.lidar_packet_size), json_text=text)


@dataclass
class OusterScan:
    """One destaggered scan. ``range_m`` (H, W) float32 metres from the beam origin, NaN = no return;
    ``xyz`` (H, W, 3) float32 sensor frame (0 where no return; None when not asked for);
    ``t_offset_ns`` (W,) int64 column time relative to ``sensor_ts_ns`` (destaggered columns: per
    pixel use :meth:`pixel_times`); ``timestamp_ns`` host/packet time of the first valid packet."""

    timestamp_ns: int
    sensor_ts_ns: int
    frame_id: int
    range_m: np.ndarray
    xyz: np.ndarray | None
    column_ts_ns: np.ndarray      # (W,) sensor clock, staggered (measurement order)
    complete: bool
    meta: SensorMeta

    def points(self) -> np.ndarray:
        """(N, 3) float32 valid points in row-major order of the destaggered grid."""
        if self.xyz is None:
            raise ValueError("scan decoded without xyz")
        return self.xyz[np.isfinite(self.range_m)]

    def pixel_times_ns(self) -> np.ndarray:
        """(H, W) int64 time of each destaggered pixel relative to ``sensor_ts_ns``."""
        H, W = self.range_m.shape
        t = np.broadcast_to(self.column_ts_ns - self.sensor_ts_ns, (H, W))
        return _destagger_np(t, self.meta.pixel_shift_by_row)


def _destagger_np(a: np.ndarray, shifts) -> np.ndarray:
    out = np.empty_like(a)
    for i, s in enumerate(shifts):
        out[i] = np.roll(a[i], int(s), axis=0)
    return out


class _Converter:
    def __init__(self, info, text: str):
        self.core = _sdk()
        self.info = info
        self.meta = sensor_meta(info, text)
        self._lut = None

    def scan(self, frame, with_xyz: bool, host_ns: int | None = None) -> OusterScan:
        core = self.core
        rng = np.asarray(frame.field(core.ChanField.RANGE))
        valid = rng > 0
        r = np.where(valid, rng.astype(np.float32) * np.float32(1e-3), np.float32(np.nan))
        xyz = None
        if with_xyz:
            if self._lut is None:
                self._lut = core.XYZLut(self.info)
            xyz = np.asarray(self._lut(rng), dtype=np.float32)
            xyz[~valid] = 0.0
            xyz = np.asarray(core.destagger(self.info, xyz))
        r = np.asarray(core.destagger(self.info, r))
        ts = np.asarray(frame.timestamp, dtype=np.int64)
        status = np.asarray(frame.status)
        ok = (status & 1) != 0 if status.size else np.ones(ts.shape, bool)
        ts0 = int(ts[ok][0]) if ok.any() else int(ts[0])
        try:
            host = int(frame.get_first_valid_packet_timestamp())
        except Exception:  # noqa: BLE001 - no packet timestamps (older SDKs): sensor clock
            host = 0
        if not host:
            host = int(host_ns) if host_ns else ts0
        return OusterScan(timestamp_ns=host, sensor_ts_ns=ts0, frame_id=int(frame.frame_id), range_m=r, xyz=xyz,
                          column_ts_ns=ts, complete=bool(frame.complete()), meta=self.meta)


class PacketAssembler:
    """Feeds raw lidar packets (bytes) to the SDK's batcher; :meth:`add` returns an
    :class:`OusterScan` whenever a frame completes, :meth:`flush` the last partial one."""

    def __init__(self, metadata, with_xyz: bool = True):
        core = _sdk()
        self.info, text = load_info(metadata)
        self.conv = _Converter(self.info, text)
        self.pf = core.PacketFormat(self.info)
        self.batcher = _batcher_cls(core)(self.info)
        self.with_xyz = with_xyz
        self._frame = None
        self._first_ns = None
        self.size_errors = 0
        self.packets = 0

    @property
    def meta(self) -> SensorMeta:
        return self.conv.meta

    def add(self, buf, log_ns: int) -> OusterScan | None:
        core = self.conv.core
        n = self.pf.lidar_packet_size
        b = np.frombuffer(bytes(buf), np.uint8) if not isinstance(buf, np.ndarray) else buf
        if len(b) not in (n, n + 1):  # ouster-ros < 0.10 appends one byte
            self.size_errors += 1
            return None
        p = core.LidarPacket(self.pf) if _takes_format(core) else core.LidarPacket(n)
        p.buf[:] = b[:n]
        with contextlib.suppress(Exception):   # SDK versions without a settable host timestamp: left unset
            p.host_timestamp = int(log_ns)
        if self._frame is None:
            self._frame = _frame_cls(core)(self.info)
            self._first_ns = log_ns
        self.packets += 1
        if self.batcher.batch(p, self._frame):
            frame, self._frame = self._frame, None
            return self.conv.scan(frame, self.with_xyz, self._first_ns)
        return None

    def flush(self) -> OusterScan | None:
        frame, self._frame = self._frame, None
        if frame is None:
            return None
        try:
            if self.batcher.batched_packets() == 0:
                return None
        except Exception:  # noqa: BLE001
            pass
        return self.conv.scan(frame, self.with_xyz, self._first_ns)


def _takes_format(core) -> bool:
    doc = core.LidarPacket.__init__.__doc__ or ""
    return "PacketFormat" in doc or "size" not in doc


# --------------------------------------------------------------------------------------------------
# pcap

def find_metadata(pcap: Path, meta: Path | None = None) -> Path:
    pcap = Path(pcap)
    if meta is not None:
        if not Path(meta).exists():
            raise RecordingError(f"{meta}: Ouster metadata file not found")
        return Path(meta)
    cands = [pcap.with_suffix(".json")] + sorted(p for p in pcap.parent.glob(f"{pcap.stem}*.json"))
    for c in cands:
        if c.exists():
            return c
    raise RecordingError(f"{pcap}: no Ouster metadata next to it (expected {pcap.with_suffix('.json').name}); "
                         f"give the sensor's .json with the pcap (holodata ingest PCAP JSON)")


def pcap_udp_summary(path: Path, limit: int = 20000) -> tuple[Counter, int]:
    """(Counter of (dst port, payload bytes), records) of the first ``limit`` records — for error
    messages only (Ethernet / IPv4 / UDP, classic pcap)."""
    out: Counter = Counter()
    n = 0
    with open_bounded(path) as f:      # a record's declared length is read only as far as the file goes
        gh = f.read(24)
        if len(gh) < 24:
            return out, 0
        magic = gh[:4]
        e = "<" if magic in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1") else ">"
        while n < limit:
            rh = f.read(16)
            if len(rh) < 16:
                break
            _, _, incl, _ = struct.unpack(e + "IIII", rh)
            pkt = f.read(incl)
            if len(pkt) < incl:
                break
            n += 1
            if len(pkt) < 42 or pkt[12:14] != b"\x08\x00":
                continue
            ihl = (pkt[14] & 0x0F) * 4
            if pkt[23] != 17:
                continue
            u = 14 + ihl
            dport, ulen = struct.unpack(">HH", pkt[u + 2:u + 6])
            out[(dport, ulen - 8)] += 1
    return out, n


class OusterPcapRecording(Recording):
    kind = "ouster-pcap"

    def __init__(self, path: Path, meta: Path | None = None):
        super().__init__(path)
        self.meta_path = find_metadata(self.path, meta)
        self.files = [self.path, self.meta_path]
        with open(self.path, "rb") as f:
            head = f.read(4)
        if not head:
            raise RecordingError(f"{self.path}: file is empty")
        if head not in (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d"):
            raise RecordingError(f"{self.path}: not a classic pcap file (pcapng is not supported; convert with "
                                 f"`editcap -F pcap`)")
        missing = sdk_missing()
        if missing:
            raise RecordingError(f"{self.path}: {missing}")
        self.info, self.text = load_info(self.meta_path)
        self.meta = sensor_meta(self.info, self.text)
        self._infos: list[TopicInfo] | None = None

    def _source(self):
        from ouster.sdk import open_source

        try:
            return open_source(str(self.path), meta=[str(self.meta_path)], collate=False)
        except TypeError:
            return open_source(str(self.path), meta=[str(self.meta_path)])
        except Exception as err:  # noqa: BLE001
            raise RecordingError(f"{self.path}: ouster-sdk cannot open it with {self.meta_path.name} "
                                 f"({' '.join(str(err).split())[:160]})") from err

    def scans(self, with_xyz: bool = True) -> Iterator[OusterScan]:
        conv = _Converter(self.info, self.text)
        n = 0
        try:
            for item in self._source():
                frames = list(item) if isinstance(item, (list, tuple)) or hasattr(item, "__len__") else [item]
                for fr in frames:
                    if fr is None:
                        continue
                    n += 1
                    yield conv.scan(fr, with_xyz)
        except RecordingError:
            raise
        except Exception as err:  # noqa: BLE001 - a damaged pcap: keep the scans read so far
            self.mark_truncated(f"{self.path}: ouster-sdk stopped after {n} scans "
                                f"({' '.join(str(err).split())[:120]}); the readable part is used")
        if n == 0:
            raise RecordingError(self._zero_scans_reason())

    def _zero_scans_reason(self) -> str:
        udp, nrec = pcap_udp_summary(self.path)
        m = self.meta
        want = f"lidar packets of {m.lidar_packet_size} bytes ({m.udp_profile_lidar}, {m.W}x{m.H})" + (
            f" on port {m.udp_port_lidar}" if m.udp_port_lidar else "")
        have = ", ".join(f"{c}x {s} B to port {p}" for (p, s), c in udp.most_common(4)) or "no UDP packets"
        hint = "the metadata .json does not belong to this pcap" if udp and all(
            s != m.lidar_packet_size for (_, s) in udp) else "packets may be incomplete or from another sensor"
        return (f"{self.path}: decoded 0 scans with {self.meta_path.name}: the pcap holds {nrec} records ({have}); "
                f"the metadata expects {want} — {hint}")

    def _topics(self) -> list[TopicInfo]:
        if self._infos is None:
            ts = [s.timestamp_ns for s in self.scans(with_xyz=False)]
            lo, hi = (min(ts), max(ts)) if ts else (None, None)
            self._infos = [TopicInfo(SCAN_TOPIC, SCAN_TYPE, len(ts), rate_of(len(ts), lo, hi), "os_sensor", "ouster",
                                     True, f"{self.meta.prod_line} {self.meta.lidar_mode} {self.meta.udp_profile_lidar}",
                                     lo, hi)]
        return [TopicInfo(**vars(t)) for t in self._infos]

    def raw_messages(self, topics: Iterable[str] | None = None, with_xyz: bool = True) -> Iterator[RawMessage]:
        if topics is not None and SCAN_TOPIC not in set(topics):
            return
        for s in self.scans(with_xyz=with_xyz):
            yield RawMessage(SCAN_TOPIC, SCAN_TYPE, s.timestamp_ns, None, "ouster", s)

    def stamp_ns(self, raw: RawMessage) -> int:
        return raw.log_ns


if __name__ == "__main__":  # scripts/setup.sh: the requirements of Ouster support, one per line
    print("\n".join(SDK_REQUIREMENTS))
