"""What a synthetic corner recording shows and how it is recorded: :class:`SceneSpec` (the arguments
of :func:`holodata.synth.scene.build_scenario`) and :class:`SynthSpec` (those of
:func:`holodata.synth.synthesis.synthesize`). Plain settings, light to import (no sensor models)."""
from __future__ import annotations

from dataclasses import dataclass

from ..conventions import Grid, RangeBins
from ..errors import InputError
from .lidar import LidarConfig
from .topics import RADAR_OUTPUTS


@dataclass(frozen=True)
class SceneSpec:
    """What one synthetic corner recording shows: what :func:`~holodata.synth.scene.build_scenario`
    draws a :class:`~holodata.synth.scene.Scenario` from. Same spec, same scenario (and, written,
    byte-identical files).

    ``visible_walkers`` N > 0 adds N people walking back and forth along the approach corridor (the
    robot's), visible to every sensor, for scoring LiDAR human segmentation against per-scan truth
    masks (``truth/lidar_instances.npz``). They draw from their own random stream, so N = 0 leaves
    every output byte-identical to a recording made without the option. ``robot_stop_x``: where the
    robot stops instead of the world's drawn stop (0.6-1.2 m short of the junction); closer to the
    junction the radar reaches more of the hidden branch (more NLOS ground truth). Either way the stop
    moves back in 0.5 m steps until some stretch of the hidden branch is out of the robot's sight for
    the person.
    """

    corner: str = "L"                   # corner kind: "T" | "L" | "cross" | "oblique"
    width: float | None = None          # approach-corridor width, m (None: drawn from ``seed``, 1.3-4.7)
    frames: int = 20                    # radar rotations (2 Hz)
    seed: int = 0                       # every random draw of the recording
    human: bool = True                  # a person walking on the hidden side
    grid: Grid | None = None            # radar heatmap beam grid (None: ``Grid()``; docs/format.md §2)
    range_bins: RangeBins | None = None  # radar range axis (None: ``RangeBins()``)
    lidar_shape: tuple[int, int] = (64, 1024)   # LiDAR (beams, columns)
    camera_shape: tuple[int, int] = (376, 672)  # depth camera (rows, columns)
    radar_encoding: str = "float16"     # heatmap samples: "float16" | "float32"
    stereo_images: bool = False         # also the rectified left/right mono8 pair (``STEREO_TOPICS``)
    visible_walkers: int = 0            # people walking in the approach corridor, seen by every sensor
    lidar_vertical_fov_deg: float = LidarConfig.vertical_fov_deg  # deg; 33.2 OS1-like, 90 OS0-like
    robot_stop_x: float | None = None   # m along the approach corridor, junction at 0 (None: drawn)
    radar_chirps: int | None = None     # chirp positions per rotation (None: ``RadarConfig``'s 1024)
    radar_output: str = "heatmap"       # "heatmap" (``/radar/heatmap``) | "iq" (``/radar/raw``, raw samples)

    def check(self) -> None:
        """Refuse what the recording cannot be made of (:class:`InputError`); the corner kind and width
        are refused by :func:`holodata.synth.worlds.make_world`."""
        if self.frames < 1:
            raise InputError(f"frames must be >= 1, got {self.frames}")
        if self.visible_walkers < 0:
            raise InputError(f"visible_walkers must be >= 0, got {self.visible_walkers}")
        if self.radar_output not in RADAR_OUTPUTS:
            raise InputError(f"unknown radar output {self.radar_output!r} (choose from {', '.join(RADAR_OUTPUTS)})")
        if self.radar_chirps is not None and self.radar_chirps < 16:
            raise InputError(f"radar_chirps must be >= 16, got {self.radar_chirps}")
        if self.robot_stop_x is not None and not -3.0 <= self.robot_stop_x <= 0.0:
            raise InputError(f"robot_stop_x must be within -3..0 m (the junction starts at 0), got {self.robot_stop_x}")


@dataclass(frozen=True)
class SynthSpec(SceneSpec):
    """One corner recording to synthesise: the scene (every :class:`SceneSpec` field: corner,
    width m, frames, seed, sensors' shapes, ...) and how it is recorded.

    ``mapping_pass``: also record the mapping pass (:mod:`holodata.synth` docstring): the robot drives
    the empty corner through every leg before the data pass, LiDAR + odometry only, LiDAR throttled to
    ``mapping_scan_hz``; the data pass is unchanged. ``radar_output`` "iq" (a scene field) writes
    ``/radar/raw``, every rotation's raw FMCW samples from the same paths, which ingest beamforms like a
    real rig's (:meth:`holodata.synth.radar.RadarModel.iq`), instead of the heatmaps (the radar model
    with the beamformer's point-spread function); ``radar_chirps`` of at least ~500 keep a 90°
    synthetic aperture free of grating lobes at 77 GHz.
    """

    format: str = "mcap"                    # "mcap" | "rosbag2" (sqlite3) | "rosbag1"
    mapping_pass: bool = False              # also write OUT/mapping, the empty corner mapped first
    mapping_scan_hz: float | None = None    # mapping-pass LiDAR scans/s, 0.1-10 (None: ``scenario.MAPPING_SCAN_HZ``)

    def check(self) -> None:
        """Refuse what :func:`~holodata.synth.synthesis.synthesize` cannot write (:class:`InputError`,
        before anything is written)."""
        from .recording import FORMATS

        if self.format not in FORMATS:
            raise InputError(f"unknown recording format {self.format!r} (choose from {', '.join(FORMATS)})")
        super().check()
        if self.mapping_scan_hz is not None and not 0.1 <= self.mapping_scan_hz <= 10.0:
            raise InputError(f"mapping_scan_hz must be within 0.1-10 Hz, got {self.mapping_scan_hz}")
