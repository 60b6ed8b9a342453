"""slam and register on a held-out recording (holodata.synth.heldout, issue 23): one world frame with
TF, a refused off-frame guess, organised camera clouds, honest held directions; and the numeric
cores they rest on (pinhole fit, camera free-space carving, held-direction words)."""
from __future__ import annotations

import numpy as np
import pytest

from holodata.errors import InputError
from holodata.readers.images import R_LINK_OPTICAL, fit_pinhole

pytestmark = pytest.mark.slow   # Dask clusters / a moto S3 server / whole recordings: the full tier


def _grid_cloud(K, h, w, depth):
    v, u = np.mgrid[0:h, 0:w]
    z = depth(v, u)
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], -1).reshape(-1, 3), v.ravel(), u.ravel()


def test_fit_pinhole_recovers_the_intrinsics_and_the_cloud_frame():
    K = np.array([[84.3, 0.0, 79.5], [0.0, 86.1, 60.2], [0.0, 0.0, 1.0]])
    p, rows, cols = _grid_cloud(K, 120, 160, lambda v, u: 2.0 + 0.01 * u + 0.02 * v)
    for R_cloud in (np.eye(3), R_LINK_OPTICAL):          # points published in optical / camera_link axes
        Kf, R, rms = fit_pinhole(p @ R_cloud.T, rows, cols)
        np.testing.assert_allclose(Kf, K, atol=1e-6)
        np.testing.assert_allclose(R @ R_cloud, np.eye(3), atol=1e-12)
        assert rms < 1e-6
    # a cloud that is not a pinhole image (shuffled pixels) fits badly
    perm = np.random.default_rng(0).permutation(len(p))
    assert fit_pinhole(p[perm], rows, cols)[2] > 10


def test_camera_seen_through_marks_map_points_the_camera_looks_past():
    from holodata.mapping.register import camera_seen_through

    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    T = np.eye(4)
    wall = np.full((48, 64), 5.0, np.float32)
    ghost = wall.copy()
    ghost[20:28, 28:36] = 3.0                                  # something at 3 m in 2 of 10 frames
    images = [ghost, ghost] + [wall] * 8
    pts = np.array([[0.0, 0.0, 3.0],     # the ghost's place: seen through in 8 of 10 frames
                    [0.0, 0.0, 5.0],     # the wall itself
                    [0.1, 0.0, 6.0],     # behind the wall: never seen through
                    [9.0, 0.0, 3.0]])    # outside the image
    np.testing.assert_array_equal(camera_seen_through(pts, T, K, (48, 64), images, 0.12), [True, False, False, False])
    # seen through in fewer than min_fraction of the frames: kept
    assert not camera_seen_through(pts[:1], T, K, (48, 64), [ghost] * 9 + [wall], 0.12, min_fraction=0.2)[0]


def test_held_directions_are_named():
    from holodata.mapping.register import held_directions

    V = np.zeros((6, 2))
    V[4, 0] = -1.0                     # translation along y
    V[2, 1] = 1.0                      # rotation about z
    assert held_directions((V, np.zeros(3), 2.0)) == ["translation along (0.00, 1.00, 0.00)",
                                                      "rotation about (0.00, 0.00, 1.00)"]


def test_a_direction_the_view_does_not_constrain_is_named_and_carries_the_guess_uncertainty():
    from holodata.mapping.register import RegisterConfig, register_extrinsic

    rng = np.random.default_rng(1)
    n = 20000
    x = rng.uniform(0.0, 6.0, n)
    s = rng.uniform(0.0, 1.0, n)
    side = rng.integers(0, 4, n)           # a corridor along x: walls y = +-1, floor, ceiling; no end wall
    corridor = np.where(side[:, None] == 0, np.c_[x, -np.ones(n), 2.5 * s],
                        np.where(side[:, None] == 1, np.c_[x, np.ones(n), 2.5 * s],
                                 np.where(side[:, None] == 2, np.c_[x, 2 * s - 1, np.zeros(n)],
                                          np.c_[x, 2 * s - 1, np.full(n, 2.5)])))
    T_true = np.eye(4)
    T_true[:3, 3] = [0.5, 0.1, 1.2]
    cam = corridor[(corridor[:, 0] > 1.5) & (corridor[:, 0] < 4.5)] - T_true[:3, 3]
    init = T_true.copy()
    init[:3, 3] += [0.04, 0.0, 0.0]        # the guess is 4 cm off along the corridor
    # the view cannot tell along the corridor: the result there is the guess, accepted at the guess's
    # stated precision (5 cm by default) and reported as such (issue 55)
    held = register_extrinsic(cam, corridor, init, RegisterConfig(mesh_target=False), allow_fallback=False)
    a = held.attempts[0]
    assert held.accepted and a["frozen_directions"] >= 1
    assert any(h.startswith("translation along (1.00, 0.0") for h in a["held_directions"]), a["held_directions"]
    assert a["uncertainty_m"] == pytest.approx(0.05)            # not the sub-millimetre pose_std_m
    ok = register_extrinsic(cam, corridor, init, RegisterConfig(mesh_target=False, guess_std_m=0.01),
                            allow_fallback=False)
    assert ok.accepted and ok.attempts[0]["uncertainty_m"] == pytest.approx(0.01)
    assert abs(ok.T[0, 3] - init[0, 3]) < 0.02 and abs(ok.T[1, 3] - T_true[1, 3]) < 0.005


