"""raytrace-gt's in-process concurrency: frames traced by two threads (FrameTracer.run) and shards
written by a background thread give the arrays the sequential trace gives, in order, and errors
surface where they did."""
from __future__ import annotations

import threading

import numpy as np
import pytest

import holodata.dataset as hds
from holodata.conventions import Grid, Label
from holodata.groundtruth import FrameTracer, GTConfig, HumanDir, HumanFile, HumanSource, raytrace_standalone
from holodata.meshio import Mesh, write_ply
from holodata.raytrace import RayScene
from holodata.trajectory import Trajectory, read_tum, write_tum

from test_raytrace import HUMAN, l_corridor

T = 9


@pytest.fixture
def inputs(tmp_path):
    v, f = l_corridor()
    write_ply(tmp_path / "scene.ply", Mesh(v, f))
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, 0, 3], poses[:, 1, 3] = np.linspace(5.0, 7.5, T), 1.0
    yaw = np.linspace(0.0, 0.8, T)  # turning towards corridor B, where the human walks
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    write_tum(tmp_path / "radar.tum", Trajectory(np.arange(T) * 500_000_000 + 10**9, poses))
    (tmp_path / "humans").mkdir()
    for k in range(T):
        write_ply(tmp_path / "humans" / f"{k:06d}.ply", Mesh(HUMAN[0] + [0, 0.1 * k, 0], HUMAN[1]))
    return tmp_path


def _tracer(inputs, human):
    v, f = l_corridor()
    return FrameTracer((v, f, None, None), GTConfig(grid=Grid(16, 64)), read_tum(inputs / "radar.tum"), human)


@pytest.mark.parametrize("kind", ["dir", "file", "none"])
def test_two_threads_give_the_sequential_frames_to_the_bit(inputs, kind):
    human = {"dir": lambda: HumanDir(inputs / "humans", T), "file": lambda: HumanFile(inputs / "humans" / "000003.ply"),
             "none": HumanSource}[kind]()
    want = [_tracer(inputs, human)(f) for f in range(T)]
    got = list(_tracer(inputs, human).run(range(T), threads=2))
    assert len(got) == T
    human_hits = sum(int(np.isin(w["gt/label"], [Label.LOS_HUMAN, Label.NLOS_HUMAN]).sum()) for w in want)
    assert (human_hits > 0) == (kind != "none")  # the human is hit: more is compared than the static scene
    for w, g in zip(want, got):
        assert w.keys() == g.keys()
        for name in w:
            assert w[name].dtype == g[name].dtype and w[name].tobytes() == g[name].tobytes(), name


def test_run_raises_a_frames_error_in_order(inputs):
    class BadAt(HumanSource):
        def __call__(self, k):
            if k == 5:
                raise ValueError("bad human at 5")
            return None

    seen = []
    with pytest.raises(ValueError, match="bad human at 5"):
        for out in _tracer(inputs, BadAt()).run(range(T), threads=2):
            seen.append(out)
    assert len(seen) == 5  # frames 0-4 came out, in order, before the error


def test_workspace_is_per_thread():
    sc = RayScene(*l_corridor())
    bufs = {}
    both = threading.Barrier(2)

    def grab(name):
        bufs[name] = sc._workspace(100)
        if name != "main":
            both.wait()  # both threads alive at once: distinct thread ids

    ts = [threading.Thread(target=grab, args=(i,)) for i in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    grab("main")
    assert len({b.__array_interface__["data"][0] for b in bufs.values()}) == 3


def test_background_writer_error_surfaces_and_the_rerun_completes(inputs, monkeypatch):
    from holodata.dataset.writer import FrameArrayWriter

    cfg = GTConfig(grid=Grid(8, 32), shard_frames=2)
    kw = dict(human_dir=inputs / "humans", cfg=cfg, processes=1)
    raytrace_standalone(inputs / "scene.ply", inputs / "radar.tum", str(inputs / "ref.zarr"), **kw)
    real = FrameArrayWriter.write_shard

    def failing(self, k, data):
        if k == 2 and self.name == "gt/point":
            raise OSError("disk full")
        return real(self, k, data)

    monkeypatch.setattr(FrameArrayWriter, "write_shard", failing)
    out = str(inputs / "out.zarr")
    with pytest.raises(OSError, match="disk full"):
        raytrace_standalone(inputs / "scene.ply", inputs / "radar.tum", out, **kw)
    monkeypatch.setattr(FrameArrayWriter, "write_shard", real)
    summary = raytrace_standalone(inputs / "scene.ply", inputs / "radar.tum", out, **kw)["scenes"][0]
    assert summary["shards_skipped"] == 2  # shards 0 and 1 were written before the failing one
    a, b = hds.open_dataset(str(inputs / "ref.zarr")).scene("scene"), hds.open_dataset(out).scene("scene")
    for name in ("gt/range", "gt/point", "gt/normal", "gt/label", "gt/semantic", "gt/human_center"):
        x, y = np.asarray(a[name][...]), np.asarray(b[name][...])
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
