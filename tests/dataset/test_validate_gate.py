"""``holodata validate`` as a CI gate (issue 50 points 5 and 7).

Point 7: a scene must hold what it declares (``layout.required_arrays``: radar, GT, LiDAR, camera,
human, mesh, poses), the dtype of ragged values is checked, and the zarr.json fields that change
decoded values (codecs, fill_value, chunk grid, dtype; the root's grid and range bins) are covered
by a digest recorded beside the shard checksums. Point 5: sizes the metadata declares are capped
against what the store holds before anything is allocated (each test runs validate in a process
limited to 1.5 GB of address space). Every problem is one line. Local folders here; the same checks
on S3 (moto) at the end.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from holodata.conventions import Grid, RangeBins
from holodata.dataset import create_dataset
from holodata.dataset import shards as sh
from holodata.dataset.layout import (
    CALIB_T_WORLD_CAMERA,
    CAMERA_POINTS,
    CAMERA_TIMESTAMP_NS,
    DECLARATIONS,
    GT_ARRAYS,
    GT_HUMAN_CENTER,
    GT_RANGE,
    GT_SEMANTIC,
    HUMAN_FACES,
    HUMAN_POINTS,
    HUMAN_VERTICES,
    LAYOUT,
    LIDAR_POINTS,
    LIDAR_TIMESTAMP_NS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_LIDAR,
    POSE_T_WORLD_RADAR,
    RADAR_CYCLE_NS,
    RADAR_HEATMAP,
    TIME_TIMESTAMP_NS,
    required_arrays,
)
from holodata.dataset.store import Store
from holodata.dataset.synthetic import array_specs, toy_frames
from holodata.dataset.validate import validate_dataset

T, S, NR = 8, 4, 8
GRID = Grid(4, 8)
DECLARED = {   # what ingest (sensors), slam, register and raytrace-gt record in the scene attributes
    "frame_sensor": "radar", "sensors": {"radar": {"topic": "/radar"}, "lidar": {"topic": "/ouster/points"},
                                         "camera": {"topic": "/camera/depth"}},
    "slam": {"complete": True, "fingerprint": "f0", "mesh_config": {"voxel_m": 0.05}}, "register": {"humans": 1},
    "gt": {"backend": "open3d", "max_bounces": 3},
}


def write_declared(url: str) -> str:
    """One scene ``c1`` holding every array its attributes declare (the writer API, small sizes)."""
    w = create_dataset(url, grid=GRID, range_bins=RangeBins(NR, 9.6 / NR), created_by="test", shard_frames=S)
    sc = w.scene("c1", n_frames=T, attrs=DECLARED)
    rng = np.random.default_rng(0)
    data = toy_frames(rng, range(T), GRID, n_range=NR)
    ts = data[TIME_TIMESTAMP_NS]
    data.update({RADAR_CYCLE_NS: np.stack([ts - 10**8, ts + 10**8], axis=1), POSE_T_WORLD_LIDAR: data[POSE_T_WORLD_RADAR],
                 LIDAR_TIMESTAMP_NS: ts, CAMERA_TIMESTAMP_NS: ts,
                 GT_SEMANTIC: np.zeros((T, 3, GRID.H, GRID.W), np.uint8),
                 GT_HUMAN_CENTER: np.full((T, 1, 3), np.nan, np.float32)})
    specs = {**array_specs(GRID, NR), RADAR_CYCLE_NS: dict(per_frame_shape=(2,)),
             POSE_T_WORLD_LIDAR: dict(per_frame_shape=(4, 4)), LIDAR_TIMESTAMP_NS: dict(per_frame_shape=()),
             CAMERA_TIMESTAMP_NS: dict(per_frame_shape=()), GT_SEMANTIC: dict(per_frame_shape=(3, GRID.H, GRID.W)),
             GT_HUMAN_CENTER: dict(per_frame_shape=(1, 3))}
    for name, spec in specs.items():
        a = sc.frame_array(name, **spec)
        for k in range(a.n_shards):
            a.write_shard(k, data[name][a.frames(k)])
    for name, dt in ((LIDAR_POINTS, np.float32), (CAMERA_POINTS, np.float32), (HUMAN_VERTICES, np.float32),
                     (HUMAN_FACES, np.int32), (HUMAN_POINTS, np.float32)):
        r = sc.ragged_array(name)
        for k in range(r.n_shards):
            r.write_shard(k, [(rng.random((int(rng.integers(1, 30)), 3)) * 4).astype(dt) for _ in range(S)])
    sc.write_array(MESH_VERTICES, rng.uniform(-5, 5, (12, 3)))
    sc.write_array(MESH_FACES, rng.integers(0, 12, (20, 3)))
    sc.write_array(CALIB_T_WORLD_CAMERA, np.eye(4))
    return url


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    return write_declared(str(tmp_path_factory.mktemp("gate") / "ds.zarr"))


@pytest.fixture
def ds(pristine, tmp_path):
    import shutil

    dst = tmp_path / "ds.zarr"
    shutil.copytree(pristine, dst)
    return str(dst)


def edit_json(store: Store, key: str, fn) -> None:
    d = json.loads(store.get(key))
    fn(d)
    store.put(key, json.dumps(d).encode())


def lines(rep: dict) -> list[str]:
    out = [p["line"] for p in rep["problems"]]
    assert all("\n" not in ln for ln in out), out   # every refusal is one line
    return out


def has(rep: dict, start: str, *words: str) -> bool:
    return any(ln.startswith(start) and all(w in ln for w in words) for ln in lines(rep))


def test_declared_scene_validates_and_its_inventory(ds):
    rep = validate_dataset(ds)
    assert rep["ok"], lines(rep)
    inv = required_arrays(DECLARED)
    assert set(inv) == {TIME_TIMESTAMP_NS, RADAR_HEATMAP, RADAR_CYCLE_NS, LIDAR_POINTS, LIDAR_TIMESTAMP_NS, CAMERA_POINTS,
                        CAMERA_TIMESTAMP_NS, POSE_T_WORLD_LIDAR, POSE_T_WORLD_RADAR, MESH_VERTICES, MESH_FACES,
                        HUMAN_VERTICES, HUMAN_FACES, HUMAN_POINTS, CALIB_T_WORLD_CAMERA, *GT_ARRAYS}
    assert set(required_arrays({"n_frames": 3})) == {TIME_TIMESTAMP_NS}
    # one table: every declaration the table names exists, and every declaration is used
    used = {d for s in LAYOUT.values() for d in s.required_if}
    assert used == set(DECLARATIONS)


# -- point 7: deleted arrays ---------------------------------------------------------------------------
def test_deleting_the_heatmap_and_every_gt_array_fails(ds):
    """The issue's case: presence was checked only for time/timestamp_ns and the GT core's all-or-none."""
    st = Store(ds)
    for name in (RADAR_HEATMAP, *GT_ARRAYS):
        st.delete_tree(f"scenes/c1/{name}")
    rep = validate_dataset(ds)
    assert not rep["ok"]
    assert has(rep, f"c1 {RADAR_HEATMAP}: missing", "sensors.radar")
    for name in GT_ARRAYS:
        assert has(rep, f"c1 {name}: missing", "attrs gt"), lines(rep)


@pytest.mark.parametrize("name", [RADAR_CYCLE_NS, LIDAR_POINTS, CAMERA_POINTS, LIDAR_TIMESTAMP_NS, HUMAN_VERTICES,
                                  MESH_FACES, POSE_T_WORLD_LIDAR, POSE_T_WORLD_RADAR, CALIB_T_WORLD_CAMERA])
def test_each_declared_array_is_required(ds, name):
    Store(ds).delete_tree(f"scenes/c1/{name}")
    rep = validate_dataset(ds)
    assert has(rep, f"c1 {name}: missing", "declares"), lines(rep)


# -- point 7: retyped data and metadata under the checksums ------------------------------------------
def test_ragged_values_retyped_in_zarr_json(ds):
    edit_json(Store(ds), f"scenes/c1/{LIDAR_POINTS}/values/zarr.json", lambda d: d.update(data_type="int32"))
    rep = validate_dataset(ds)
    assert has(rep, f"c1 {LIDAR_POINTS}", "int32", "float32"), lines(rep)


def _codec(d: dict, name: str) -> dict:
    """The configuration of codec ``name`` in a zarr.json (inside the sharding codec when there is one)."""
    codecs = d["codecs"]
    if codecs[0]["name"] == "sharding_indexed":
        codecs = codecs[0]["configuration"]["codecs"]
    return next(c for c in codecs if c["name"] == name).setdefault("configuration", {})


META_EDITS = {
    "fill_value": (f"scenes/c1/{RADAR_HEATMAP}/zarr.json", lambda d: d.update(fill_value=0.0), RADAR_HEATMAP),
    "shuffle": (f"scenes/c1/{GT_RANGE}/zarr.json", lambda d: _codec(d, "blosc").update(shuffle="bitshuffle"),
                GT_RANGE),
    "endian": (f"scenes/c1/{POSE_T_WORLD_RADAR}/zarr.json", lambda d: _codec(d, "bytes").update(endian="big"),
               POSE_T_WORLD_RADAR),
    "ragged_fill": (f"scenes/c1/{CAMERA_POINTS}/values/zarr.json", lambda d: d.update(fill_value=1.0), CAMERA_POINTS),
    "offsets_codec": (f"scenes/c1/{HUMAN_FACES}/offsets/zarr.json", lambda d: _codec(d, "blosc").update(clevel=9),
                      HUMAN_FACES),
}


@pytest.mark.parametrize("case", sorted(META_EDITS))
def test_value_metadata_edit_is_detected(ds, case):
    key, fn, name = META_EDITS[case]
    edit_json(Store(ds), key, fn)
    rep = validate_dataset(ds)
    assert has(rep, f"c1 {name}", "zarr.json"), lines(rep)


@pytest.mark.parametrize("field", ["elev_deg", "dr"])
def test_root_grid_edit_is_detected(ds, field):
    def edit(d):
        hd = d["attributes"]["holodata"]
        if field == "elev_deg":
            hd["grid"]["elev_deg"] = [hd["grid"]["elev_deg"][0] - 5, hd["grid"]["elev_deg"][1]]
        else:
            hd["range_bins"]["dr"] = hd["range_bins"]["dr"] * 2

    edit_json(Store(ds), "zarr.json", edit)
    rep = validate_dataset(ds)
    assert not rep["ok"] and has(rep, "(dataset)", "grid"), lines(rep)


def test_records_written_before_the_digests_still_validate(ds):
    """Datasets written before the metadata digests: their records lack them; validate passes them."""
    st = Store(ds)
    n = 0
    for sid in st.list("scenes"):
        for name in st.list(f"scenes/{sid}"):
            for sub in [name] + [f"{name}/{x}" for x in st.list(f"scenes/{sid}/{name}")]:
                mdir = f"scenes/{sid}/{sub}/{sh.MANIFEST_DIR}"
                for rec in st.list(mdir):
                    edit_json(st, f"{mdir}/{rec}", lambda d: [d.pop(k, None) for k in ("meta_sha256", "grid_sha256")])
                    n += 1
    assert n > 10
    rep = validate_dataset(ds)
    assert rep["ok"], lines(rep)


# -- point 5: sizes declared by the metadata, capped before allocating ----------------------------------
LIMIT_MB = 1500


def validate_limited(url: str) -> dict:
    """validate in a child process limited to LIMIT_MB of address space (and 60 s): declared sizes must
    not be allocated (or walked) before they are checked against the store."""
    code = ("import json, resource, sys\n"
            f"resource.setrlimit(resource.RLIMIT_AS, ({LIMIT_MB} << 20, {LIMIT_MB} << 20))\n"
            "from holodata.dataset.validate import validate_dataset\n"
            "print(json.dumps(validate_dataset(sys.argv[1])))\n")
    p = subprocess.run([sys.executable, "-c", code, url], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr[-2000:]
    rep = json.loads(p.stdout)
    assert "MemoryError" not in p.stdout
    return rep


def test_huge_n_frames_is_refused_without_a_task_per_declared_shard(ds):
    edit_json(Store(ds), "scenes/c1/zarr.json", lambda d: d["attributes"].update(n_frames=10**12))
    rep = validate_limited(ds)
    assert not rep["ok"]
    assert has(rep, f"c1 {TIME_TIMESTAMP_NS}", "n_frames"), lines(rep)


def test_huge_declared_frame_axis_counts_missing_shards(ds):
    """n_frames and an array's shape agree on 10**12 frames: the shards the store does not hold are
    counted, not walked one by one."""
    st = Store(ds)
    edit_json(st, "scenes/c1/zarr.json", lambda d: d["attributes"].update(n_frames=10**12))
    edit_json(st, f"scenes/c1/{TIME_TIMESTAMP_NS}/zarr.json", lambda d: d.update(shape=[10**12]))
    rep = validate_limited(ds)
    assert has(rep, f"c1 {TIME_TIMESTAMP_NS}", "249999999998 of 250000000000 shards not written"), lines(rep)
    assert len(rep["problems"]) < 60


def test_huge_declared_mesh_is_not_read_whole(ds):
    edit_json(Store(ds), f"scenes/c1/{MESH_VERTICES}/zarr.json", lambda d: d.update(shape=[10**10, 3]))
    rep = validate_limited(ds)
    assert has(rep, f"c1 {MESH_VERTICES}", "(12, 3)"), lines(rep)


def test_huge_declared_offsets_are_not_read_whole(ds):
    def edit(d):
        d["shape"] = [10**11]
        d["chunk_grid"]["configuration"]["chunk_shape"] = [10**11]

    st = Store(ds)
    edit_json(st, f"scenes/c1/{LIDAR_POINTS}/offsets/zarr.json", edit)
    rep = validate_limited(ds)
    assert has(rep, f"c1 {LIDAR_POINTS}", "offsets (100000000000,) int64, expected (9,) int64"), lines(rep)
    # the scene agrees (10**11 - 1 frames): the one offsets chunk's Blosc header refuses it
    edit_json(st, "scenes/c1/zarr.json", lambda d: d["attributes"].update(n_frames=10**11 - 1))
    rep = validate_limited(ds)
    assert has(rep, f"c1 {LIDAR_POINTS}", "offsets cannot be read", "zarr.json declares 100000000000 offsets"), lines(rep)


def _huge_frames(d):
    """gt/human_center (T, 1, 3) declared (T, 10**10, 3): 120 GB a frame, consistently in shape and chunks."""
    d["shape"] = [d["shape"][0], 10**10, 3]
    d["chunk_grid"]["configuration"]["chunk_shape"] = [S, 10**10, 3]
    d["codecs"][0]["configuration"]["chunk_shape"] = [1, 10**10, 3]


def test_huge_declared_frame_shape_checked_before_allocating(ds):
    """shards.decode_shard checks every chunk's Blosc header against the declared frame size before it
    allocates the frames (the declared 10**10 x 3 float32 = 120 GB a frame)."""
    st = Store(ds)
    key = f"scenes/c1/{GT_HUMAN_CENTER}/zarr.json"
    meta = json.loads(st.get(key))
    blob = st.get(sh.shard_key(f"scenes/c1/{GT_HUMAN_CENTER}", 0, 3))
    assert sh.decode_shard(meta, S, blob).shape == (S, 1, 3)
    _huge_frames(meta)
    with pytest.raises(ValueError, match="Blosc header"):
        sh.decode_shard(meta, S, blob)
    edit_json(st, key, _huge_frames)
    rep = validate_limited(ds)
    assert has(rep, f"c1 {GT_HUMAN_CENTER}"), lines(rep)


def test_objects_larger_than_recorded_are_not_read(ds, monkeypatch):
    """A shard object or a ragged chunk larger than its record (or than its chunk can be) is refused on
    the size the store gives, before it is read."""
    import holodata.dataset.store as store_mod

    st = Store(ds)
    big = bytes(32 << 20)
    st.put(sh.shard_key(f"scenes/c1/{RADAR_HEATMAP}", 1, 4), big)
    st.put(f"scenes/c1/{LIDAR_POINTS}/values/c/0/0", big)
    read = []
    get = store_mod.Store.get
    monkeypatch.setattr(store_mod.Store, "get", lambda self, key: (read.append(key), get(self, key))[1])
    rep = validate_dataset(ds)
    assert has(rep, f"c1 {RADAR_HEATMAP} frame 4", f"{32 << 20} bytes, recorded"), lines(rep)
    assert has(rep, f"c1 {LIDAR_POINTS}", "values chunk 0 object holds", "not read"), lines(rep)
    assert sh.shard_key(f"scenes/c1/{RADAR_HEATMAP}", 1, 4) not in read
    assert f"scenes/c1/{LIDAR_POINTS}/values/c/0/0" not in read


def test_cli_gate_exit_code_and_one_line_per_problem(ds):
    from click.testing import CliRunner

    from holodata.cli.main import cli

    Store(ds).delete_tree(f"scenes/c1/{RADAR_HEATMAP}")
    r = CliRunner().invoke(cli, ["validate", ds, "--quiet"])
    assert r.exit_code == 1 and "Traceback" not in r.output
    assert any(ln.startswith(f"c1 {RADAR_HEATMAP}: missing") for ln in r.output.splitlines()), r.output


# -- the same on S3 (moto) --------------------------------------------------------------------------------
BUCKET = "holodata-gate"   # not tests/dataset/test_s3.py's: moto's buckets outlive its server in this process


@pytest.fixture(scope="module")
def s3():
    """moto's S3 server on a free port, the AWS_* environment pointing at it (as tests/dataset/test_s3.py)."""
    import os
    import socket

    import fsspec
    import s3fs
    from moto.server import ThreadedMotoServer

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    with pytest.MonkeyPatch.context() as mp:
        for k in list(os.environ):
            if k.startswith(("AWS_", "FSSPEC_S3")):
                mp.delenv(k)
        mp.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{port}")
        mp.setenv("AWS_ACCESS_KEY_ID", "testing")
        mp.setenv("AWS_SECRET_ACCESS_KEY", "testing")
        mp.setenv("AWS_DEFAULT_REGION", "us-east-1")
        s3fs.S3FileSystem.clear_instance_cache()
        fs = fsspec.filesystem("s3")
        if not fs.exists(BUCKET):
            fs.mkdir(BUCKET)
        try:
            yield
        finally:
            from holodata.dataset.store import close_filesystems

            close_filesystems()
            server.stop()


