"""One synthetic recording end to end: world, robot, human, sensor rig, clocks, message schedule.

Time: ``t0`` = EPOCH + seed hours. Radar cycle k covers [t0 + 0.3 s + k/2 s, + 0.5 s) (true time);
LiDAR scans every 0.1 s from t0 + 0.05 s; camera frames every 1/rate from t0 + 0.1 s; odometry
(/tf, /odom) at 30 Hz. Each sensor's header stamps carry its own clock offset; the bag's log time
adds a per-sensor latency. Random streams are seeded per (seed, stream, index), so any message can
be generated independently and the output does not depend on generation order.

The module is split by job; it re-exports their public names:

- :mod:`holodata.synth.scene`: clocks, frames and streams, :class:`Scenario`, :func:`build_scenario`
  (of a :class:`~holodata.synth.spec.SceneSpec`), :class:`Sensors`, :func:`path_stats`;
- :mod:`holodata.synth.data_pass`: :func:`write_recording` (the data pass's bag and ``truth/``);
- :mod:`holodata.synth.mapping_pass`: :class:`MappingPass`, :func:`mapping_legs`,
  :func:`build_mapping_pass`, :func:`write_mapping_recording`.
"""
from __future__ import annotations

from .data_pass import write_recording
from .mapping_pass import (
    MAPPING_GAP_S,
    MAPPING_SCAN_HZ,
    MAPPING_SPEED_MPS,
    MAPPING_YAW_RATE_RPS,
    MappingPass,
    build_mapping_pass,
    mapping_legs,
    write_mapping_recording,
)
from .scene import (
    CAMERA_START_S,
    EPOCH_S,
    FRAME_BASE,
    FRAME_CAM_LINK,
    FRAME_MAP,
    FRAME_ODOM,
    FRAME_RADAR,
    FRAME_RIGHT_OPT,
    LIDAR_START_S,
    ODOM_HZ,
    RADAR_START_S,
    STREAMS,
    Scenario,
    Sensors,
    build_scenario,
    path_stats,
)
from .spec import SceneSpec

__all__ = [
    "CAMERA_START_S", "EPOCH_S", "FRAME_BASE", "FRAME_CAM_LINK", "FRAME_MAP", "FRAME_ODOM", "FRAME_RADAR", "FRAME_RIGHT_OPT",
    "LIDAR_START_S", "MAPPING_GAP_S", "MAPPING_SCAN_HZ", "MAPPING_SPEED_MPS", "MAPPING_YAW_RATE_RPS", "ODOM_HZ",
    "RADAR_START_S", "STREAMS", "MappingPass", "Scenario", "SceneSpec", "Sensors", "build_mapping_pass", "build_scenario",
    "mapping_legs", "path_stats", "write_mapping_recording", "write_recording",
]
