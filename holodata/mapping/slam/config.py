"""Settings and results of ``holodata slam``: :class:`SlamConfig`, :class:`SlamOutputs`, :class:`Scans`,
:class:`SlamResult`."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...trajectory import Trajectory

SEED_POSES = ("kiss-icp", "tf")


@dataclass(frozen=True)
class SlamConfig:
    """SLAM settings (metres, seconds).

    ``voxel``: kiss-icp map voxel (indoor: 0.1–0.2); ``max_range``: None = from the data; ``min_range``:
    drop returns closer than this (robot body); ``deskew``: use per-point times; ``refine``: open3d
    scan-to-map refinement after kiss-icp (False = bare kiss-icp poses); ``source_voxel``: scan
    downsampling for refinement ICP; ``map_voxel``: refinement map resolution (a scan adds to it only
    when the sensor moved ``map_keyframe_m`` or turned ``map_keyframe_deg`` since the last scan that
    did); ``icp_distances``: coarse-to-fine max correspondence distances; ``tukey_k``: robust kernel
    width as a multiple of each stage's distance; ``min_fitness``: a refined scan pose whose share of
    source points with a map correspondence (finest stage) is below this keeps kiss-icp's relative
    motion instead (counted in the health figures); ``global_pass``: second refinement pass against the
    whole (background-filtered) map (about the cost of the first pass; off by default;
    ``docs/design/slam.md``); ``background_voxel`` /
    ``background_min_fraction``: the voxel background model (moving points out of the map and mesh);
    ``mesh``: build and store the static mesh from at most ``mesh_max_scans`` scans (every scan that
    moved a keyframe distance plus scans evenly spread in time, so that people walking while the robot
    stands still are still seen moving); ``still_m`` / ``still_deg``: when kiss-icp says the sensor
    moved less than this since the last ICP-refined scan, and one point-to-plane Gauss-Newton step of
    the scan from that scan's pose against the map is below ``still_check_m`` / ``still_check_deg``
    (kiss-icp alone lags when the robot starts from rest), the robot is at rest: the scan holds that
    refined pose without ICP; ``same_beam``: on organised scans (``lidar/range``) that check reuses,
    beam by beam, the map planes found for the last scan that passed it (:class:`_SameBeam`: at most
    ``same_beam_points`` beams, bounds ``same_beam_scale`` × the check's, at least ``same_beam_share``
    of the returns near their plane; else the full check runs); ``icp_converged_m``: ICP stages stop
    when the inlier RMSE changes less than this between iterations; kiss-icp runs on the scan
    downsampled to ``kiss_input_voxel`` (its own first voxelisation is at voxel/2) with ICP convergence
    ``kiss_convergence`` (norm of the pose update) and at most ``kiss_max_iterations`` (the kiss-icp
    defaults 1e-4 / 500 cost several times more on a robot at rest for no better ATE: it only seeds
    the refinement; ``docs/design/slam.md``).
    ``seed_poses``: what seeds the refinement's relative motion: "kiss-icp" (default) or "tf" — the
    recording's odometry/TF poses (:func:`guess_poses`) where the scene has them for every scan
    (kiss-icp otherwise); a mapping pass throttled to a few scans per second (0.3-0.4 m apart) is seeded
    better and cheaper by its wheel odometry than by kiss-icp's constant-velocity model.
    ``scan_normal_radius`` / ``scan_normal_nn``: the normals of a keyframe scan added to the
    refinement map (open3d hybrid search, sensor frame), and ``map_normal_radius`` /
    ``map_normal_nn`` those of a whole static map (the global pass's target, localisation's map):
    neighbourhoods that must span a few of the LiDAR's rings on a wall (a sparser LiDAR needs larger).
    """

    voxel: float = 0.15
    max_range: float | None = None
    min_range: float = 0.3
    deskew: bool = True
    refine: bool = True
    source_voxel: float = 0.12
    map_voxel: float = 0.06
    icp_distances: tuple[float, ...] = (0.3, 0.1)
    icp_iterations: int = 10
    fine_source_voxel: float = 0.1
    fine_map_voxel: float = 0.04
    fine_distances: tuple[float, ...] = (0.1, 0.05)
    tukey_k: float = 1.0
    global_pass: bool = False
    min_fitness: float = 0.3
    map_keyframe_m: float = 0.05
    map_keyframe_deg: float = 2.0
    mesh_max_scans: int = 120
    still_m: float = 0.01
    still_deg: float = 0.2
    still_check_m: float = 0.003
    still_check_deg: float = 0.06
    same_beam: bool = True
    same_beam_points: int = 8192
    same_beam_scale: float = 1.0
    same_beam_share: float = 0.9
    kiss_convergence: float = 1e-3
    kiss_max_iterations: int = 50
    kiss_input_voxel: float = 0.075
    icp_converged_m: float = 1e-5
    background_voxel: float = 0.15
    background_min_fraction: float = 0.6
    mesh: bool = True
    seed_poses: str = "kiss-icp"
    scan_normal_radius: float = 0.3
    scan_normal_nn: int = 20
    map_normal_radius: float = 0.25
    map_normal_nn: int = 30

    def __post_init__(self):
        if self.seed_poses not in SEED_POSES:
            raise InputError(f"unknown slam seed_poses {self.seed_poses!r} (choose from {', '.join(SEED_POSES)})")
        if not 0.02 <= self.voxel <= 2.0:
            raise InputError(f"slam voxel must be in [0.02, 2] m, got {self.voxel}")
        if self.max_range is not None and not self.max_range > self.min_range:
            raise InputError(f"slam max_range ({self.max_range}) must exceed min_range ({self.min_range})")
        if not self.icp_distances or min(self.icp_distances) <= 0:
            raise InputError("slam icp_distances must be positive")

    def to_attrs(self) -> dict:
        d = asdict(self)
        d["icp_distances"] = list(self.icp_distances)
        return d


@dataclass(frozen=True)
class SlamOutputs:
    """What slam does with a scene's result: ``write`` it into the scene (poses, mesh, map and the
    ``slam`` attribute); a scene already done with the same inputs and settings is not recomputed for
    writing unless ``force`` (its stored result comes back); export the LiDAR trajectory as TUM text
    (``tum``, a path or None) and the mesh as PLY (``ply``)."""

    write: bool = True
    force: bool = False
    tum: str | Path | None = None
    ply: str | Path | None = None


@dataclass
class Scans:
    """LiDAR scans of one scene. ``frames`` (S,) frame index of each scan; ``stamp_ns`` (S,) scan
    stamps (int64 ns); ``points`` list of (Ni,3) float32 sensor-frame points; ``times`` list of
    (Ni,) float32 seconds relative to the stamp, or None when the scene has no per-point time."""

    frames: np.ndarray
    stamp_ns: np.ndarray
    points: list
    times: list | None
    # organised scans (``lidar/range`` (T,H,W) whose finite pixels in row-major order are the rows of
    # ``lidar/points``): ``grid`` (H, W) and per scan the flat pixel index (Ni,) int32 of each point
    # (None for a scan whose point count does not match); None without lidar/range
    grid: tuple | None = None
    pixels: list | None = None

    def __len__(self) -> int:
        return len(self.frames)


@dataclass
class SlamResult:
    """``scene``; ``timestamp_ns`` (S,) scan stamps; ``T_world_lidar`` (T,4,4) per frame;
    ``T_world_radar`` (T,4,4) or None; ``scan_poses`` (S,4,4) refined; ``kiss_poses`` (S,4,4) bare
    kiss-icp (its own reference time ``kiss_stamp_ns``); ``mesh`` (vertices, faces) or None;
    ``summary`` dict (counts, timings, health)."""

    scene: str
    timestamp_ns: np.ndarray
    scan_poses: np.ndarray
    kiss_poses: np.ndarray
    kiss_stamp_ns: np.ndarray
    T_world_lidar: np.ndarray
    T_world_radar: np.ndarray | None
    mesh: tuple | None = None
    summary: dict = field(default_factory=dict)
    map_points: np.ndarray | None = None

    def trajectory(self) -> Trajectory:
        """Refined LiDAR trajectory at the scan stamps."""
        return Trajectory(self.timestamp_ns.copy(), self.scan_poses.copy())

    def kiss_trajectory(self) -> Trajectory | None:
        """Bare kiss-icp trajectory (its own reference times), None for a result read back from a dataset."""
        if self.kiss_poses is None:
            return None
        return Trajectory(self.kiss_stamp_ns.copy(), self.kiss_poses.copy())
