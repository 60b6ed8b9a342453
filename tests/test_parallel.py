"""holodata.parallel: work in forked processes, and the memory handed back before forking."""
from __future__ import annotations

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


def test_fork_call_returns_the_result_and_raises_the_error():
    from holodata.parallel import fork_call

    a = np.arange(10.0)
    assert fork_call(np.sum, a, label="sum")() == 45.0
    with pytest.raises(ZeroDivisionError):
        fork_call(lambda: 1 / 0, label="divide")()
