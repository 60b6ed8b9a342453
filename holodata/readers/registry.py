"""The reader registry (:data:`READERS`, the table in :mod:`holodata.readers`): each reader's
detector and opener, :func:`guess_reader` (an extension names its reader, else the first detector
that accepts the path) and :func:`open_recording`."""
from __future__ import annotations

from pathlib import Path

from ..errors import HolodataError, RecordingError
from .base import MCAP_MAGIC, ReaderSpec, Recording
from .synth_output import synth_output_recording

PCAP_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")


def _head(path: Path, n: int = 16) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError:
        return b""


def _bag_dir(path: Path) -> Path | None:
    """The rosbag2 folder a storage file belongs to (its folder has a metadata.yaml), else None."""
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").exists():
        return path.parent
    if path.is_file() and path.name == "metadata.yaml":
        return path.parent
    return None


# -- detectors ---------------------------------------------------------------------------------------
def _is_rosbag2(p: Path) -> bool:
    if p.is_dir():
        return (p / "metadata.yaml").exists() or any(c.suffix in (".db3", ".mcap") for c in p.iterdir())
    return p.suffix == ".db3" or _bag_dir(p) is not None or _head(p, 15) == b"SQLite format 3"


def _is_rosbag1(p: Path) -> bool:
    return p.is_file() and (p.suffix == ".bag" or _head(p, 9) == b"#ROSBAG V")


def _is_mcap(p: Path) -> bool:
    return p.is_file() and (p.suffix == ".mcap" or _head(p, 8) == MCAP_MAGIC)


def _is_pcap(p: Path) -> bool:
    return p.is_file() and (p.suffix in (".pcap", ".pcapng") or _head(p, 4) in PCAP_MAGICS)


def _is_hdf5(p: Path) -> bool:
    return p.is_file() and (p.suffix in (".h5", ".hdf5") or _head(p, 8) == b"\x89HDF\r\n\x1a\n")


def _is_panoradar_raw(p: Path) -> bool:
    return p.is_dir() and (p / "radar_data.npy").exists()   # the raw layout; its other files are checked on open


def _is_npy_folder(p: Path) -> bool:
    return p.is_dir() and ((p / "rf_npy").is_dir() or (p / "lidar_npy").is_dir())


# -- openers -------------------------------------------------------------------------------------------
def _open_rosbag2(p: Path, msg_dir=None, **_):
    from .rosbag import open_rosbag2

    return open_rosbag2(_bag_dir(p) or p, msg_dir)


def _open_rosbag1(p: Path, msg_dir=None, **_):
    from .rosbag import open_rosbag1

    return open_rosbag1(p, msg_dir)


def _open_mcap(p: Path, msg_dir=None, **_):
    """A single ``.mcap``: rosbags for ROS 2 files with a summary (CDR on every channel), the mcap
    library otherwise (here, not in either reader, so that neither imports the other)."""
    from .mcap_file import McapRecording, ros2_cdr

    path = Path(p)
    if ros2_cdr(path):
        try:
            from rosbags.rosbag2 import Reader

            from .rosbag import RosbagsRecording, bound_rosbags_mcap

            bound_rosbags_mcap()          # its chunks decompressed in bounded steps (ros2_cdr checked their sizes)
            reader = Reader(path)
            reader.open()
            return RosbagsRecording(path, reader, 2, "mcap", msg_dir)
        except Exception:  # noqa: BLE001 - e.g. profile not ros2: the mcap library reads it
            pass
    return McapRecording(path, [path], msg_dir)


def _open_pcap(p: Path, meta=None, **_):
    from .ouster import OusterPcapRecording

    return OusterPcapRecording(p, meta)


def _open_hdf5(p: Path, **_):
    from .hdf5 import Hdf5Recording

    return Hdf5Recording(p)


def _open_panoradar_raw(p: Path, beamform=None, device="cpu", motion=None, **_):
    from .panoradar_raw import PanoRadarRawRecording

    return PanoRadarRawRecording(p, beamform, device, motion)


def _open_npy(p: Path, **_):
    from .npy_folder import NpyFolderRecording

    return NpyFolderRecording(p)


READERS: dict[str, ReaderSpec] = {}


