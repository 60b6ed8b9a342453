"""Synthetic corner recordings: procedural world + walking human + robot + sensor models, written as
a real ROS recording (rosbag2/MCAP by default) with a hidden ``truth/`` folder.

Recording layout under ``out_dir``::

    recording/recording.mcap + recording/metadata.yaml   (format "mcap", rosbag2 with MCAP storage)
    recording/recording.db3  + recording/metadata.yaml   (format "rosbag2", sqlite3 storage)
    recording.bag                                         (format "rosbag1")
    mapping/mapping.mcap + mapping/metadata.yaml          (``mapping_pass=True``; mapping.db3 / mapping.bag)
    truth/...                                             (see holodata.synth.truth)

**Map first, then record** (``SynthSpec(mapping_pass=True)``, the CLI's default; HoloRadar maps each corner
without a person before recording): the *mapping pass* is its own recording of the same corner,
``mapping/``, ending :data:`scenario.MAPPING_GAP_S` before the data pass starts. The robot drives the
empty corner from 1 m short of the approach corridor's end wall to the junction and up the hidden
branch to 1.5 m short of its end; in a T or cross it first turns into the opposite branch and backs
out of it straight through the junction into the hidden one (``scenario.mapping_legs``), 0.8 m/s,
turns rounded to arcs with at most 0.4 rad/s.
Topics ``MAPPING_TOPICS``: the LiDAR, throttled to ``mapping_scan_hz`` (2) scans per second, and
its own drifting odometry (``/tf``, ``/odom``, ``/tf_static`` map→odom and base_link→os_sensor).
Its truth (``truth/mapping_*.tum``, ``scene.json`` ``mapping_pass``) is in the data pass's world
frame. The data pass (radar, LiDAR, camera, hidden person) is byte-identical with or without it.
Ingest it as its own LiDAR-only scene and localise the data scene in its map with ``holodata slam
DATASET --scene ID --map-scene MAPID``.

Topics (``TOPICS``): radar heatmaps ``/radar/heatmap`` (holodata_msgs/msg/RadarHeatmap, frame
``radar``, header stamp = mid-cycle in the radar's clock), Ouster-like scans ``/ouster/points``
(frame ``os_sensor``, stamp = scan start) + ``/ouster/metadata`` (JSON), ZED-like depth
``/zed2i/zed_node/depth/depth_registered`` (32FC1) + ``.../camera_info`` + cloud
``/zed2i/zed_node/point_cloud/cloud_registered``, odometry ``/tf`` (odom→base_link, drifting) and
``/odom``, extrinsics ``/tf_static`` (map→odom, base_link→radar, base_link→os_sensor,
map→zed2i_camera_link→optical frames). Bag (log) time = header stamp + a per-sensor latency;
messages are written in log-time order.

Modules (besides the world, motion and sensor models and the writers): :mod:`.topics` (the
recordings' topics), :mod:`.result` (:class:`SynthResult`), :mod:`.spec` (:class:`SynthSpec`,
:class:`SceneSpec`: what to synthesise), :mod:`.synthesis` (:func:`synthesize`, :func:`estimate_bytes`),
:mod:`.batch` (:func:`~.batch.synth_scenes`: ``--count`` recordings, in this process or one Dask task
each); this module only re-exports.
"""
from __future__ import annotations

from .result import SynthResult
from .spec import SceneSpec, SynthSpec
from .synthesis import PARTIAL_NAME as PARTIAL_NAME
from .synthesis import estimate_bytes, synthesize

# ``name as name``: importable from the package since its code lived here, kept so; not in __all__
from .topics import MAPPING_TOPICS, RADAR_OUTPUTS, RAW_TOPIC, STEREO_TOPICS, TOPICS

__all__ = ["synthesize", "SynthSpec", "SceneSpec", "estimate_bytes", "SynthResult", "TOPICS", "STEREO_TOPICS",
           "MAPPING_TOPICS", "RAW_TOPIC", "RADAR_OUTPUTS"]
