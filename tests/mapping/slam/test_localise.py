"""Map first, then record (issue 22): ``holodata slam --map-scene`` slams a mapping pass and localises
the data pass in its map; the mesh coverage of the true surface within the radar's reach."""
import numpy as np
import pytest
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.conventions import Grid, RangeBins
from holodata.evaluate.slam_accuracy import RadarTrace, mesh_coverage, radar_reach


@pytest.fixture(scope="module")
def localised(tmp_path_factory):
    from holodata.ingest import ingest
    from holodata.mapping.slam import slam_scene
    from holodata.synth import SynthSpec, synthesize

    root = tmp_path_factory.mktemp("loc")
    res = synthesize(root / "rec", SynthSpec(corner="L", width=2.0, frames=4, seed=3, grid=Grid(8, 32),
                                             range_bins=RangeBins(64), lidar_shape=(32, 256), camera_shape=(24, 40),
                                             lidar_vertical_fov_deg=90.0, mapping_pass=True), quiet=True)
    url = str(root / "ds.zarr")
    ingest([str(res.recording), str(res.mapping_recording)], url, scene_ids=["c", "c_map"], quiet=True)
    r = slam_scene(url, "c", map_scene="c_map", quiet=True)
    return url, res, r


@pytest.mark.slow
def test_data_pass_localised_in_the_maps_world_within_a_few_cm(localised):
    import holodata
    from holodata.trajectory import read_tum

    url, res, r = localised
    ds = holodata.open_dataset(url)
    sc, mp = ds.scene("c"), ds.scene("c_map")
    assert mp.attrs["role"] == "mapping" and mp.attrs["mapping_for"] == ["c"]
    slam = sc.attrs["slam"]
    assert slam["mode"] == "localisation" and slam["map_scene"] == "c_map" and slam["complete"]
    # the same world frame as the truth (both recordings' TF "map" frame): no alignment
    Tl = np.asarray(sc["pose/T_world_lidar"][...])
    st = np.asarray(sc["lidar/timestamp_ns"][...])
    truth = read_tum(res.truth_dir / "trajectory_lidar.tum").interpolate(st)
    err = np.linalg.norm(Tl[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert err.max() < 0.04, err
    Tr = np.asarray(sc["pose/T_world_radar"][...])
    tr = read_tum(res.truth_dir / "trajectory_radar.tum").poses
    assert np.linalg.norm(Tr[:, :3, 3] - tr[:, :3, 3], axis=1).max() < 0.05
    # the map pass too, and the data scene holds the map's mesh and points, in that frame
    Tm = np.asarray(mp["pose/T_world_lidar"][...])
    tm = read_tum(res.truth_dir / "mapping_trajectory_lidar.tum").interpolate(np.asarray(mp["lidar/timestamp_ns"][...]))
    assert np.linalg.norm(Tm[:, :3, 3] - tm[:, :3, 3], axis=1).max() < 0.08
    assert np.array_equal(np.asarray(sc["mesh/faces"][...]), np.asarray(mp["mesh/faces"][...]))
    assert np.array_equal(np.asarray(sc["map/points"][...]), np.asarray(mp["map/points"][...]))
    nodes = sc.nodes()
    srcs = {(nodes[n][1].get("attributes") or {}).get("source") for n in ("pose/T_world_lidar", "mesh/vertices", "map/points")}
    assert srcs == {"slam"}                              # register takes them as built from these poses
    # the map reaches into the hidden branch, which the data pass's LiDAR never sees
    v = np.asarray(sc["mesh/vertices"][...])
    from holodata.synth.worlds import make_world

    w = make_world("L", 2.0, 3)
    o, d, length, _ = w.hidden_axis
    assert ((v[:, :2] - o) @ d).max() > length - 2.0
    # resumable: a second run finds it done
    from holodata.mapping.slam import slam_scene

    again = slam_scene(url, "c", map_scene="c_map", quiet=True)
    assert "skipped" in again.summary
    # slam over every scene keeps the scene localised against its mapping pass (no approach-only map);
    # the mapping pass is slammed as that map, not on its own
    from holodata.mapping.slam import slam_dataset

    res = {r.scene: r for r in slam_dataset(url, quiet=True)}
    assert set(res) == {"c"} and "skipped" in res["c"].summary
    assert open_dataset_attrs(url, "c")["mode"] == "localisation"


@pytest.mark.slow
def test_coverage_through_slam_mesh_of_the_localised_scene(localised):
    import holodata
    from holodata.evaluate.slam_accuracy import evaluate_slam

    url, res, r = localised
    sc = holodata.open_dataset(url).scene("c")
    a = evaluate_slam(r.trajectory(), (np.asarray(sc["mesh/vertices"][...]), np.asarray(sc["mesh/faces"][...])),
                      res.truth_dir)
    c = a["coverage"]
    assert c["coverage"] > 0.9 and c["grid"] == [8, 32] and c["max_bounces"] == 3
    assert c["nlos_per_frame_true"] > 0 and c["coverage_nlos"] > 0.8


def test_cli_bad_map_scene_one_line_exit_1(localised, tmp_path):
    url = localised[0]
    r = CliRunner().invoke(cli, ["slam", url, "--scene", "c", "--map-scene", "nope"], obj={})
    assert r.exit_code == 1 and "nope" in r.output and r.output.strip().count("\n") == 0
    r = CliRunner().invoke(cli, ["slam", url, "--scene", "c", "--map-scene", "c"], obj={})
    assert r.exit_code == 1 and r.output.strip().count("\n") == 0
    r = CliRunner().invoke(cli, ["slam", url, "--map-scene", "c_map"], obj={})
    assert r.exit_code == 2                                          # usage: needs --scene
    from holodata.dataset import create_dataset

    w = create_dataset(str(tmp_path / "d.zarr"))
    for sid in ("s", "radar_only"):
        sc = w.scene(sid, n_frames=2)
        a = sc.frame_array("time/timestamp_ns", dtype="int64", dims=["frame"], units="ns", fill_value=0)
        a.write_shard(0, np.array([1, 2], np.int64))
    r = CliRunner().invoke(cli, ["slam", str(tmp_path / "d.zarr"), "--scene", "s", "--map-scene", "radar_only"], obj={})
    assert r.exit_code == 1 and "radar_only" in r.output and "LiDAR" in r.output
    assert r.output.strip().count("\n") == 0


def open_dataset_attrs(url, sid):
    import holodata

    return holodata.open_dataset(url).scene(sid).attrs["slam"]


def _box_room(half=(2.0, 1.5, 1.0)):
    """A closed box room centred at the origin, faces facing inwards; returns vertices, faces, face_side
    (0..5: -x, +x, -y, +y, -z, +z)."""
    hx, hy, hz = half
    V = np.array([[x, y, z] for z in (-hz, hz) for y in (-hy, hy) for x in (-hx, hx)], float)
    quads = {0: [0, 2, 6, 4], 1: [1, 5, 7, 3], 2: [0, 4, 5, 1], 3: [2, 3, 7, 6], 4: [0, 1, 3, 2], 5: [4, 6, 7, 5]}
    F, side = [], []
    for k, (a, b, c, d) in quads.items():
        F += [[a, c, b], [a, d, c]]
        side += [k, k]
    return V, np.array(F), np.array(side)


def test_coverage_analytic_missing_wall():
    V, F, side = _box_room()
    grid = Grid(16, 64)
    pose = np.eye(4)[None]
    # one bounce: the beam from the centre ends on the face where its direction leaves the box first
    d = grid.directions().reshape(-1, 3)
    t = np.min(np.where(np.abs(d) > 1e-12, np.array([2.0, 1.5, 1.0]) / np.maximum(np.abs(d), 1e-12), np.inf), axis=1)
    p = d * t[:, None]

    def uncovered(q):   # on the +x wall, farther than tau = 5 cm from the walls the estimate keeps
        return np.isclose(q[:, 0], 2.0, atol=1e-4) & (1.5 - np.abs(q[:, 1]) > 0.05) & (1.0 - np.abs(q[:, 2]) > 0.05)

    on_px = uncovered(p)
    keep = side != 1                                          # the estimate lacks the +x wall
    c1 = mesh_coverage(V, F[keep], V, F, pose, grid, trace=RadarTrace(max_bounces=1, max_range=9.6))
    assert c1["coverage"] == pytest.approx(1.0 - on_px.mean(), abs=1e-9)
    assert c1["n_points"] == len(d)
    full = mesh_coverage(V, F, V, F, pose, grid, trace=RadarTrace(max_bounces=3, max_range=9.6))
    assert full["coverage"] == 1.0
    assert full["nlos_per_frame_true"] == full["nlos_per_frame_est"] == 0   # a convex room: every bounce is LOS
    assert np.isnan(full["coverage_nlos"])
    c3 = mesh_coverage(V, F[keep], V, F, pose, grid, trace=RadarTrace(max_bounces=3, max_range=9.6))
    reach = radar_reach(V, F, pose, grid, 3, 9.6)
    assert c3["coverage"] == pytest.approx(1.0 - uncovered(reach["points"]).mean(), abs=1e-6)
    assert c3["n_points"] > 2 * len(d)                   # the second and third bounces count too
    assert c3["coverage_bounce"][1] == pytest.approx(c1["coverage"], abs=1e-9)
    # a mesh 10 cm off its wall is outside tau = 5 cm; 3 cm off is inside
    for shift, covered in ((0.10, False), (0.03, True)):
        V2 = V.copy()
        V2[V2[:, 0] > 0, 0] += shift
        c = mesh_coverage(V2, F, V, F, pose, grid, trace=RadarTrace(max_bounces=1, max_range=9.6))
        assert c["coverage"] == pytest.approx(1.0 if covered else 1.0 - on_px.mean(), abs=1e-9)
