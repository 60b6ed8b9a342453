"""holodata's own ROS message types — radar heatmaps and raw radar rotations — and typestores that know them.

``holodata_msgs/msg/RadarHeatmap`` carries one rotation cycle: a linear-amplitude heatmap
``(n_range, n_elevation, n_azimuth)`` in C order, little-endian, ``encoding`` "float16" or
"float32"; ``holodata_msgs/msg/RadarRawRotation`` carries one rotation of raw FMCW samples
(:data:`RADAR_RAW_MSGDEF`), which ingest beamforms. Recordings written by holodata embed these definitions (rosbag2
``message_definitions``,
MCAP schemas, ROS1 connection headers), so rosbags and mcap decode it without extra files.
"""
from __future__ import annotations

import numpy as np

RADAR_HEATMAP_TYPE = "holodata_msgs/msg/RadarHeatmap"
RANGE_ORIGINS = ("rotation_centre", "antenna")  # RadarHeatmap.range_origin; "" (older recordings) = centre

RADAR_HEATMAP_MSGDEF = """\
# One rotation cycle of a rotating mmWave radar, beamformed onto a (range, elevation, azimuth) grid.
# Azimuth column j looks at phi_j = -2*pi*j/n_azimuth in the radar frame (REP-103, column 0 = +x,
# clockwise seen from above); elevation row i at elevation_max - i*(elevation_max-elevation_min)/(n_elevation-1);
# range bin k centre (k+0.5)*range_resolution. Amplitudes are linear (not dB).
# range_origin says where ranges are measured from: "rotation_centre" (rotating-array beamforming aligns
# every chirp to the centre of rotation) or "antenna" (on the rotation circle of rotation_radius metres).
# Column j is formed at cycle_start_ns + (j+0.5)/n_azimuth*(cycle_end_ns-cycle_start_ns).
std_msgs/Header header
uint64 cycle_start_ns
uint64 cycle_end_ns
uint32 n_range
uint32 n_elevation
uint32 n_azimuth
float32 range_resolution
float32 elevation_max
float32 elevation_min
float32 rotation_radius
string range_origin
string encoding
uint8[] data
"""


RADAR_RAW_TYPE = "holodata_msgs/msg/RadarRawRotation"

RADAR_RAW_MSGDEF = """\
# One rotation of a rotating FMCW radar as raw samples, for holodata's beamformer (holodata.radar.beamform;
# PanoRadar's imaging). Chirp frames in time order: n_before of the previous rotation (the outer chirps of
# the first beams of a moving platform), the n_rotation of this one (chirp n faces -2*pi*n/n_rotation in
# the radar frame, chirp 0 along +x), n_after of the next. Each chirp frame holds n_tx*n_rx virtual
# antennas (a vertical column: antenna v sits antenna_spacing*(n_tx*n_rx-1-v) below the phase reference
# in two-way path per sin(elevation)) x n_samples ADC samples, sample i at
# start_frequency + slope*i/sample_rate. encoding "complex64": little-endian float32 I/Q pairs, C order
# (chirp, antenna, sample). travel_per_chirp (m) and heading (rad, counter-clockwise from chirp 0's
# facing) describe the platform's motion during the rotation (0: at rest or unknown).
std_msgs/Header header
uint64 cycle_start_ns
uint64 cycle_end_ns
float64 start_frequency
float64 slope
float64 sample_rate
uint32 n_samples
uint32 n_tx
uint32 n_rx
float64 antenna_spacing
float64 rotation_radius
uint32 n_before
uint32 n_rotation
uint32 n_after
float64 travel_per_chirp
float64 heading
string encoding
uint8[] data
"""


def register_holodata_types(typestore) -> None:
    """Add holodata's message types to a rosbags typestore (idempotent)."""
    from rosbags.typesys import get_types_from_msg

    if RADAR_HEATMAP_TYPE not in typestore.fielddefs:
        typestore.register(get_types_from_msg(RADAR_HEATMAP_MSGDEF, RADAR_HEATMAP_TYPE))
    if RADAR_RAW_TYPE not in typestore.fielddefs:
        typestore.register(get_types_from_msg(RADAR_RAW_MSGDEF, RADAR_RAW_TYPE))


def typestore_for(ros_version: int = 2):
    """A rosbags typestore (ROS 2 Humble or ROS 1 Noetic) with holodata's types registered."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros_version == 2 else Stores.ROS1_NOETIC)
    register_holodata_types(store)
    return store


def heatmap_from_msg(msg) -> np.ndarray:
    """Decode a RadarHeatmap message to (n_range, n_elevation, n_azimuth) float32 linear amplitude."""
    dtype = {"float16": "<f2", "float32": "<f4"}.get(msg.encoding)
    if dtype is None:
        raise ValueError(f"unknown RadarHeatmap encoding {msg.encoding!r}")
    shape = (int(msg.n_range), int(msg.n_elevation), int(msg.n_azimuth))
    data = np.frombuffer(bytes(msg.data), dtype=dtype)
    if data.size != np.prod(shape):
        raise ValueError(f"RadarHeatmap payload has {data.size} values, header says {shape}")
    return data.reshape(shape).astype(np.float32)
