"""raytrace-gt's in-process concurrency: frames traced by two threads (FrameTracer.run) and shards
written by a background thread give the arrays the sequential trace gives, in order, and errors
surface where they did."""
from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures.process import BrokenProcessPool

import numpy as np
import pytest
from _paths import TESTS
from _scenes import HUMAN, l_corridor

import holodata.dataset as hds
from holodata.conventions import Grid, Label
from holodata.errors import InputError
from holodata.groundtruth import FrameTracer, GTConfig, HumanDir, HumanFile, HumanSource, RaytraceStandalone
from holodata.meshio import Mesh, write_ply
from holodata.raytrace import RayScene
from holodata.trajectory import Trajectory, read_tum, write_tum

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
    RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", str(inputs / "ref.zarr"), **kw).run()
    real = FrameArrayWriter.write_shard

    def failing(self, k, data):
        if k == 2 and self.name == "gt/point":
            raise OSError("disk full")
        return real(self, k, data)

    monkeypatch.setattr(FrameArrayWriter, "write_shard", failing)
    out = str(inputs / "out.zarr")
    with pytest.raises(OSError, match="disk full"):
        RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", out, **kw).run()
    monkeypatch.setattr(FrameArrayWriter, "write_shard", real)
    summary = RaytraceStandalone(inputs / "scene.ply", inputs / "radar.tum", out, **kw).run()["scenes"][0]
    assert summary["shards_skipped"] == 2  # shards 0 and 1 were written before the failing one
    a, b = hds.open_dataset(str(inputs / "ref.zarr")).scene("scene"), hds.open_dataset(out).scene("scene")
    for name in ("gt/range", "gt/point", "gt/normal", "gt/label", "gt/semantic", "gt/human_center"):
        x, y = np.asarray(a[name][...]), np.asarray(b[name][...])
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name


# -- a helper process beside the threads (holodata.raytrace.pool.run_with_helper) ----------------------
class DieInChild(HumanSource):
    """No human; kills any other process that asks for a frame (as a signal or the OOM killer would
    kill a helper); slow in the process that made it, so that the helper is handed frames."""

    def __init__(self):
        self.parent = os.getpid()

    def __call__(self, k):
        if os.getpid() == self.parent:
            time.sleep(0.2)
        else:
            os.kill(os.getpid(), signal.SIGKILL)
        return None


class BadAt(HumanSource):
    def __call__(self, k):
        if k == 5:
            raise ValueError("bad human at 5")
        return None


def _helper(inputs, human, method="spawn"):
    from holodata.raytrace.pool import Helper

    v, f = l_corridor()
    return Helper((v, f, None, None), GTConfig(grid=Grid(16, 64)), read_tum(inputs / "radar.tum"), human,
                  method=method)


def test_helper_process_gives_the_sequential_frames_to_the_bit(inputs):
    from holodata.raytrace.pool import run_with_helper

    human = HumanDir(inputs / "humans", T)
    want = [_tracer(inputs, human)(f) for f in range(T)]
    order = [3, 0, 8, 1, 7, 2, 6, 4, 5]  # any order of frames comes out in that order
    with _helper(inputs, human) as helper:
        helper.ready.result()   # started: it takes part from the first frame
        got = list(run_with_helper(_tracer(inputs, human), order, 1, helper))
        by_helper = helper.pool.submit(os.getpid).result()
    assert by_helper != os.getpid()
    assert len(got) == T
    for f, g in zip(order, got):
        assert want[f].keys() == g.keys()
        for name in g:
            assert want[f][name].dtype == g[name].dtype and want[f][name].tobytes() == g[name].tobytes(), name


def test_helper_frames_error_is_raised_in_order(inputs):
    from holodata.raytrace.pool import run_with_helper

    seen = []
    with _helper(inputs, BadAt()) as helper:
        helper.ready.result()
        with pytest.raises(ValueError, match="bad human at 5"):
            for out in run_with_helper(_tracer(inputs, BadAt()), range(T), 2, helper):
                seen.append(out)
    assert len(seen) == 5  # frames 0-4 came out, in order, before the error


def test_a_killed_helper_leaves_its_frames_to_this_process(inputs):
    """The helper dies (SIGKILL) on the first frame it is handed: the frames it held are traced
    here, every frame comes out once, in order, as the sequential trace."""
    from holodata.raytrace.pool import run_with_helper

    want = [_tracer(inputs, HumanSource())(f) for f in range(T)]
    with _helper(inputs, DieInChild()) as helper:
        helper.ready.result()   # started: its feeders hand it frames 1 and 2 while frame 0 is traced here
        got = list(run_with_helper(_tracer(inputs, DieInChild()), range(T), 1, helper))
        with pytest.raises(BrokenProcessPool):   # it did die
            helper.pool.submit(os.getpid)
    assert len(got) == T
    for w, g in zip(want, got):
        for name in w:
            assert w[name].tobytes() == g[name].tobytes(), name


