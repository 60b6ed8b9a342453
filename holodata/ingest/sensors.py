"""The scene attributes ingest writes about its sensors (:func:`sensor_attrs`: topic, frame, message
type and the decoder's settings per role, the pose in a world frame TF gives; :func:`extrinsics`: each
sensor's static pose in the robot's base frame) and the TF frames they are found by."""
from __future__ import annotations

import numpy as np

from .plan import Plan
from .radar_streams import radar_beam_origin
from .streams import CameraCloudStream, CloudStream, DepthStream, OusterPacketStream, OusterScanStream, StereoStream


def world_frame(tf, frame: str) -> str | None:
    """``map``/``world``/``odom`` if TF connects it to ``frame``, else the root of ``frame``'s tree
    when a moving (non-static) transform leads from it to ``frame`` — a tree of static transforms only
    is the rig's own (``base_link → radar``), not a world the sensor moves in."""
    from ..readers.tf import WORLD_FRAMES

    for cand in WORLD_FRAMES:
        if cand in tf.frames and tf._path(cand, frame, False) is not None:
            return cand
    root = tf.root(frame)
    return None if root == frame or tf._path(root, frame, True) is not None else root


def sensor_frame(plan: Plan, role: str) -> str | None:
    """The TF frame of sensor ``role``'s messages (the radar's first message, the probe's for the others), or None."""
    st = plan.streams.get(role)
    if st is None:
        return None
    if role == "radar":
        return str(st.first.header.frame_id).lstrip("/")
    pr = plan.probe.get(role) or {}
    return (pr.get("frame_id") or "").lstrip("/") or None


def extrinsics(plan: Plan) -> dict:
    """{role: T_base_sensor (4x4 list)}: each sensor's static pose in the robot's base frame, where TF gives one."""
    tf = plan.tf
    if tf is None or not tf.frames:
        return {}
    from ..readers.tf import BASE_FRAMES, find_frame

    base = plan.tmap.base_frame or find_frame(tf.frames, BASE_FRAMES)
    out = {}
    if base is None:
        return out
    for role in ("radar", "lidar", "camera"):
        fr = sensor_frame(plan, role)
        if not fr:
            continue
        T = tf.lookup(base, fr, None, static_only=True)
        if T is not None:
            out[role] = T.tolist()
    return out


def sensor_attrs(plan: Plan) -> dict:
    """{role: the scene attribute ``sensors.<role>``}: topic, frame, message type and the decoder's
    settings, and ``T_<world>_sensor`` where TF gives the sensor a static pose in a world frame."""
    out: dict = {}
    tf = plan.tf
    for role, st in plan.streams.items():
        d = {"topic": st.topic, "frame_id": sensor_frame(plan, role)}
        if role == "radar":
            m = st.first
            d.update({"type": m.__class__.__name__ if not hasattr(m, "__msgtype__") else m.__msgtype__,
                      "encoding": str(m.encoding), "shape": list(st.shape),
                      "rotation_radius_m": float(m.rotation_radius), "range_resolution_m": float(m.range_resolution),
                      "elevation_max_rad": float(m.elevation_max), "elevation_min_rad": float(m.elevation_min),
                      "beam_origin": radar_beam_origin(m, st.topic).to_attrs()})
        if isinstance(st, (OusterScanStream, OusterPacketStream)):
            meta = st.rec.meta if isinstance(st, OusterScanStream) else None
            if meta is None:
                from ..readers.ouster import load_info, sensor_meta

                info, text = load_info(st.metadata_text)
                meta = sensor_meta(info, text)
            d["ouster"] = meta.to_attrs()
            d["ouster_metadata_json"] = meta.json_text
            d["range_definition"] = "Ouster RANGE channel (beam origin), destaggered"
        elif role == "lidar":
            pr = plan.probe.get("lidar") or {}
            d["organised_grid"] = list(pr["grid"]) if pr.get("grid") else None
            if pr.get("grid"):
                d["range_definition"] = ("norm of xyz (sensor origin), grid as published" if isinstance(st, CloudStream)
                                         else "range image as stored in the recording (m)")
            if getattr(st, "time_field", None):
                d["time_field"] = st.time_field
                d["time_reference"] = st.time_reference
        if isinstance(st, StereoStream):
            d["stereo"] = {"right_topic": st.right_topic, "right_camera_info_topic": st.right_info_topic,
                           "baseline_m": st.baseline, "matcher": "OpenCV StereoSGBM (3-way), block 5",
                           "depth": "fx * baseline / disparity"}
        if isinstance(st, DepthStream):
            d["camera_info_topic"] = st.info_topic
            d["intrinsics"] = st.model.to_attrs()
            d["stride"] = st.stride
            d["points_frame"] = "optical (x right, y down, z forward)"
        T_frame_points = np.eye(4)
        if isinstance(st, CameraCloudStream) and st.model is not None:
            d["camera_info_topic"] = st.info_topic
            d["intrinsics"] = {**st.model.to_attrs(), "source": st.model_source}
            d["points_frame"] = ("optical (x right, y down, z forward)" + (
                "" if np.array_equal(st.R_opt, np.eye(3)) else f", rotated from the cloud's frame {d['frame_id']!r}"))
            T_frame_points[:3, :3] = st.R_opt.T      # the points' optical axes in the cloud's frame
        fr = d.get("frame_id")
        if tf is not None and fr and tf.frames:
            from ..readers.tf import WORLD_FRAMES, find_frame

            world = plan.tmap.world_frame or find_frame(tf.frames, WORLD_FRAMES)
            if world:
                T = tf.lookup(world, fr, None, static_only=True)
                if T is not None:
                    d[f"T_{world}_sensor"] = (T @ T_frame_points).tolist()   # the frame camera/points are in
        out[role] = d
    return out
