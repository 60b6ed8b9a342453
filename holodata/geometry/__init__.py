"""holodata's geometry core, shared by slam, register, the mesh and the background model: voxel keys,
one point per voxel and voxel means (:mod:`.voxels`), point-to-plane Gauss-Newton ICP with robust
weights and held directions (:mod:`.icp`), plane fits (:mod:`.planes`), un-mirroring of multi-return
range images into real points (:mod:`.unmirror`, stage two without learning), quaternions and SLERP for
poses (:mod:`.rotations`). Arrays in, arrays out: no I/O, no dataset types."""
from __future__ import annotations

from .icp import (
                  IcpParams,
                  Step,
                  StepRule,
                  about_origin,
                  centred_offset,
                  gauss_newton_step,
                  hold_at,
                  moved_by,
                  open3d_icp,
                  point_to_plane_icp,
                  tukey_weights,
)
from .planes import (
                  PlaneRansac,
                  agreeing_planes,
                  fit_height_plane,
                  fit_plane,
                  local_plane_projection,
                  ransac_plane,
                  window_plane_normals,
)
from .voxels import (
                  cell_keys,
                  dense_box,
                  first_per_voxel,
                  flat_index,
                  unique_voxels,
                  unpack_keys,
                  voxel_average,
                  voxel_index,
                  voxel_keys,
)

__all__ = ["IcpParams", "Step", "StepRule", "PlaneRansac", "about_origin", "centred_offset", "gauss_newton_step",
           "hold_at", "moved_by", "open3d_icp", "point_to_plane_icp", "tukey_weights", "agreeing_planes",
           "fit_height_plane", "fit_plane", "local_plane_projection", "ransac_plane", "window_plane_normals",
           "cell_keys", "dense_box", "first_per_voxel", "flat_index", "unique_voxels", "unpack_keys", "voxel_average",
           "voxel_index", "voxel_keys"]
