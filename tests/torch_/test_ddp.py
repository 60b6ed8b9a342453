"""Data-parallel training (holodata.torch.ddp): two gloo CPU processes under torchrun follow the
loss curve of one process at the same global batch and seed, and only rank 0 writes."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from _paths import TESTS

torch = pytest.importorskip("torch")

from holodata.torch.ddp import Ddp, local_batches  # noqa: E402

SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
import torch
from _torch_synth import synth_frames
from holodata.torch import ArrayFrames, RunOptions, TrainConfig, fit
torch.set_num_threads(1)
hm, R, L = synth_frames(T=8, n=32, dr=0.3)
ds = ArrayFrames(hm, R, L)
cfg = TrainConfig(epochs=8, lr=3e-3, depth=3, base_channels=8, max_channels=16, blocks=1, batch_size=4,
                  range_loss="ce", crop_w=48)
fit(ds, sys.argv[1], cfg, ds.norm, in_channels=hm.shape[1], max_range=9.6, options=RunOptions(quiet=True))
"""


def test_local_batches_split_each_global_batch():
    order = list(range(10))
    one = local_batches(order, 4, Ddp())
    assert one == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9]]
    r0, r1 = (local_batches(order, 4, Ddp(rank=r, world=2)) for r in (0, 1))
    assert r0 == [[0, 2], [4, 6], [8]] and r1 == [[1, 3], [5, 7], [9]]
    # a last global batch smaller than the group is dropped on every rank (they step together)
    assert local_batches(list(range(9)), 4, Ddp(rank=1, world=2)) == [[1, 3], [5, 7]]


def _history(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_two_processes_follow_the_one_process_loss_curve(tmp_path):
    script = tmp_path / "fit.py"
    script.write_text(SCRIPT.format(tests=str(TESTS)))
    env = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK")}
    one = subprocess.run([sys.executable, str(script), str(tmp_path / "one")], env=env,
                         capture_output=True, text=True, timeout=600)
    assert one.returncode == 0, one.stderr[-2000:]
    two = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
                          str(script), str(tmp_path / "two")], env=env, capture_output=True, text=True, timeout=600)
    assert two.returncode == 0, two.stderr[-2000:]
    h1, h2 = _history(tmp_path / "one"), _history(tmp_path / "two")
    assert len(h1) == len(h2) == 8                        # one writer: no line logged twice
    assert [r["samples"] for r in h2] == [8] * 8          # every sample once per epoch, over both ranks
    l1 = [r["loss"] for r in h1]
    l2 = [r["loss"] for r in h2]
    assert l1[-1] < 0.95 * l1[0]                          # it learns
    for a, b in zip(l1, l2):
        assert abs(a - b) <= 1e-3 * abs(a), (l1, l2)
    ck = torch.load(tmp_path / "two" / "checkpoint.pt", weights_only=False)
    assert ck["meta"]["processes"] == 2 and ck["epoch"] == 8
    assert not any(k.startswith("module.") for k in ck["model_state"])   # the bare model, loadable anywhere
