"""The topics of a synthetic recording (the package docstring describes each): the data pass's
``TOPICS``, ``RAW_TOPIC`` instead of the heatmaps with ``radar_output="iq"``, the mapping pass's
``MAPPING_TOPICS`` and the stereo pair's ``STEREO_TOPICS``."""
from __future__ import annotations

TOPICS = {
    "/radar/heatmap": "holodata_msgs/msg/RadarHeatmap",
    "/ouster/points": "sensor_msgs/msg/PointCloud2",
    "/ouster/metadata": "std_msgs/msg/String",
    "/zed2i/zed_node/depth/depth_registered": "sensor_msgs/msg/Image",
    "/zed2i/zed_node/depth/camera_info": "sensor_msgs/msg/CameraInfo",
    "/zed2i/zed_node/point_cloud/cloud_registered": "sensor_msgs/msg/PointCloud2",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/odom": "nav_msgs/msg/Odometry",
}
# ``radar_output="iq"``: raw samples of every rotation instead of the heatmaps
RAW_TOPIC = "/radar/raw"
RADAR_OUTPUTS = ("heatmap", "iq")
# the mapping pass's recording (``mapping_pass=True``): LiDAR and odometry only
MAPPING_TOPICS = {t: TOPICS[t] for t in ("/ouster/points", "/ouster/metadata", "/tf", "/tf_static", "/odom")}
# with ``stereo_images=True``: the rectified pair behind the depth camera (mono8, textured scene)
STEREO_TOPICS = {
    "/zed2i/zed_node/left/image_rect_gray": "sensor_msgs/msg/Image",
    "/zed2i/zed_node/left/camera_info": "sensor_msgs/msg/CameraInfo",
    "/zed2i/zed_node/right/image_rect_gray": "sensor_msgs/msg/Image",
    "/zed2i/zed_node/right/camera_info": "sensor_msgs/msg/CameraInfo",
}

