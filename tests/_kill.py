"""A kill injected at a store write (issue 43 point 2): every mutation a dataset writer makes goes
through :class:`holodata.dataset.store.Store` (``put``, ``delete``, ``delete_tree``); :func:`killed_at`
makes the n-th of them, and every one after it (a killed process writes nothing more, whichever
thread asks), raise :class:`Killed` before it happens. Writes that bypass the Store (zarr's own store
writes) are counted, so a test can check that the sweep saw every write.

:func:`kill_sweep` runs a command once to count its writes, then once per write n = 1..N killed
there, and checks what the brief asks: the dataset left behind does not validate (the command has
not finished) and names the stage that did not finish wherever the scene exists; a rerun finishes
it into a dataset that validates and holds arrays identical to the uninterrupted run's."""
from __future__ import annotations

import shutil
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np


class Killed(BaseException):
    """The simulated SIGKILL: a BaseException, so no ``except Exception`` of the code under test
    turns it into a handled error."""


MUTATORS = ("put", "delete", "delete_tree")


@contextmanager
def killed_at(n: int | None):
    """Within the block, the ``n``-th Store mutation (1-based) and all later ones raise
    :class:`Killed` (``n`` None: nothing is killed, writes are only counted). Yields a dict
    {"writes": Store mutations asked for, "bypass": writes through zarr's LocalStore, "keys": the
    keys in order}."""
    import zarr

    from holodata.dataset.store import Store

    state = {"writes": 0, "bypass": 0, "keys": []}
    lock = threading.Lock()
    real = {m: getattr(Store, m) for m in MUTATORS}
    zreal = {m: getattr(zarr.storage.LocalStore, m) for m in ("set", "delete", "delete_dir")}

    def gate(method):
        def wrapped(self, key, *a, **k):
            with lock:
                state["writes"] += 1
                state["keys"].append((method, key))
                dead = n is not None and state["writes"] >= n
            if dead:
                raise Killed(f"killed at store write {n} ({method} {key})")
            return real[method](self, key, *a, **k)
        return wrapped

    def count(method):
        async def wrapped(self, *a, **k):
            with lock:
                state["bypass"] += 1
            return await zreal[method](self, *a, **k)
        return wrapped

    try:
        for m in MUTATORS:
            setattr(Store, m, gate(m))
        for m in zreal:
            setattr(zarr.storage.LocalStore, m, count(m))
        yield state
    finally:
        for m in MUTATORS:
            setattr(Store, m, real[m])
        for m, f in zreal.items():
            setattr(zarr.storage.LocalStore, m, f)


def arrays_of(url: str) -> dict:
    """{(scene, array): numpy array, or the list of a ragged array's frames} of every scene."""
    from holodata.dataset import open_dataset
    from holodata.dataset.reader import Ragged

    ds = open_dataset(url)
    out = {}
    for sid in ds.scenes:
        sc = ds.scene(sid)
        for name in sc.arrays():
            a = sc[name]
            out[(sid, name)] = [np.asarray(f) for f in a[:]] if isinstance(a, Ragged) else np.asarray(a[...])
    return out


def assert_same_arrays(got: dict, want: dict, where: str) -> None:
    assert sorted(got) == sorted(want), f"{where}: arrays {sorted(set(got) ^ set(want))} differ"
    for key, w in want.items():
        g = got[key]
        if isinstance(w, list):
            assert len(g) == len(w), f"{where}: {key}"
            for i, (x, y) in enumerate(zip(g, w)):
                np.testing.assert_array_equal(x, y, err_msg=f"{where}: {key} frame {i}")
        else:
            np.testing.assert_array_equal(g, w, err_msg=f"{where}: {key}")


def marks_of(url: str) -> dict:
    """{scene id or "(dataset)": its unfinished stages} of a dataset that exists."""
    from holodata.dataset import open_dataset

    ds = open_dataset(url)
    root = getattr(ds, "unfinished", {})   # (getattr: the sweep also runs against writers without marks)
    out = {"(dataset)": root} if root else {}
    for sid in ds.scenes:
        marks = getattr(ds.scene(sid), "unfinished", {})
        if marks:
            out[sid] = marks
    return out


