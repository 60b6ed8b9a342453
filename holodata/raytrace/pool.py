"""raytrace-gt's local process pool: spawned workers, each with its own :class:`FrameTracer` (the
static scene built once per worker), trace frames into shared-memory slots; the parent writes them,
with at most as many frames in flight as there are slots.
"""
from __future__ import annotations

import numpy as np

from .frames import FrameTracer, gt_array_specs


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
