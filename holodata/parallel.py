"""Work beside the caller in a forked process (Linux): the mapping stages use it to keep both cores
of a small machine busy without pickling their inputs (a forked child sees the caller's arrays).

Rules for what runs in the child: no OpenMP (open3d) — a process forked from one that ran OpenMP
threads can hang in it; numpy, scipy and zarr are fine (zarr and c-blosc reset their threads after a
fork). Results come back pickled through a pipe, so keep them to arrays and plain data.
"""
from __future__ import annotations

import os
import sys
from typing import Callable

from .errors import HolodataError


class WorkerError(HolodataError, RuntimeError):
    """A forked worker process died (killed by a signal or the OOM killer)."""


def cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def can_fork() -> bool:
    return sys.platform.startswith("linux")


def fork_call(fn: Callable, *args, label: str = "", enabled: bool = True) -> Callable[[], object]:
    """Start ``fn(*args)`` in a forked process and return a function that waits for its result
    (re-raising the child's exception). With ``enabled`` False or where fork is not available the
    call runs right away, in this process. A child that dies without a result raises
    :class:`WorkerError` naming ``label``."""
    if not (enabled and can_fork()):
        out = fn(*args)
        return lambda: out
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def run():
        recv.close()
        try:
            out = (True, fn(*args))
        except BaseException as err:  # noqa: BLE001 - handed to the parent, which raises it
            out = (False, err)
        try:
            send.send(out)
        except Exception as err:  # noqa: BLE001 - an unpicklable result or exception
            send.send((False, HolodataError(f"{label or fn.__name__}: {type(err).__name__}: {err}")))
        send.close()

    proc = ctx.Process(target=run)   # not a daemon: it may fork workers of its own
    proc.start()
    send.close()
    done: list = []

    def result():
        if not done:
            try:
                done.append(recv.recv())
            except EOFError:
                proc.join()
                raise WorkerError(f"{label or fn.__name__}: its worker process died (exit code {proc.exitcode}: killed "
                                  f"by a signal or out of memory); rerun, or use --processes 1") from None
            finally:
                recv.close()
            proc.join()
        ok, val = done[0]
        if not ok:
            raise val
        return val
    return result


def split_call(fn: Callable, items: list, processes: int = 2, label: str = "") -> list:
    """``fn(items)`` (a list in, a list of the same length out) with the second half of ``items`` in
    a forked process when ``processes`` > 1; results in the order of ``items``."""
    if processes <= 1 or len(items) < 2 or not can_fork():
        return list(fn(items))
    half = (len(items) + 1) // 2
    rest = fork_call(fn, items[half:], label=label)
    first = list(fn(items[:half]))
    return first + list(rest())


__all__ = ["WorkerError", "fork_call", "split_call", "cpus", "can_fork"]
