"""Mapping stages: LiDAR SLAM (:mod:`.slam`), the voxel background model of the static scene
(:mod:`.background`), static meshing (:mod:`.mesh`), human segmentation and camera registration
(part B modules). Their accuracy against synthetic truth is evaluation: :mod:`holodata.evaluate.slam_accuracy`
and :mod:`holodata.evaluate.register_accuracy`.

Submodules are imported on demand (heavy dependencies: kiss-icp, open3d, evo)."""