@pytest.fixture(scope="module")
def heldout(tmp_path_factory):
    from holodata.synth.heldout import HeldOutConfig, synthesize_heldout

    root = tmp_path_factory.mktemp("heldout")
    rec = synthesize_heldout(root / "h", HeldOutConfig(seed=3, start_back_m=2.5, into_hidden_m=1.8, lidar_rows=64,
                                                       lidar_cols=512, lidar_fov_deg=45.0, camera_output="cloud",
                                                       camera_shape=(90, 120), tf_late_s=0.35))
    return root, rec


def test_slam_world_is_the_tf_world_and_register_uses_the_organised_cloud(heldout):
    from holodata import open_dataset
    from holodata.evaluate.register_accuracy import extrinsic_error, human_centroid_errors, truth_camera_extrinsic
    from holodata.ingest import ingest
    from holodata.mapping.register import RegisterConfig, register_scene
    from holodata.mapping.slam import slam_scene
    from holodata.trajectory import read_tum

    root, rec = heldout
    url = str(root / "tf.zarr")
    ingest([rec], url)
    sc = open_dataset(url).scene(open_dataset(url).scenes[0])
    P = np.asarray(sc["tf/T_world_lidar"][...])
    assert np.isnan(P[0]).all() and np.isfinite(P[-1]).all()     # TF starts after the LiDAR
    intr = sc.attrs["sensors"]["camera"]["intrinsics"]
    assert (intr["height"], intr["width"]) == (90, 120) and intr["source"].startswith("CameraInfo")
    slam_scene(url, sc.id, quiet=True)
    sc = open_dataset(url).scene(sc.id)
    a = sc.attrs["slam"]["anchor"]
    assert a["kind"] == "tf" and a["world_frame"] == "map" and a["scan"] > 0
    truth = read_tum(root / "h" / "truth" / "trajectory_lidar.tum").poses
    err = np.linalg.norm(np.asarray(sc["pose/T_world_lidar"][...])[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert err[:5].max() < 0.01 and np.median(err) < 0.05, err   # scan 0 was the identity before
    # the TF tree is planar (wheel odometry on a level floor): height, roll and pitch are TF's
    assert sc.attrs["slam"]["summary"]["health"]["sequential"]["vertical_from"] == "tf"
    Pe = np.asarray(sc["pose/T_world_lidar"][...])
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ki,ki->k", Pe[:, :3, 2], truth[:, :3, 2]), -1, 1)))
    assert tilt.max() < 0.05 and np.abs(Pe[:, 2, 3] - truth[:, 2, 3]).max() < 0.01
    g = sc.attrs["slam"]["summary"]["tf_agreement"]            # TF's odometry drifts 1 % of the distance
    assert g["scans"] >= 0.9 * np.isfinite(P[:, 0, 0]).sum() and 0 < g["position_max_m"] < 0.15, g
    # the camera looks down the hidden leg and sees little across it: that direction is the guess's,
    # accepted at the guess's stated precision (--guess-std, 5 cm by default; issue 55)
    res = register_scene(url, sc.id, quiet=True)
    held = res["extrinsic"]["attempts"][0]
    assert held["uncertainty_m"] == pytest.approx(0.05) and held["pose_std_m"] < 0.005
    # "good to 2 cm": taken at the user's word; the map's possible turn about its anchor, which the
    # data could not read here (the guess's yaw is off too), is reported beside it as a bound
    res = register_scene(url, sc.id, cfg=RegisterConfig(guess_std_m=0.02), quiet=True)
    chosen = res["extrinsic"]["attempts"][0]
    assert chosen["uncertainty_m"] == pytest.approx(0.02) and chosen["pose_std_m"] < 0.005
    assert chosen["map_turn_reach_m"] and max(chosen["map_turn_reach_m"]) > 0.01
    assert chosen["held_slide_m"] and max(abs(x) for x in chosen["held_slide_m"]) < 1e-4
    T = np.asarray(open_dataset(url).scene(sc.id)["calib/T_world_camera"][...])
    e = extrinsic_error(T, truth_camera_extrinsic(root / "h" / "truth"))
    assert e["rot_deg"] < 1, e                                 # the TF guess was 7.8 cm / 2.7 deg off
    assert res["frames_with_human"] > 0.5 * res["frames"]
    # (the held direction keeps the guess's 7.8 cm error, in the camera and so in the person: the
    # issue's p90 floor, 20 cm, bounds the median here; a clean-clone run gave 15.02 cm)
    assert human_centroid_errors(url, sc.id, root / "h" / "truth")["median_cm"] < 20


def test_register_refuses_a_guess_from_a_frame_the_map_is_not_in(heldout):
    from holodata import open_dataset
    from holodata.ingest import IngestOptions, ingest
    from holodata.mapping.register import register_scene
    from holodata.mapping.slam import SlamConfig, slam_scene

    root, rec = heldout
    url = str(root / "notf.zarr")
    ingest([rec], url, IngestOptions(topics={"tf": None}))   # odometry TF left out: the LiDAR is not connected to map
    sid = open_dataset(url).scenes[0]
    assert "tf/T_world_lidar" not in open_dataset(url).scene(sid).arrays()
    slam_scene(url, sid, quiet=True, config=SlamConfig(mesh=False))
    assert open_dataset(url).scene(sid).attrs["slam"]["anchor"]["kind"] != "tf"
    with pytest.raises(InputError, match=r"camera's TF pose is in 'map' but the LiDAR map is in .*--init"):
        register_scene(url, sid, quiet=True)


def test_heldout_truth_masks_are_the_returns_on_the_person(heldout):
    """truth/lidar_instances.npz (issue 25 point 11): per scan, returns of the recorded scan only, and
    they lie on the person (the true pose puts them around the person's mesh)."""
    from holodata import open_dataset
    from holodata.ingest import ingest
    from holodata.meshio import read_mesh
    from holodata.synth.truth import read_lidar_instances
    from holodata.trajectory import read_tum

    root, rec = heldout
    truth = root / "h" / "truth"
    url = str(root / "masks.zarr")
    ingest([rec], url)
    sc = open_dataset(url).scene(open_dataset(url).scenes[0])
    tr = read_lidar_instances(truth / "lidar_instances.npz")
    lid = read_tum(truth / "trajectory_lidar.tum")
    np.testing.assert_array_equal(tr["stamp_ns"], lid.timestamp_ns)
    assert int(tr["n_walkers"]) == 1 and not bool(tr["hidden_human"])
    frame = {int(t): k for k, t in enumerate(np.asarray(sc["lidar/timestamp_ns"][...], np.int64))}
    on_person = 0
    for i in range(0, len(tr["stamp_ns"]), 3):
        m = tr["mask"](i) > 0
        k = frame[int(tr["stamp_ns"][i])]
        r = np.asarray(sc["lidar/range"][k], float)
        fin = np.isfinite(r)
        P = np.zeros(r.shape + (3,))
        P[fin] = np.asarray(sc.ragged("lidar/points", k), float)   # the valid pixels in row-major order
        valid = fin & (r > 0)
        assert not (m & ~valid).any()                         # only returns are labelled
        if m.sum() < 20:
            continue
        on_person += 1
        T = lid.poses[i]
        Pw = P[m] @ T[:3, :3].T + T[:3, 3]
        others = P[valid & ~m] @ T[:3, :3].T + T[:3, 3]
        c = read_mesh(truth / "human" / f"{i:06d}.ply").vertices[:, :2].mean(0)
        near = np.linalg.norm(Pw[:, :2] - c, axis=1)
        assert np.median(near) < 0.4, np.median(near)         # the person moves < 6 cm within half a sweep
        others = others[others[:, 2] > 0.3]                  # (the floor between the feet is not the person)
        assert (np.linalg.norm(others[:, :2] - c, axis=1) < 0.1).sum() < 0.05 * m.sum()   # few unlabelled there
    assert on_person >= 5
