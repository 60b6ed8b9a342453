"""raytrace-gt's local tracing processes: workers, each with its own :class:`FrameTracer` (the
static scene built once per worker), trace frames into shared-memory slots, with at most as many
frames in flight as there are slots.

Two ways to use them: a pool of spawned workers while the parent only writes (:func:`_bounded_imap`,
``--processes N``), or one :class:`Helper` process beside the parent's own tracing threads
(:func:`run_with_helper`, raytrace-gt's automatic choice from ``HELPER_MIN_FRAMES`` frames on a
machine with two cores or more). Why the helper: open3d's ``cast_rays`` holds the GIL while it casts
on every core, so in one process a frame's Python between casts waits for the other frame's cast,
and its compiled per-bounce work competes with it for the cores (docs/design/raytrace.md); a second
process casts and computes beside it without sharing a GIL.
"""
from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from ..parallel import cpus
from .backends import open3d_has_cast
from .frames import FrameTracer, GTConfig, gt_array_specs

_WORKER: dict = {}


def _slot_views(buf, specs: dict) -> dict:
    """Numpy views of one frame's gt arrays laid out back to back in ``buf``."""
    out, off = {}, 0
    for name, spec in specs.items():
        shape, dt = tuple(spec["per_frame_shape"]), np.dtype(spec["dtype"])
        n = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        out[name] = np.ndarray(shape, dtype=dt, buffer=buf, offset=off)
        off += (n + 63) // 64 * 64
    return out


def _slot_bytes(specs: dict) -> int:
    return sum((int(np.prod(s["per_frame_shape"], dtype=np.int64)) * np.dtype(s["dtype"]).itemsize + 63) // 64 * 64
               for s in specs.values())


def _worker_init(mesh, cfg, traj, human, shm_name, n_slots, cycles=None) -> None:
    from multiprocessing import shared_memory

    specs = gt_array_specs(cfg.grid, cfg.max_bounces)
    shm = shared_memory.SharedMemory(name=shm_name)
    size, buf = _slot_bytes(specs), shm.buf
    assert buf is not None   # an open block always has its buffer
    _WORKER.update(tracer=FrameTracer(mesh, cfg, traj, human, cycles), shm=shm,
                   slots=[_slot_views(buf[i * size:(i + 1) * size], specs) for i in range(n_slots)])


def _worker_frame(f: int, slot: int) -> int:
    """Trace frame ``f`` into shared-memory slot ``slot`` (results do not travel through pipes)."""
    out = _WORKER["tracer"](f)
    for name, view in _WORKER["slots"][slot].items():
        view[...] = out[name]
    return slot


def _helper_init(*args) -> None:
    """:func:`_worker_init` for a :class:`Helper`: an error is kept for :func:`_worker_ready` to raise
    as its task's error (the parent then traces alone), not logged by the pool as a traceback. Ctrl-C
    is the parent's to handle (it stops the helper after its frame), not a traceback from here."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        _worker_init(*args)
    except BaseException as err:  # noqa: BLE001 - handed to the parent by _worker_ready
        _WORKER["error"] = err


def _worker_ready() -> int:
    """A no-op task: it runs once the worker's initializer (its FrameTracer) has, and raises its error."""
    if "error" in _WORKER:
        raise _WORKER["error"]
    return os.getpid()


def _bounded_imap(pool, frames: list, slots: list):
    """Ordered per-frame results (views into shared-memory ``slots``, valid until the next item)
    with at most ``len(slots)`` frames in flight; ``pool`` a ``ProcessPoolExecutor`` whose workers ran
    :func:`_worker_init`."""
    from collections import deque

    pending: deque = deque()
    free = list(range(len(slots)))
    it = iter(frames)

    def submit():
        f = next(it, None)
        if f is not None:
            slot = free.pop()
            pending.append(pool.submit(_worker_frame, f, slot))
        return f is not None

    while free and submit():
        pass
    while pending:
        slot = pending.popleft().result()
        yield slots[slot]
        free.append(slot)
        submit()


def can_fork(backend: str) -> bool:
    """A tracing process may be forked from this one (Linux): no Python thread but this one, open3d
    has not cast here (its first cast starts the thread pool it casts on) and no library that runs its own
    thread pool in the child's way (the full ``open3d`` package, torch) is loaded. A fork copies only
    the calling thread: a pool started before would be missing in the child, its locks in whatever
    state the fork found them (numpy's and scipy's OpenBLAS reset theirs at a fork). Forking costs the
    helper no interpreter and no imports (docs/design/raytrace.md: its start-up, forked and spawned)."""
    return (sys.platform.startswith("linux") and backend == "open3d" and not open3d_has_cast()
            and threading.active_count() == 1 and not any(m in sys.modules for m in ("open3d", "torch")))


