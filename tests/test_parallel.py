"""holodata.parallel: work in forked processes, and the memory handed back before forking."""
from __future__ import annotations

import contextlib
import sys

import numpy as np
import pytest


def _rss_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc_trim and /proc are Linux's")
def test_release_free_memory_hands_freed_heap_back():
    """Memory freed below a live allocation stays in the C heap (free() can only trim its top); the
    call hands it back to the OS."""
    from holodata.parallel import release_free_memory

    release_free_memory()
    chunks = [np.ones(8192) for _ in range(3000)]     # 64 KiB each (malloc'd on the heap): ~200 MB
    pin = np.ones(8192)                               # ... and one more above them, kept
    del chunks
    before = _rss_bytes()
    release_free_memory()
    after = _rss_bytes()
    assert pin.sum() == 8192
    assert before - after > 100 * 2**20, (before, after)


_KEEP = """
import sys, numpy as np
from holodata.parallel import keep_freed_memory
def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
kept = keep_freed_memory() if sys.argv[1] == "keep" else None
a = np.ones(1 << 19)                              # 4 MiB: mmap'd by glibc's defaults
before = rss()
del a
import os
print(kept, before - rss(), os.environ.get("MALLOC_TRIM_THRESHOLD_"))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_keep_freed_memory_keeps_a_freed_array_for_the_next_one():
    """With glibc's defaults a freed 4 MiB array is unmapped at once (its pages fault in anew next
    time); after keep_freed_memory it stays with the process, and the processes it starts inherit the
    setting through the environment."""
    import os
    import subprocess

    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    run = [subprocess.run([sys.executable, "-c", _KEEP, how], capture_output=True, text=True, check=True, env=env)
           .stdout.split() for how in ("default", "keep")]
    assert run[0][0] == "None" and int(run[0][1]) > 3 * 2**20 and run[0][2] == "None"
    assert run[1][0] == "True" and int(run[1][1]) < 2**20 and run[1][2] == str(128 << 20)


def test_fork_call_returns_the_result_and_raises_the_error():
    from holodata.parallel import fork_call

    a = np.arange(10.0)
    assert fork_call(np.sum, a, label="sum")() == 45.0
    with pytest.raises(ZeroDivisionError):
        fork_call(lambda: 1 / 0, label="divide")()


def _die():
    import os
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def _die_leaving_a_grandchild(pid_file):
    """Fork a long-running grandchild (it inherits the result pipe's write end), then die."""
    import os
    import time

    from holodata.parallel import fork_call

    fork_call(time.sleep, 60, label="grandchild")
    for _ in range(200):      # the grandchild is running (its pipe ends are open) before this one dies
        if len(os.listdir(f"/proc/{os.getpid()}/task")) >= 1 and _children(os.getpid()):
            break
        time.sleep(0.01)
    with open(pid_file, "w") as f:
        f.write(" ".join(map(str, _children(os.getpid()))))
    _die()


def _children(pid: int) -> list[int]:
    import os

    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(x) for x in f.read().split()]
        except FileNotFoundError:
            pass
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and /proc are Linux's")
@pytest.mark.parametrize("early", [False, True])
def test_sigkilled_worker_is_a_one_line_error_within_seconds(early):
    """A forked worker killed by SIGKILL (as by the OOM killer) raises WorkerError naming the step,
    for its result and for its early value, instead of waiting."""
    import time

    from holodata.parallel import WorkerError, fork_call

    t = time.monotonic()
    f = fork_call((lambda early: _die()) if early else _die, label="step x", early=early)
    with pytest.raises(WorkerError, match="step x: its worker process died") as e:
        f.early() if early else f()
    assert "\n" not in str(e.value) and "killed by a signal" in str(e.value)
    assert time.monotonic() - t < 10


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and /proc are Linux's")
def test_sigkilled_worker_whose_own_fork_lives_on_is_still_an_error_within_seconds(tmp_path):
    """The killed worker's own forked child still holds the result pipe open (it was forked with it):
    the parent must notice the death itself, not wait 60 s for the pipe to close."""
    import os
    import signal
    import time

    from holodata.parallel import WorkerError, fork_call

    pid_file = tmp_path / "grandchild"
    t = time.monotonic()
    try:
        with pytest.raises(WorkerError, match="nested step: its worker process died"):
            fork_call(_die_leaving_a_grandchild, str(pid_file), label="nested step")()
        assert time.monotonic() - t < 10
        assert pid_file.read_text().split(), "the worker forked no grandchild: the test proves nothing"
    finally:
        for pid in pid_file.read_text().split() if pid_file.exists() else []:
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(pid), signal.SIGKILL)


def test_kernel_threads_sets_numba_threads_within_the_block_only():
    import numba

    from holodata.parallel import kernel_threads

    before = numba.get_num_threads()
    with kernel_threads(1):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with kernel_threads(None):
        assert numba.get_num_threads() == before
