"""Settings and results of ``holodata register``: :class:`RegisterConfig` (every field
documented), :class:`Registration`, :class:`RegistrationError`."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ...errors import HolodataError


class RegistrationError(HolodataError, RuntimeError):
    """Camera-to-map registration did not pass its acceptance check. Raised by
    :func:`~holodata.mapping.register.register_scene` after it finished the scene without a person
    (mesh and poses kept; scene attrs ``register_failed`` with the numbers);
    ``report``: that summary (dict), or None."""

    def __init__(self, message: str, report: dict | None = None):
        super().__init__(message)
        self.report = report


@dataclass(frozen=True)
class RegisterConfig:
    """Parameters (metres unless noted); docs/design/register.md says what each does and why it has
    this value."""

    map_voxel: float = 0.04
    map_max_scans: int = 120
    cam_voxel: float = 0.03
    icp_distances: tuple = (0.15, 0.08, 0.04)
    map_sigma_m: float = 0.015
    map_normal_voxel: float = 0.15
    map_normal_m: float = 0.45
    map_normal_nn: int = 30
    map_plane_m: float = 0.3
    map_plane_ratio: float = 0.1
    mesh_target: bool = True
    mesh_sample_m: float = 0.02
    mesh_degenerate_ratio: float = 0.025
    max_pose_std_m: float = 0.02   # the pose's standard deviation along every direction the data measured
                                   # (and the result's slide off the guess along the held ones) must be within this
    guess_std_m: float = 0.05   # accuracy of the guess (TF / --init) along directions the data does not
                                # constrain (held at it): a hand-measured mount is good to a few cm. Reported
                                # as their uncertainty and accepted as stated (extrinsic.check_held): the data
                                # can neither confirm nor improve the guess there; it changes no result
    hold_m: float = 0.05        # directions the ICP holds stay within this of the guess (docs/design/register.md, 3.)
    anchor_max_deg: float = 0.5    # TF guess, slam map: held directions follow a map turn up to this
                                   # (docs/design/register.md, 3.)
    anchor_agree_deg: float = 0.1  # ... that the camera's yaw and position corrections show alike
    max_scale_m: float = 0.25
    crop_m: float = 0.6
    check_sigma_m: float = 0.02
    icp_iterations: int = 15
    degenerate_ratio: float = 0.05
    min_normal_cos: float = 0.8
    overlap_m: float = 0.15
    inlier_m: float = 0.05
    min_fitness: float = 0.6
    max_rmse_m: float = 0.03
    min_overlap_points: int = 300
    fpfh_voxel: float = 0.1
    # the global fallback must stay near the informed guess (TF / --init): corridors are
    # self-similar, and FPFH+RANSAC found 5-8 m shifted alignments that passed fitness/RMSE
    fallback_max_shift_m: float = 1.0
    fallback_max_rot_deg: float = 20.0
    max_range_m: float = 12.0
    fg_min_m: float = 0.12
    fg_sigma: float = 4.0
    map_explain_m: float = 0.08
    cluster_m: float = 0.08
    min_height_m: float = 0.5
    max_width_m: float = 1.4
    min_points: int = 100
    min_area_m2: float = 0.1
    cluster_px: float = 1.5
    link_sigma: float = 2.0     # neighbouring pixels link along the view within this many sigmas of their
                                # depth difference (docs/design/register.md, far people on a noisy camera)
    track_radius_m: float = 2.0
    track_jump_m: float = 0.4
    track_smooth: bool = True   # the person's centroid smoothed along the track, as far as its own noise
                                # allows (tracks.smooth_window; docs/design/register.md)
    walk_speed_mps: float = 1.5
    cut_reach_px: int = 3       # a silhouette ends against a nearer static surface within this many pixels
    cut_share: float = 0.5      # a frame whose silhouette is cut on this share of its rows is partly hidden:
                                # placed from the track's whole frames (humans.silhouette_cut, tracks.cut_prediction)
    cut_window_s: float = 1.0   # ... those within this many seconds either side
    max_depth_spread_m: float = 0.35
    floor_margin_m: float = 0.04
    max_speed_mps: float = 2.5
    plane_dist_m: float = 0.05
    plane_min_fraction: float = 0.03
    max_planes: int = 12
    thickness_m: float = 0.22
    min_thickness_m: float = 0.06
    surface_voxel: float = 0.04
    surface_gap_px: int = 2
    floor_reach_m: float = 0.35
    walk_back_frac: float = 0.3
    walk_back_speed_mps: float = 1.0
    breadth_m: float = 0.45     # a body's breadth across the shoulders, about twice its depth thickness_m: a person
                                # walking across the view shows their side, the far half hidden behind the near
                                # (tracks.side_back; docs/design/register.md, seen side-on)
    heading_speed_mps: float = 0.3   # above this plan speed the track's direction is the person's heading
    segment_lidar: bool = True
    slam_map: bool = True       # slam's stored static map (map/points) as the map, when built from these poses
    median_frames: int = 60
    processes: int = 0          # 0: two when the machine has two CPUs (the LiDAR half beside the camera half)
    write_camera_world: bool = False   # camera/points_world: the map-frame copy of camera/points

    def to_attrs(self) -> dict:
        d = asdict(self)
        d["icp_distances"] = list(self.icp_distances)
        return d


@dataclass
class Registration:
    """Result of :func:`register_extrinsic`: ``T`` (4,4) T_world_camera; ``method`` "icp" | "fpfh+icp";
    ``fitness`` inlier fraction of the overlap, ``rmse`` m, ``overlap`` points; ``accepted``;
    ``attempts`` the checks of every try (for the report)."""

    T: np.ndarray
    method: str
    fitness: float
    rmse: float
    overlap: int
    accepted: bool
    attempts: list = field(default_factory=list)

    def to_attrs(self) -> dict:
        return {"T_world_camera": np.asarray(self.T).tolist(), "method": self.method, "fitness": self.fitness,
                "rmse_m": self.rmse, "overlap_points": self.overlap, "accepted": self.accepted,
                "attempts": self.attempts}