def register_reader(spec: ReaderSpec) -> None:
    """Add (or replace) a reader; readers are tried in registration order."""
    READERS[spec.name] = spec


for _spec in (
    ReaderSpec("rosbag2", _is_rosbag2, _open_rosbag2, "rosbag2 folder / .db3 (rosbags)", (".db3",)),
    ReaderSpec("rosbag1", _is_rosbag1, _open_rosbag1, "ROS 1 bag v2.0 (rosbags)", (".bag",)),
    ReaderSpec("mcap", _is_mcap, _open_mcap, "MCAP (rosbags / mcap)", (".mcap",)),
    ReaderSpec("ouster-pcap", _is_pcap, _open_pcap, "Ouster pcap + metadata json (ouster-sdk)", (".pcap",)),
    ReaderSpec("hdf5", _is_hdf5, _open_hdf5, "HDF5, holodata layout (h5py)", (".h5", ".hdf5")),
    ReaderSpec("panoradar-raw", _is_panoradar_raw, _open_panoradar_raw, "PanoRadar raw trajectory (beamformed)", ()),
    ReaderSpec("npy-folder", _is_npy_folder, _open_npy, "PanoRadar-style .npy folder", ()),
):
    register_reader(_spec)


def guess_reader(path) -> str:
    """Name of the reader for ``path`` (RecordingError if none fits); a synth output folder is read
    as its recording (:func:`synth_output_recording`)."""
    p = synth_output_recording(path)
    if not p.exists():
        raise RecordingError(f"{p}: no such file or folder")
    if p.is_file() and p.stat().st_size == 0:
        raise RecordingError(f"{p}: file is empty")
    # an extension names its reader; content sniffing only for unknown extensions
    by_ext = {ext: name for name, spec in READERS.items() for ext in spec.extensions}
    if p.is_file() and p.suffix in by_ext and p.name != "metadata.yaml":
        name = by_ext[p.suffix]
        if name == "mcap" and _bag_dir(p) is not None:
            return "rosbag2"
        return name
    for name, spec in READERS.items():
        try:
            if spec.detect(p):
                return name
        except OSError:
            continue
    if p.is_dir():
        bags = sorted(c.name for c in p.iterdir() if c.suffix == ".bag")
        if bags:
            raise RecordingError(f"{p}: folder holds ROS 1 bags ({', '.join(bags[:3])}{' ...' if len(bags) > 3 else ''}); "
                                 f"pass the .bag files themselves")
        raise RecordingError(f"{p}: folder is not a recording (no metadata.yaml, .db3 or .mcap files, no rf_npy/ or "
                             f"lidar_npy/ folder, no radar_data.npy)")
    raise RecordingError(f"{p}: unknown recording format (expected .bag, .mcap, .db3, a rosbag2 folder, "
                         f".pcap + .json, .h5 or a folder of .npy files)")


def open_recording(path, msg_dir=None, meta=None, reader: str | None = None, beamform=None,
                   device: str = "cpu", motion: str | None = None) -> Recording:
    """Open ``path`` with the reader :func:`guess_reader` picks (or ``reader``). ``msg_dir``: folder
    of ``.msg`` files for types the file does not define; ``meta``: Ouster metadata ``.json``;
    ``beamform``: :class:`~holodata.radar.beam_geometry.BeamformParams` and ``device`` for readers of raw
    radar samples; ``motion``: "static" | "moving", the robot's motion for readers that otherwise
    read it from folder names (PanoRadar raw trajectories, :func:`.panoradar_raw.motion_rule`)."""
    p = synth_output_recording(path)
    name = reader or guess_reader(p)
    if name not in READERS:
        raise RecordingError(f"unknown reader {name!r} (have {', '.join(READERS)})")
    try:
        return READERS[name].open(p, msg_dir=Path(msg_dir) if msg_dir else None, meta=meta, beamform=beamform,
                                  device=device, motion=motion)
    except HolodataError:
        raise
    except Exception as err:  # noqa: BLE001 - library errors become one line naming the file
        msg = " ".join(str(err).split()) or "unreadable"     # the exception class stays in the cause (--debug)
        raise RecordingError(f"{p}: cannot read as {name} ({msg[:200]})") from err