def verdict(url: Path) -> tuple[bool, list[str]]:
    """(validates, problem lines) of what is at ``url``; no dataset there: (False, [why])."""
    from holodata.dataset import validate_dataset
    from holodata.errors import DatasetError

    if not url.exists():
        return False, ["no dataset"]
    try:
        rep = validate_dataset(str(url))
    except DatasetError as err:
        return False, [str(err)]
    return rep["ok"], [p["line"] for p in rep["problems"]]


def kill_sweep(tmp: Path, name: str, prepare, run, stage: str, scenes: tuple[str, ...] = (),
               root_stage: str | None = None, stride: int = 1) -> dict:
    """The sweep of one command. ``prepare(url)``: the dataset the command starts from (None: no
    dataset); ``run(url)``: the command. ``stage``: the mark the command leaves on ``scenes`` (the
    scenes it writes); ``root_stage``: its mark on the dataset root, if it writes the root after its
    scenes. Kills at writes 1, 1 + stride, ... and the last one. Returns {"writes", "kills",
    "unfinished_named"} for the caller's own checks."""
    base = tmp / f"{name}-base.zarr"
    if prepare is not None:
        prepare(str(base))
    ref = tmp / f"{name}-ref.zarr"

    def fresh(dst: Path) -> None:
        if base.exists():
            shutil.copytree(base, dst)

    fresh(ref)
    with killed_at(None) as st:
        run(str(ref))
    total = st["writes"]
    assert st["bypass"] == 0, f"{name}: {st['bypass']} writes went around the Store (not covered by the sweep)"
    ok, lines = verdict(ref)
    assert ok, f"{name}: the uninterrupted run does not validate: {lines[:3]}"
    assert not marks_of(str(ref)), f"{name}: the finished run left marks {marks_of(str(ref))}"
    want = arrays_of(str(ref))
    points = sorted(set(range(1, total + 1, stride)) | {total})
    named = 0
    for n in points:
        url = tmp / f"{name}-k{n}.zarr"
        fresh(url)
        with killed_at(n) as st:
            try:
                run(str(url))
            except Killed:
                pass
            else:
                raise AssertionError(f"{name}: the kill at write {n} of {total} did not stop the command")
        key = st["keys"][n - 1]
        ok, lines = verdict(url)
        if n == 1 and base.exists():   # killed before its first write: the dataset it started from, untouched
            assert (ok, lines) == verdict(base), f"{name}: killed before its first write ({key}): {lines[:3]}"
            assert_same_arrays(arrays_of(str(url)), arrays_of(str(base)), f"{name}: killed before its first write")
        else:
            assert not ok, f"{name}: killed at write {n}/{total} ({key}) and the dataset validates"
        if n > 1 and url.exists() and (url / "zarr.json").exists():
            present = [s for s in scenes if (url / "scenes" / s / "zarr.json").exists()]
            want_lines = [f"{s}: unfinished: {stage} did not finish" for s in present]
            if root_stage is not None and not present:
                want_lines = []
            for w in want_lines:
                if not any(line.startswith(w) for line in lines):
                    # the scene exists but its mark is gone: only after the command's own last scene write,
                    # when the root mark (written after the scenes) is what names the command
                    assert root_stage is not None and any(
                        line.startswith(f"(dataset): unfinished: {root_stage} did not finish") for line in lines), \
                        f"{name}: killed at write {n}/{total} ({key}): no line names {stage!r}: {lines[:4]}"
            named += bool(want_lines)
        with killed_at(None) as st:
            run(str(url))                                   # the rerun finishes what the killed run started
        assert st["bypass"] == 0
        ok, lines = verdict(url)
        assert ok, f"{name}: killed at write {n}/{total} ({key}), rerun does not validate: {lines[:3]}"
        assert not marks_of(str(url)), f"{name}: killed at write {n}: the rerun left marks {marks_of(str(url))}"
        assert_same_arrays(arrays_of(str(url)), want, f"{name}: killed at write {n}/{total} ({key}), rerun")
        shutil.rmtree(url, ignore_errors=True)
    return {"writes": total, "kills": len(points), "unfinished_named": named}
