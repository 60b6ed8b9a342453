"""Depth images + CameraInfo -> points: encodings, row padding, truncated payloads, unprojection
against the pinhole model, and the truncated Image of the test_bag_sqlite3 fixture."""
from __future__ import annotations

import numpy as np
import pytest
from _recordings import FIXTURES, camera_info_msg, image_msg, store_for

from holodata.readers.base import DecodeError
from holodata.readers.images import camera_model, depth_image, depth_to_points, image_array


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1"])
def test_16uc1_millimetres_and_32fc1_metres(fmt):
    T = store_for(fmt).types
    mm = np.array([[0, 1000, 2500], [65535, 1, 10]], np.uint16)
    d = depth_image(image_msg(T, fmt, 0, "cam", mm, "16UC1"), "/d")
    assert d.dtype == np.float32 and np.isnan(d[0, 0])
    np.testing.assert_allclose(d[0, 1:], [1.0, 2.5])
    np.testing.assert_allclose(d[1], [65.535, 0.001, 0.01], rtol=1e-6)
    m = np.array([[np.nan, 1.25], [np.inf, -1.0]], np.float32)
    d2 = depth_image(image_msg(T, fmt, 0, "cam", m, "32FC1"), "/d")
    assert np.isnan(d2[0, 0]) and d2[0, 1] == 1.25 and np.isnan(d2[1]).all()


def test_row_padding_and_truncated_payload_names_topic():
    T = store_for("mcap").types
    a = np.arange(12, dtype=np.uint16).reshape(3, 4) + 1
    msg = image_msg(T, "mcap", 0, "cam", a, "16UC1")
    padded = b"".join(a[i].tobytes() + b"\0\0\0\0" for i in range(3))
    msg.step, msg.data = 12, np.frombuffer(padded, np.uint8)
    np.testing.assert_array_equal(image_array(msg), a)
    msg.data = np.frombuffer(padded[:20], np.uint8)
    with pytest.raises(DecodeError, match="topic /cam/depth: Image payload is 20 bytes.*truncated"):
        depth_image(msg, "/cam/depth")
    rgb = image_msg(T, "mcap", 0, "cam", np.zeros((2, 2, 3), np.uint8).reshape(2, 6), "rgb8")
    rgb.width = 2
    with pytest.raises(DecodeError, match="not a depth encoding"):
        depth_image(rgb, "/cam")


def test_unprojection_matches_pinhole_model():
    T = store_for("mcap").types
    K = np.array([[500.0, 0, 319.5], [0, 480.0, 239.5], [0, 0, 1]])
    cm = camera_model(camera_info_msg(T, "mcap", 0, "cam", K, 640, 480), "/info")
    np.testing.assert_array_equal(cm.K, K)
    assert (cm.width, cm.height) == (640, 480)
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.5, 5.0, (480, 640)).astype(np.float32)
    depth[rng.random((480, 640)) < 0.1] = np.nan
    pts, idx = depth_to_points(depth, cm.K)
    v, u = np.divmod(idx, 640)
    # project back: u = fx x/z + cx, v = fy y/z + cy
    np.testing.assert_allclose(500.0 * pts[:, 0] / pts[:, 2] + 319.5, u, atol=2e-3)
    np.testing.assert_allclose(480.0 * pts[:, 1] / pts[:, 2] + 239.5, v, atol=2e-3)
    np.testing.assert_array_equal(pts[:, 2], depth[v, u])
    assert len(pts) == np.isfinite(depth).sum()
    p2, i2 = depth_to_points(depth, cm.K, stride=4)
    assert np.all((i2 // 640) % 4 == 0) and np.all((i2 % 640) % 4 == 0)
    assert len(p2) == np.isfinite(depth[::4, ::4]).sum()
    bad = camera_info_msg(T, "mcap", 0, "cam", np.zeros((3, 3)), 640, 480)
    with pytest.raises(DecodeError, match="no focal length"):
        camera_model(bad, "/info")


def test_truncated_image_in_real_bag():
    path = FIXTURES / "ros2" / "sqlite3" / "test_bag_sqlite3"
    if not path.exists():
        pytest.skip(f"fixture folder {FIXTURES} is absent")
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        conns = [c for c in r.connections if c.topic == "/test/sensor_msgs/image"]
        msgs = [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(conns)]
    assert len(msgs) == 2
    for m in msgs:
        assert len(m.data) == 30 < m.step * m.height
        with pytest.raises(DecodeError, match="/test/sensor_msgs/image.*30 bytes.*921600"):
            image_array(m, "/test/sensor_msgs/image")


def test_stereo_depth_recovers_known_disparity():
    pytest.importorskip("cv2")
    from scipy.ndimage import gaussian_filter

    from holodata.readers.images import gray_image, stereo_baseline, stereo_depth

    rng = np.random.default_rng(3)
    tex = gaussian_filter(rng.uniform(0, 255, (80, 220)), 1.2)
    L = np.clip(tex[:, 20:180], 0, 255).astype(np.uint8)
    R = np.clip(tex[:, 28:188], 0, 255).astype(np.uint8)        # disparity 8 px everywhere
    fx, B = 50.0, 0.1
    d = stereo_depth(L, R, fx, B)
    core = d[10:-10, 40:-10]
    assert np.isfinite(core).mean() > 0.9
    np.testing.assert_allclose(np.nanmedian(core), fx * B / 8, rtol=0.02)
    T = store_for("mcap").types
    K = np.array([[fx, 0, 80], [0, fx, 40], [0, 0, 1.0]])
    info = camera_info_msg(T, "mcap", 0, "r", K, 160, 80)
    info.p = np.array([fx, 0, 80, -fx * B, 0, fx, 40, 0, 0, 0, 1, 0], float)
    assert stereo_baseline(info) == pytest.approx(B)
    rgb = np.repeat(L[..., None], 3, axis=2).reshape(80, 480)
    msg = image_msg(T, "mcap", 0, "l", rgb, "rgb8")
    msg.width = 160
    np.testing.assert_allclose(gray_image(msg).astype(int), L.astype(int), atol=1)
