"""Topic roles: which recording topic is the radar, the LiDAR, the camera, TF (:func:`map_topics`,
:class:`TopicMap`, ``--topics`` YAML files)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import HolodataError, InputError, one_line
from ..readers.base import POINTS_TYPE, RANGE_IMAGE_TYPE, Recording, TopicInfo

RADAR_SUFFIX = ("/RadarHeatmap", "/RadarRawRotation")   # heatmaps, raw rotations (beamformed by ingest)
RAW_SUFFIX = "/RadarRawRotation"
PC2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
CAMINFO = "sensor_msgs/msg/CameraInfo"
STRING = "std_msgs/msg/String"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
OUSTER_SCAN = "ouster/LidarScan"
OUSTER_PACKETS = ("ouster_ros/msg/PacketMsg", "ouster_sensor_msgs/msg/PacketMsg")  # ouster-ros < / >= 0.10
CAMERA_WORDS = ("camera", "cam", "zed", "realsense", "rgbd", "depth", "stereo", "optical", "kinect", "oak",
                "d435", "d455", "image")
ROLES = ("radar", "lidar", "lidar_metadata", "camera", "camera_info", "camera_right", "camera_info_right", "tf",
         "tf_static")
OPTIONS = ("time", "world_frame", "base_frame", "camera_stride")
DEFAULT_TOLERANCE_MS = 50.0
SHARD_TARGET_BYTES = 32 << 20
# Codec of the bulk arrays (radar/heatmap, lidar/range, lidar|camera/points, lidar/point_time_ns)
# unless --codec says otherwise; the small ones (time stamps, cycles, poses) keep the dataset's
# (zstd). Blosc lz4 + byte shuffle encodes several times faster than zstd clevel 3, for slightly larger
# output on float heatmaps and point clouds (benchmarks/results/ingest.md; benchmarks/ingest.py).
BULK_CODEC = "lz4"




# ==================================================================================================
# topic mapping

@dataclass
class TopicMap:
    """Which topic plays which role (None = not used) plus options."""

    radar: str | None = None
    lidar: str | None = None
    lidar_metadata: str | None = None
    camera: str | None = None
    camera_info: str | None = None
    camera_right: str | None = None
    camera_info_right: str | None = None
    tf: list[str] = field(default_factory=list)
    tf_static: list[str] = field(default_factory=list)
    time: str = "header"
    world_frame: str | None = None
    base_frame: str | None = None
    camera_stride: int = 1

    def to_dict(self) -> dict:
        return dict(vars(self))


def load_topics_file(path) -> dict:
    """The YAML mapping of ``--topics`` (see ``examples/topics.yaml``); InputError on bad content."""
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except OSError as err:
        raise InputError(f"{p}: cannot read topics file ({err.strerror})") from err
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        what = getattr(err, "problem", None) or one_line(err)
        raise InputError(f"{p}: not valid YAML{where}: {what}") from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"{p}: topics file must be a mapping of role: topic")
    bad = [k for k in data if k not in ROLES + OPTIONS]
    if bad:
        raise InputError(f"{p}: unknown key(s) {', '.join(map(str, bad))} (roles: {', '.join(ROLES)}; "
                         f"options: {', '.join(OPTIONS)})")
    if data.get("time", "header") not in ("header", "log"):
        raise InputError(f"{p}: time must be 'header' or 'log', got {data.get('time')!r}")
    for k in ("tf", "tf_static"):
        if isinstance(data.get(k), str):
            data[k] = [data[k]]
    return data


def _camera_like(*names: str | None) -> bool:
    low = " ".join(n.lower() for n in names if n)
    return any(w in low for w in CAMERA_WORDS)


def _looks_static(name: str) -> bool:
    return "static" in name


def map_topics(rec: Recording, override: dict | None = None, topics: list[TopicInfo] | None = None
               ) -> tuple[TopicMap, list[str]]:
    """Guess the topic roles of ``rec`` (see module docstring), apply ``override``; returns the map
    and notes (one line each) about topics that look like sensors but are not used."""
    infos = topics if topics is not None else rec.topics(frame_ids=True)
    by = {t.name: t for t in infos}
    notes: list[str] = []
    m = TopicMap()
    usable = [t for t in infos if t.count > 0 and t.decodable]
    for t in infos:
        if t.count > 0 and not t.decodable:
            notes.append(f"topic {t.name}: {t.msgtype} x{t.count} skipped ({t.note or 'not decodable'})")
    radar = sorted((t for t in usable if t.msgtype.endswith(RADAR_SUFFIX)), key=lambda t: (-t.count, t.name))
    if radar:
        m.radar = radar[0].name
        notes += [f"topic {t.name}: second radar topic, not used" for t in radar[1:]]
    # LiDAR
    ouster = [t for t in usable if t.msgtype in (OUSTER_SCAN, RANGE_IMAGE_TYPE)]
    plain = [t for t in usable if t.msgtype == POINTS_TYPE]
    packets = [t for t in usable if t.msgtype in OUSTER_PACKETS and "imu" not in t.name.lower()]
    clouds = [t for t in usable if t.msgtype == PC2] + plain
    lidar_clouds = sorted((t for t in clouds if not _camera_like(t.name, t.frame_id)), key=lambda t: (-t.count, t.name))
    cam_clouds = sorted((t for t in clouds if _camera_like(t.name, t.frame_id)), key=lambda t: (-t.count, t.name))
    if ouster:
        m.lidar = ouster[0].name
    elif lidar_clouds:
        m.lidar = lidar_clouds[0].name
        notes += [f"topic {t.name}: another point cloud, not used (name it in --topics to choose)"
                  for t in lidar_clouds[1:]]
    elif packets:
        meta = [t for t in infos if t.msgtype == STRING and "metadata" in t.name.lower() and t.count > 0]
        if meta:
            m.lidar, m.lidar_metadata = packets[0].name, meta[0].name
        else:
            notes.append(f"topic {packets[0].name}: Ouster packets without a metadata String topic; not used")
    # camera: a depth image with camera info, else a camera point cloud
    images = [t for t in usable if t.msgtype == IMAGE]
    infos_ci = [t for t in usable if t.msgtype == CAMINFO]
    depth, not_depth = [], {}
    for t in images:
        ok, why = _probe_depth(rec, t.name)
        if ok:
            depth.append(t)
        else:
            not_depth[t.name] = why
    if depth:
        depth.sort(key=lambda t: (0 if "depth" in t.name.lower() else 1, -t.count, t.name))
        m.camera = depth[0].name
        m.camera_info = _camera_info_for(depth[0], infos_ci)
        if m.camera_info is None:
            notes.append(f"topic {m.camera}: depth image without a CameraInfo topic; not used")
            m.camera = None
    if m.camera is None and cam_clouds:
        m.camera = cam_clouds[0].name
        m.camera_info = _camera_info_for(cam_clouds[0], infos_ci)   # (used when it fits the cloud's pixels)
    if m.camera is None:  # only images: a rectified stereo pair (left/right + CameraInfo) gives depth
        for t in sorted(images, key=lambda t: t.name):
            right = t.name.replace("left", "right")
            if "left" in t.name and right != t.name and right in by and by[right].msgtype == IMAGE \
                    and "truncated" not in not_depth.get(t.name, "") + not_depth.get(right, ""):
                li, ri = _camera_info_for(t, infos_ci), _camera_info_for(by[right], infos_ci)
                if li and ri and li != ri:
                    m.camera, m.camera_info, m.camera_right, m.camera_info_right = t.name, li, right, ri
                    not_depth.pop(t.name, None)
                    not_depth.pop(right, None)
                    break
    notes += list(not_depth.values())
    for t in usable:
        if t.msgtype in TF_TYPES:
            (m.tf_static if _looks_static(t.name) else m.tf).append(t.name)
    if override:
        _apply_override(m, override, by, rec)
    used = {v for r in ROLES for v in ([getattr(m, r)] if isinstance(getattr(m, r), str) else getattr(m, r) or [])}
    notes = [n for n in notes if not any(f"topic {t}:" in n for t in used)]
    return m, notes


def _probe_depth(rec: Recording, topic: str) -> tuple[bool, str]:
    """(is a usable depth image topic, why not) from its first message."""
    from ..readers.images import depth_image, image_array, is_depth_encoding

    try:
        raw = next(iter(rec.raw_messages([topic])))
        msg = rec.decode(raw)
        if not is_depth_encoding(str(msg.encoding)):
            image_array(msg, topic)  # a truncated payload is reported as such
            return False, f"topic {topic}: Image {msg.encoding} is not a depth image (16UC1/32FC1); not used"
        depth_image(msg, topic)
    except StopIteration:
        return False, f"topic {topic}: no messages"
    except HolodataError as err:
        return False, f"{one_line(err)}; topic skipped"
    return True, ""


def _camera_info_for(img: TopicInfo, infos: list[TopicInfo]) -> str | None:
    if not infos:
        return None
    ns = img.name.rsplit("/", 1)[0]
    same_ns = [t for t in infos if t.name.rsplit("/", 1)[0] == ns]
    same_frame = [t for t in infos if img.frame_id and t.frame_id == img.frame_id]
    for group in (same_ns, same_frame, infos):
        if group:
            return sorted(group, key=lambda t: t.name)[0].name
    return None


def _apply_override(m: TopicMap, ov: dict, by: dict[str, TopicInfo], rec: Recording) -> None:
    for k, v in ov.items():
        if k in ("tf", "tf_static"):
            v = [] if v is None else list(v)
            for name in v:
                _check_topic(name, by, rec)
            setattr(m, k, v)
        elif k in ROLES:
            if v is not None:
                _check_topic(str(v), by, rec)
            setattr(m, k, None if v is None else str(v))
        elif k == "camera_stride":
            if not isinstance(v, int) or v < 1:
                raise InputError(f"topics file: camera_stride must be an integer >= 1, got {v!r}")
            m.camera_stride = v
        else:
            setattr(m, k, v)
    if m.lidar and by[m.lidar].msgtype in OUSTER_PACKETS and not m.lidar_metadata:
        raise InputError(f"topics file: lidar {m.lidar} carries Ouster packets; name the metadata String topic "
                         f"as lidar_metadata")
    if m.camera and by[m.camera].msgtype == IMAGE and not m.camera_info:
        raise InputError(f"topics file: camera {m.camera} is an Image; name its CameraInfo topic as camera_info")
    if m.camera_right and not m.camera_info_right:
        raise InputError(f"topics file: camera_right {m.camera_right} needs its CameraInfo as camera_info_right")


def _check_topic(name: str, by: dict[str, TopicInfo], rec: Recording) -> None:
    if name not in by:
        have = ", ".join(sorted(by)[:12])
        raise InputError(f"topics file: {name} is not a topic of {rec.path} (have: {have}{' ...' if len(by) > 12 else ''})")
