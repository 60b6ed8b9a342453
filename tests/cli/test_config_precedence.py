"""``holodata raytrace-gt|slam|register``: the stage settings a run gets from its flags and ``--config``
file. Every such flag defaults to None ("not given"): a flag given wins over the file, which wins
over the config dataclass's default (the one place of the number), for (no flags), (flags only),
(file only) and (file + flags). The stages themselves are replaced by stubs that record the config."""
from __future__ import annotations

import pytest
from click.testing import CliRunner

from holodata.beams import OriginModel
from holodata.cli.main import cli
from holodata.conventions import Grid
from holodata.groundtruth import GTConfig
from holodata.mapping.mesh import MeshConfig
from holodata.mapping.register.config import RegisterConfig
from holodata.mapping.slam.config import SlamConfig

COMBOS = ("defaults", "flags", "file", "file+flags")


def _run(args: list[str]) -> None:
    r = CliRunner().invoke(cli, args)
    if r.exit_code == 1 and "extra" in r.output:
        pytest.skip(r.output.strip())
    assert r.exit_code == 0, r.output


def _file(tmp_path, text: str, combo: str) -> list[str]:
    if "file" not in combo:
        return []
    f = tmp_path / "stages.yaml"
    f.write_text(text)
    return ["--config", str(f)]


@pytest.fixture
def gt_seen(monkeypatch):
    import holodata.groundtruth as gt

    seen = {}

    def fake(url, scenes, cfg, **_kw):
        seen["cfg"] = cfg
        return {"out": url, "scenes": []}

    monkeypatch.setattr(gt, "raytrace_dataset", fake)
    return seen


@pytest.mark.parametrize("combo", COMBOS)
def test_raytrace_gt_flag_over_file_over_dataclass(tmp_path, gt_seen, combo):
    args = ["raytrace-gt", str(tmp_path / "ds.zarr"), "--json"]
    args += _file(tmp_path, "gt: {max_bounces: 2, max_range: 8.0, grid: 16x64, codec: zstd, nthreads: 3}\n", combo)
    if "flags" in combo:
        args += ["--max-bounces", "4", "--grid", "8x32", "--backend", "open3d", "--threads", "5"]
    _run(args)
    cfg, d = gt_seen["cfg"], GTConfig()
    expect = {"defaults": d,
              "flags": GTConfig(grid=Grid(8, 32), max_bounces=4, nthreads=5),
              "file": GTConfig(grid=Grid(16, 64), max_bounces=2, max_range=8.0, codec="zstd", nthreads=3),
              "file+flags": GTConfig(grid=Grid(8, 32), max_bounces=4, max_range=8.0, codec="zstd", nthreads=5)}[combo]
    assert cfg == expect


def test_raytrace_gt_grid_and_origin_flags_change_only_their_part_of_the_file(tmp_path, gt_seen):
    f = tmp_path / "stages.yaml"
    f.write_text("gt:\n  grid: 16x64\n  origin: {type: rotation_circle, rotation_radius_m: 0.1, column_time: false}\n")
    _run(["raytrace-gt", str(tmp_path / "ds.zarr"), "--json", "--config", str(f), "--elevation-fov", "-30,20",
          "--rotation-hz", "4"])
    assert gt_seen["cfg"].grid == Grid(16, 64, 20.0, -30.0)
    assert gt_seen["cfg"].origin == OriginModel(0.1, False, 4.0)
    _run(["raytrace-gt", str(tmp_path / "ds.zarr"), "--json", "--rotation-radius", "0.2"])   # no file: the defaults
    assert gt_seen["cfg"].origin == OriginModel(0.2, OriginModel().column_time, OriginModel().rotation_hz)
    assert gt_seen["cfg"].grid == Grid()


@pytest.mark.parametrize("combo", COMBOS)
def test_slam_flag_over_file_over_dataclass(tmp_path, monkeypatch, combo):
    import holodata.mapping.slam as slam

    seen = {}

    def fake(url, scenes, config, mesh_config, **_kw):
        seen.update(cfg=config, mcfg=mesh_config)
        return []

    monkeypatch.setattr(slam, "slam_dataset", fake)
    args = ["slam", str(tmp_path / "ds.zarr"), "--json"]
    args += _file(tmp_path, "slam: {voxel: 0.3, max_range: 40.0, global_pass: true, refine: true, min_range: 0.5}\n"
                            "mesh: {method: bpa, voxel: 0.05}\n", combo)
    if "flags" in combo:
        args += ["--voxel", "0.2", "--no-refine", "--no-mesh", "--mesh-voxel", "0.03"]
    _run(args)
    s, m = {"defaults": (SlamConfig(), MeshConfig()),
            "flags": (SlamConfig(voxel=0.2, refine=False, mesh=False), MeshConfig(voxel=0.03)),
            "file": (SlamConfig(voxel=0.3, max_range=40.0, global_pass=True, min_range=0.5),
                     MeshConfig(method="bpa", voxel=0.05)),
            "file+flags": (SlamConfig(voxel=0.2, max_range=40.0, global_pass=True, min_range=0.5, refine=False,
                                      mesh=False), MeshConfig(method="bpa", voxel=0.03))}[combo]
    assert (seen["cfg"], seen["mcfg"]) == (s, m)


@pytest.mark.parametrize("combo", COMBOS)
def test_register_flag_over_file_over_dataclass(tmp_path, monkeypatch, combo):
    import holodata.mapping.register as register

    seen = {}

    def fake(url, sid, init=None, cfg=None, **_kw):
        seen["cfg"] = cfg
        return {"scene": sid}

    monkeypatch.setattr(register, "register_scene", fake)
    args = ["register", str(tmp_path / "ds.zarr"), "--scene", "c1", "--json", "--quiet"]
    args += _file(tmp_path, "register: {guess_std_m: 0.1, processes: 2, write_camera_world: true, "
                            "max_rmse_m: 0.04}\n", combo)
    if "flags" in combo:
        args += ["--guess-std", "3", "--no-segment", "--no-camera-world"]
    _run(args)
    expect = {"defaults": RegisterConfig(),
              "flags": RegisterConfig(guess_std_m=0.03, segment_lidar=False),
              "file": RegisterConfig(guess_std_m=0.1, processes=2, write_camera_world=True, max_rmse_m=0.04),
              "file+flags": RegisterConfig(guess_std_m=0.03, processes=2, segment_lidar=False, max_rmse_m=0.04)}[combo]
    assert seen["cfg"] == expect
