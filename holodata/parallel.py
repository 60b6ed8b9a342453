"""Work beside the caller in a forked process (Linux): the mapping stages use it to keep both cores
of a small machine busy without pickling their inputs (a forked child sees the caller's arrays).

Rules for what runs in the child: no OpenMP (open3d) — a process forked from one that ran OpenMP
threads can hang in it; numpy, scipy and zarr are fine (zarr and c-blosc reset their threads after a
fork). Results come back pickled through a pipe, so keep them to arrays and plain data.
"""
from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from .errors import HolodataError


class WorkerError(HolodataError, RuntimeError):
    """A forked worker process died (killed by a signal or the OOM killer)."""


def cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def can_fork() -> bool:
    return sys.platform.startswith("linux")


def release_free_memory() -> None:
    """Collect garbage and hand the C heap's free pages back to the OS (glibc ``malloc_trim``; only
    the garbage collection elsewhere). The mapping stages call it where they start, before they fork:
    a stage run after others in one process (``holodata demo``, the benchmarks) otherwise forks
    children that share the heap the earlier stages left behind, and copies it page by page as it
    writes there again (register right after slam in one process: benchmarks/results/pipeline.md,
    docs/design/performance.md)."""
    import gc

    gc.collect()
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL("libc.so.6").malloc_trim(0)
        except (OSError, AttributeError):   # not glibc (musl has no malloc_trim)
            pass


@contextmanager
def kernel_threads(n: int | None) -> Iterator[None]:
    """numba's parallel kernels (``prange``) on ``n`` threads of the calling thread within the block
    (None: as they are). Two processes that each run a kernel on every CPU's thread oversubscribe a
    small machine: two of the quick demo's corners synthesised side by side took 18.2 s each with two
    threads per process and 14.4 s with one (docs/design/performance.md)."""
    if n is None:
        yield
        return
    import numba

    prev = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(prev)


# glibc's allocator settings for holodata's processes (:func:`keep_freed_memory`): blocks up to 32 MiB
# (glibc's largest mmap threshold) come from the heap, and up to 128 MiB of freed heap stays mapped
ALLOCATOR_ENV = {"MALLOC_MMAP_THRESHOLD_": str(32 << 20), "MALLOC_TRIM_THRESHOLD_": str(128 << 20)}


def keep_freed_memory() -> bool:
    """Let glibc keep freed memory for the next allocation instead of handing it back to the OS at
    once. Numpy's temporaries of a few MB (a (256, 1024) float64 product is 2 MB) are otherwise
    mapped and unmapped by each operation, and every page of them faults in anew: ``(n @ X.T) - d``
    on such arrays took 2.7 ms with glibc's defaults and 0.9 ms with these settings, on this
    project's 2-core machine (docs/design/performance.md). Sets the settings for this process
    (``mallopt``) and, through :data:`ALLOCATOR_ENV` (unless the caller set those variables), for
    the processes it starts; the CLI calls it first. Memory a stage frees stays with the process up
    to 128 MiB (:func:`release_free_memory` still hands it back before a fork). Returns whether the
    allocator took them (False off glibc)."""
    if not sys.platform.startswith("linux"):
        return False
    for k, v in ALLOCATOR_ENV.items():
        os.environ.setdefault(k, v)
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3     # glibc's malloc.h
        return bool(libc.mallopt(m_mmap_threshold, int(os.environ["MALLOC_MMAP_THRESHOLD_"]))
                    and libc.mallopt(m_trim_threshold, int(os.environ["MALLOC_TRIM_THRESHOLD_"])))
    except (OSError, AttributeError, ValueError):   # not glibc, or a caller's setting that is no number
        return False