@pytest.mark.slow
def test_gate_on_s3(s3):
    url = f"s3://{BUCKET}/gate.zarr"
    write_declared(url)
    assert validate_dataset(url)["ok"]
    st = Store(url)
    for name in (RADAR_HEATMAP, *GT_ARRAYS):
        st.delete_tree(f"scenes/c1/{name}")
    edit_json(st, f"scenes/c1/{LIDAR_POINTS}/values/zarr.json", lambda d: d.update(data_type="int32"))
    edit_json(st, f"scenes/c1/{MESH_VERTICES}/zarr.json", lambda d: d.update(shape=[10**10, 3]))
    edit_json(st, f"scenes/c1/{CAMERA_POINTS}/values/zarr.json", lambda d: d.update(fill_value=1.0))
    edit_json(st, f"scenes/c1/{POSE_T_WORLD_LIDAR}/zarr.json", lambda d: _codec(d, "bytes").update(endian="big"))
    rep = validate_dataset(url)
    assert has(rep, f"c1 {RADAR_HEATMAP}: missing", "sensors.radar")
    assert has(rep, "c1 gt/range: missing", "attrs gt")
    assert has(rep, f"c1 {LIDAR_POINTS}", "int32")
    assert has(rep, f"c1 {MESH_VERTICES}", "(12, 3)")
    assert has(rep, f"c1 {CAMERA_POINTS}", "zarr.json")
    assert has(rep, f"c1 {POSE_T_WORLD_LIDAR}", "zarr.json")
    # sizes: 10**12 frames declared by the scene, and by one array too
    edit_json(st, "scenes/c1/zarr.json", lambda d: d["attributes"].update(n_frames=10**12))
    edit_json(st, f"scenes/c1/{POSE_T_WORLD_RADAR}/zarr.json", lambda d: d.update(shape=[10**12, 4, 4]))
    rep = validate_dataset(url)
    assert has(rep, f"c1 {TIME_TIMESTAMP_NS}", "n_frames")
    assert has(rep, f"c1 {POSE_T_WORLD_RADAR}", "249999999998 of 250000000000 shards not written")