def test_a_helper_that_cannot_start_leaves_every_frame_here(inputs):
    from holodata.raytrace.pool import Helper, run_with_helper

    v, f = l_corridor()
    traj = read_tum(inputs / "radar.tum")
    bad = Helper((v, f[:, :2], None, None), GTConfig(grid=Grid(16, 64)), traj, HumanSource(), method="spawn")
    with bad:
        with pytest.raises(InputError, match="scene mesh"):
            bad.ready.result()   # its scene cannot be built: the error is its task's, no traceback printed
        got = list(run_with_helper(_tracer(inputs, HumanSource()), range(T), 2, bad))
    want = [_tracer(inputs, HumanSource())(f) for f in range(T)]
    assert all(w[n].tobytes() == g[n].tobytes() for w, g in zip(want, got) for n in w)


STANDALONE = '''
import json, sys
import holodata.groundtruth as gt
from holodata.conventions import Grid
gt.HELPER_MIN_FRAMES = 4
d = sys.argv[1]
s = gt.RaytraceStandalone(d + "/scene.ply", d + "/radar.tum", sys.argv[2], human_dir=d + "/humans",
                          cfg=gt.GTConfig(grid=Grid(16, 64), shard_frames=2), quiet=True,
                          processes=int(sys.argv[3])).run()
print(json.dumps(s["scenes"][0]))
'''


def test_standalone_forks_a_helper_and_writes_the_in_process_arrays(inputs):
    """A fresh process running raytrace_standalone (as the command does) forks its helper before it
    casts, and writes every gt array as ``processes=1`` (threads only) does."""
    import json
    import subprocess
    import sys

    script = inputs / "standalone.py"
    script.write_text(STANDALONE)
    runs = {}
    for name, processes in (("threads", 1), ("helper", 0)):
        r = subprocess.run([sys.executable, str(script), str(inputs), str(inputs / f"{name}.zarr"), str(processes)],
                           capture_output=True, text=True, check=True)
        runs[name] = json.loads(r.stdout.strip().splitlines()[-1])
        assert r.stderr == ""
    assert runs["threads"]["helper"] is None and runs["threads"]["processes"] == 1
    assert runs["helper"]["helper"] == "fork" and runs["helper"]["processes"] == 2
    a, b = (hds.open_dataset(str(inputs / f"{n}.zarr")).scene("scene") for n in ("threads", "helper"))
    for name in ("gt/range", "gt/point", "gt/normal", "gt/label", "gt/semantic", "gt/human_center"):
        x, y = np.asarray(a[name][...]), np.asarray(b[name][...])
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name


def test_no_fork_once_open3d_has_cast():
    import subprocess
    import sys

    code = ("from holodata.raytrace.pool import can_fork\n"
            "from holodata.raytrace import RayScene\n"
            "import numpy as np\n"
            "from _scenes import l_corridor\n"
            "a = can_fork('open3d')\n"
            "RayScene(*l_corridor()).trace(np.zeros((4, 3)), np.tile([1.0, 0, 0], (4, 1)))\n"
            "print(a, can_fork('open3d'), can_fork('embreex'))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                       cwd=TESTS)
    assert r.stdout.split() == ["True", "False", "False"]


def test_auto_helper_frame_counts(monkeypatch):
    import holodata.groundtruth as gt

    monkeypatch.setattr(gt, "cpus", lambda: 2)
    monkeypatch.setattr(gt, "can_fork", lambda backend: True)
    assert [gt.auto_helper(n) for n in (gt.HELPER_MIN_FRAMES - 1, gt.HELPER_MIN_FRAMES, gt.POOL_MIN_FRAMES - 1,
                                         gt.POOL_MIN_FRAMES)] == [False, True, True, False]
    assert not gt.auto_helper(500, processes=1) and not gt.auto_helper(500, processes=2)
    monkeypatch.setattr(gt, "can_fork", lambda backend: False)   # spawned: it has to earn an interpreter back
    assert [gt.auto_helper(n) for n in (gt.HELPER_SPAWN_MIN_FRAMES - 1, gt.HELPER_SPAWN_MIN_FRAMES)] == [False, True]
    monkeypatch.setattr(gt, "cpus", lambda: 1)
    assert not gt.auto_helper(gt.HELPER_SPAWN_MIN_FRAMES)