def _recv_or_died(pipe, proc, poll_s: float = 0.2):
    """``pipe.recv()``, or EOFError as soon as ``proc`` has ended without sending. The process is
    polled (``waitpid``) beside the pipe: a child killed while processes it forked still run would
    otherwise go unnoticed, as they inherited the pipe's write end (and the process sentinel's) and
    keep both open until they finish."""
    while True:
        if pipe.poll(poll_s):
            return pipe.recv()      # data (or EOF) is there: a child that sent and exited is not an error
        if proc.exitcode is not None:
            if pipe.poll(0.05):     # sent right before it ended
                return pipe.recv()
            raise EOFError(f"worker ended with exit code {proc.exitcode}")


class Forked:
    """A call started by :func:`fork_call`: ``forked()`` waits for its result (re-raising the call's
    exception); ``forked.early()`` for the value the call handed to its ``early`` callback before
    it finished (calls started with ``early=True``)."""

    def __init__(self, label: str, proc=None, recv=None, recv_early=None, value=None):
        self.label, self._proc = label, proc
        self._pipes = {"result": recv, "early": recv_early}
        self._got = {} if proc is not None else value

    def _no_early(self):
        """The call ended without handing over its early value: its own error, else this one."""
        self()
        raise HolodataError(f"{self.label}: finished without its early result") from None

    def _get(self, which: str):
        if which not in self._got:
            if self._proc is None:        # ran in this process: only an early value can be missing
                self._no_early()
            pipe = self._pipes[which]
            try:
                self._got[which] = _recv_or_died(pipe, self._proc)
            except EOFError as err:
                if which == "early":
                    self._no_early()
                self._proc.join()
                raise WorkerError(f"{self.label}: its worker process died (exit code {self._proc.exitcode}: killed "
                                  f"by a signal or out of memory); rerun, or use --processes 1") from err
            finally:
                pipe.close()
            if which == "result":
                self._proc.join()
        ok, val = self._got[which]
        if not ok:
            raise val
        return val

    def __call__(self):
        return self._get("result")

    def join(self) -> None:
        """Wait for the process to end, without its result or error (cleaning up after a failure)."""
        if self._proc is not None:
            self._proc.join()

    def early(self):
        return self._get("early")


def fork_call(fn: Callable, *args, label: str = "", enabled: bool = True, early: bool = False) -> Forked:
    """Start ``fn(*args)`` in a forked process; returns a :class:`Forked` to wait for its result.
    With ``early`` the call also gets ``early=callback``: what it passes to the callback (once) can be
    had with ``Forked.early()`` while it goes on. With ``enabled`` False or where fork is not
    available the call runs right away, in this process. A child that dies without a result raises
    :class:`WorkerError` naming ``label``."""
    label = label or fn.__name__
    kwargs = {}
    if not (enabled and can_fork()):
        box = {}
        if early:
            kwargs["early"] = lambda v: box.setdefault("early", (True, v))
        try:
            box["result"] = (True, fn(*args, **kwargs))
        except Exception as err:  # noqa: BLE001 - raised where the result is asked for, as from a process
            box["result"] = (False, err)
        return Forked(label, value=box)
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    recv_early, send_early = ctx.Pipe(duplex=False) if early else (None, None)

    def run():
        recv.close()
        if early:
            recv_early.close()
            kwargs["early"] = lambda v: send_early.send((True, v))
        try:
            out = (True, fn(*args, **kwargs))
        except BaseException as err:  # noqa: BLE001 - handed to the parent, which raises it
            out = (False, err)
        if early:
            send_early.close()
        try:
            send.send(out)
        except Exception as err:  # noqa: BLE001 - an unpicklable result or exception
            send.send((False, HolodataError(f"{label}: {type(err).__name__}: {err}")))
        send.close()

    proc = ctx.Process(target=run)   # not a daemon: it may fork workers of its own
    proc.start()
    send.close()
    if early:
        send_early.close()
    return Forked(label, proc, recv, recv_early)


__all__ = ["WorkerError", "Forked", "fork_call", "cpus", "can_fork", "release_free_memory", "keep_freed_memory", "kernel_threads",
           "ALLOCATOR_ENV"]
