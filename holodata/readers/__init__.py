"""Recording readers: a registry that picks a reader from the path, à la kiss-icp's ``datasets/``
and rosbags' ``AnyReader``.

    rec = open_recording("drive.bag")                 # or a rosbag2 folder, .mcap, .db3, .pcap, ...
    for t in rec.topics(): print(t.name, t.msgtype, t.count, t.rate_hz, t.frame_id)
    for topic, t_ns, msg in rec.messages(["/ouster/points"]): ...
    for raw in rec.raw_messages(["/radar/heatmap"]):  # filter first, decode later
        msg = rec.decode(raw)

Registered readers (first whose ``detect`` accepts the path wins; see :data:`READERS`):

=================  =====================================================================
``rosbag2``        folder with ``metadata.yaml`` (sqlite3 / mcap storage), a ``.db3``, or a
                   folder of ``.db3``/``.mcap`` files without metadata (rosbags)
``rosbag1``        ``.bag`` (rosbags; linear-scan fallback for unindexed/cut-short bags)
``mcap``           ``.mcap`` (rosbags for ROS 2 files, the ``mcap`` library otherwise)
``ouster-pcap``    ``.pcap`` + sensor metadata ``.json`` (ouster-sdk)
``hdf5``           ``.h5``/``.hdf5`` in holodata's documented layout (:mod:`.hdf5`)
``panoradar-raw``  PanoRadar raw trajectory folder (``radar_data.npy`` + ``data_params.npz`` ...): raw
                   FMCW samples, beamformed into heatmaps on decode (:mod:`.panoradar_raw`)
``npy-folder``     PanoRadar-style folder of per-frame ``.npy`` files (:mod:`.npy_folder`)
=================  =====================================================================

Every failure to open becomes a one-line :class:`~holodata.errors.RecordingError` naming the path.
A recording that could only be read in part has ``truncated = True`` and says why in ``problems``.

Modules: :mod:`.registry` (the readers' detectors and openers, :func:`guess_reader`,
:func:`open_recording`), :mod:`.synth_output` (``holodata synth`` output folders as recordings),
:mod:`.base` (the :class:`Recording` interface), one module per reader; this module only re-exports.
"""
from __future__ import annotations

# ``name as name``: importable from the package since its code lived here, kept so; not in __all__
from .base import MCAP_MAGIC as MCAP_MAGIC
from .base import DecodeError, MessageDecoder, RawMessage, ReaderSpec, Recording, TopicInfo
from .registry import PCAP_MAGICS as PCAP_MAGICS
from .registry import READERS, guess_reader, open_recording, register_reader
from .registry import _bag_dir as _bag_dir
from .registry import _head as _head
from .registry import _is_hdf5 as _is_hdf5
from .registry import _is_mcap as _is_mcap
from .registry import _is_npy_folder as _is_npy_folder
from .registry import _is_panoradar_raw as _is_panoradar_raw
from .registry import _is_pcap as _is_pcap
from .registry import _is_rosbag1 as _is_rosbag1
from .registry import _is_rosbag2 as _is_rosbag2
from .registry import _open_hdf5 as _open_hdf5
from .registry import _open_mcap as _open_mcap
from .registry import _open_npy as _open_npy
from .registry import _open_panoradar_raw as _open_panoradar_raw
from .registry import _open_pcap as _open_pcap
from .registry import _open_rosbag1 as _open_rosbag1
from .registry import _open_rosbag2 as _open_rosbag2
from .synth_output import SYNTH_MAPPING as SYNTH_MAPPING
from .synth_output import SYNTH_RECORDINGS, synth_output_folder, synth_output_recording
from .synth_output import synth_passes as synth_passes

__all__ = ["open_recording", "guess_reader", "synth_output_folder", "synth_output_recording", "SYNTH_RECORDINGS",
           "register_reader", "READERS", "Recording", "TopicInfo", "RawMessage",
           "ReaderSpec", "DecodeError", "MessageDecoder"]