class Helper:
    """One tracing process beside this one: it builds its own :class:`FrameTracer` (forked when
    :func:`can_fork`, else spawned) and traces the frames :func:`run_with_helper` hands it into
    ``n_slots`` shared-memory slots. Start it early (its start-up overlaps the caller's) and
    :meth:`close` it (``with``). ``mesh``, ``cfg``, ``traj``, ``human``, ``cycles``: as
    :class:`FrameTracer`'s; its ray casts use ``cfg.nthreads`` threads, default cores / 2 (the
    caller's own tracing has the rest); ``method``: "fork" or "spawn" instead of the choice of
    :func:`can_fork`."""

    def __init__(self, mesh: tuple, cfg: GTConfig, traj, human, cycles=None, n_slots: int = 2,
                 method: str | None = None):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        from multiprocessing import shared_memory

        specs = gt_array_specs(cfg.grid, cfg.max_bounces)
        size = _slot_bytes(specs)
        self.method = method or ("fork" if can_fork(cfg.backend) else "spawn")
        self.shm = shared_memory.SharedMemory(create=True, size=size * n_slots)
        buf = self.shm.buf
        assert buf is not None   # an open block always has its buffer
        self.slots = [_slot_views(buf[i * size:(i + 1) * size], specs) for i in range(n_slots)]
        wcfg = replace(cfg, nthreads=cfg.nthreads or max(1, cpus() // 2))
        try:
            self.pool = ProcessPoolExecutor(1, mp.get_context(self.method), initializer=_helper_init,
                                            initargs=(mesh, wcfg, traj, human, self.shm.name, n_slots, cycles))
            self.ready = self.pool.submit(_worker_ready)   # starts the process now
        except BaseException:
            self._free()
            raise

    def _free(self) -> None:
        self.slots = []
        self.shm.close()
        self.shm.unlink()

    def close(self) -> None:
        """Stop the process (frames not yet started are dropped) and free the slots."""
        self.pool.shutdown(wait=True, cancel_futures=True)
        self._free()

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Ordered:
    """Positions ``0..n-1`` handed to whichever tracer asks next (a local thread or a helper's
    feeder), results handed back in order; at most ``window`` positions taken and not yet yielded
    (memory stays bounded while one tracer is slow). A position given back (its helper died) is
    handed out again first."""

    def __init__(self, n: int, window: int):
        self.n, self.window = n, window
        self.next_take = self.next_out = 0
        self.again: list[int] = []
        self.done: dict = {}
        self.stop = False
        self.cond = threading.Condition()

    def take(self) -> int | None:
        with self.cond:
            while not self.stop and not self.again and self.next_take < self.n and \
                    self.next_take >= self.next_out + self.window:
                self.cond.wait()
            if self.stop:
                return None
            if self.again:
                return self.again.pop(0)
            if self.next_take >= self.n:
                return None
            self.next_take += 1
            return self.next_take - 1

    def put(self, i: int, ok: bool, value) -> None:
        with self.cond:
            self.done[i] = (ok, value)
            self.cond.notify_all()

    def give_back(self, i: int) -> None:
        with self.cond:
            self.again.append(i)
            self.again.sort()
            self.cond.notify_all()

    def results(self) -> Iterator:
        for i in range(self.n):
            with self.cond:
                while i not in self.done:
                    self.cond.wait()
                ok, value = self.done.pop(i)
                self.next_out = i + 1
                self.cond.notify_all()
            if not ok:
                raise value
            yield value

    def close(self) -> None:
        with self.cond:
            self.stop = True
            self.cond.notify_all()


def run_with_helper(tracer: FrameTracer, frames, threads: int, helper: Helper) -> Iterator[dict]:
    """Each frame's gt dict (as ``tracer(f)``), in the order of ``frames``, traced by ``threads``
    threads of this process (as :meth:`FrameTracer.run`) and by ``helper``'s process, whichever is
    free taking the next frame; the helper's results are copied out of their slot (the caller may
    keep them, e.g. for a background writer). The helper joins once its start-up is done; if its
    process dies, the frames it held are traced here. Each frame is traced by one
    :class:`FrameTracer` of the same scene and configuration, so the results are those of
    ``tracer(f)`` to the bit (tested). An error tracing frame k is raised after frames < k came out."""
    from concurrent.futures.process import BrokenProcessPool

    frames = list(frames)
    order = _Ordered(len(frames), window=2 * (threads + len(helper.slots)))

    def local() -> None:
        while (i := order.take()) is not None:
            try:
                order.put(i, True, tracer(frames[i]))
            except BaseException as err:  # noqa: BLE001 - raised in order by the consumer
                order.put(i, False, err)

    def feed(slot: int) -> None:
        try:
            helper.ready.result()
        except BaseException:  # noqa: BLE001 - it did not start (its initializer failed, it died): the
            return             # threads here trace every frame, and meet any error of the inputs themselves
        views = helper.slots[slot]
        while (i := order.take()) is not None:
            try:
                helper.pool.submit(_worker_frame, frames[i], slot).result()
            except BrokenProcessPool:
                order.give_back(i)
                return
            except BaseException as err:  # noqa: BLE001 - the frame's own error, raised in order
                order.put(i, False, err)
                continue
            order.put(i, True, {name: v.copy() for name, v in views.items()})

    workers = [threading.Thread(target=local, name=f"holodata-gt-trace-{j}", daemon=True) for j in range(threads)]
    workers += [threading.Thread(target=feed, args=(j,), name=f"holodata-gt-helper-{j}", daemon=True)
                for j in range(len(helper.slots))]
    for w in workers:
        w.start()
    try:
        yield from order.results()
    finally:
        order.close()
        for w in workers:
            w.join()
