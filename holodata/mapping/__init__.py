"""Mapping stages: LiDAR SLAM (:mod:`.slam`), the voxel background model of the static scene
(:mod:`.background`), static meshing (:mod:`.mesh`), accuracy against synthetic truth
(:mod:`.accuracy`), human segmentation and camera registration (part B modules).

Submodules are imported on demand (heavy dependencies: kiss-icp, open3d, evo)."""
