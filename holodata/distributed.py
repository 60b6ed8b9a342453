"""Scale-out on Dask distributed: per-shard and per-scene tasks, run on a local or existing cluster.

Engine: ``dask.distributed``. ``--workers N`` starts a :class:`distributed.LocalCluster` (N worker
processes, one task thread each, on 127.0.0.1); ``--scheduler ADDRESS`` connects to an existing
cluster (``tcp://host:8786``, or the path of a ``--scheduler-file`` JSON as written by
``dask scheduler`` / dask-jobqueue / dask-kubernetes). Without either flag nothing here is used and
every stage runs in-process as before.

Tasks (the unit a lost worker loses, and the scheduler reruns elsewhere). This module only runs
them (:func:`run_tasks` over a function and its calls) and knows no stage; each stage owns its task
function (``groundtruth._gt_shard_task``, ``ingest._ingest_task``, ``synth.batch._synth_task``) and
imports this module, never the other way round (tests/project/test_import_graph.py):

* ``raytrace-gt``: one task per *shard* of a scene (``shard_frames`` consecutive frames); it
  traces those frames and writes every gt/* array's shard with ``FrameArrayWriter.write_shard``.
  The static scene (mesh, trajectory, config, human source) is scattered once to every worker and
  its ray-casting scene built once per worker thread.
* ``ingest``: one task per recording (a whole scene: ragged arrays are appended in order, so a
  scene cannot be split).
* ``synth``: one task per recording (:mod:`holodata.synth.batch`).

Idempotence: a shard is written whole in one atomic put and committed by its manifest record
(:mod:`holodata.dataset.writer`); a task whose shards are already committed does nothing, a task
killed before the commit leaves at most an uncommitted object that the rerun overwrites with the
same bytes (tracing and encoding are deterministic). Object stores have no atomic rename, but a
PUT is atomic (see :mod:`holodata.dataset.store`), so the same holds on ``s3://``. Once all tasks
are done the client folds the manifest records into the array attributes (idempotent).

Datasets are read and written by the workers themselves through fsspec, so a dataset URL must be
reachable from every worker (a shared folder or an object store); credentials come from the
workers' environment (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_ENDPOINT_URL``,
``FSSPEC_S3_*``), never from the command line. Recordings, meshes and human meshes given as local
paths must exist at the same path on the workers.

Progress: a bar over completed tasks (``holodata.progress.track`` over ``as_completed``).
"""
from __future__ import annotations

import contextlib
import logging
import os
from contextlib import contextmanager
from pathlib import Path

from .errors import InputError

CONNECT_TIMEOUT_S = 30  # to an existing scheduler
TASK_RETRIES = 2  # reruns of a task that *raised* (lost workers are rescheduled by Dask itself)


@contextmanager
def cluster(workers: int = 0, scheduler: str | None = None):
    """Yield a ``distributed.Client`` (``workers`` > 0: a new LocalCluster; ``scheduler``: an existing
    cluster's address or scheduler-file path), or None when neither is given (run in-process).

    The client carries ``holodata_local_workers`` (N for a LocalCluster, 0 for an external one)."""
    if workers and scheduler:
        raise InputError("give either --workers or --scheduler, not both")
    if workers < 0:
        raise InputError(f"--workers must be >= 0, got {workers}")
    if not workers and not scheduler:
        yield None
        return
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            if Path(scheduler).is_file():
                client = Client(scheduler_file=scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
            else:
                client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError, ValueError) as err:
            raise InputError(f"{scheduler}: cannot connect to the Dask scheduler ({' '.join(str(err).split())})") from err
        client.holodata_local_workers = 0
        try:
            yield client
        finally:
            client.close()
        return
    # the scheduler's HTTP server binds dashboard_address even without a dashboard (None means :8787,
    # and a second cluster on the machine then warns): a free port instead
    lc = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
    client = Client(lc)
    client.holodata_local_workers = workers
    try:
        yield client
    finally:
        close_worker_filesystems(client)
        client.close()
        lc.close()


def close_worker_filesystems(client) -> None:
    """Close the object-store HTTP sessions of the workers of a LocalCluster this process started,
    before the cluster stops: the worker processes write to the CLI's stderr, where aiohttp would
    print "Unclosed client session" for each session left to their interpreter shutdown
    (:func:`holodata.dataset.store.close_filesystems`). An existing cluster's workers are left alone:
    they outlive this command, may serve other clients, and do not write to its stderr."""
    from .dataset.store import close_filesystems

    with contextlib.suppress(Exception):   # any failure: a worker already gone has nothing left to close
        client.run(close_filesystems, on_error="ignore")


def n_workers(client) -> int:
    return len(client.scheduler_info(n_workers=-1)["workers"]) if client is not None else 0


def run_tasks(client, fn, calls: list[tuple], keys: list[str], description: str = "", quiet: bool = True,
              retries: int = TASK_RETRIES) -> list:
    """Submit ``fn(*args)`` for every ``args`` in ``calls`` (task keys ``keys``), show progress over
    completions, return the results in submission order. The first task error is re-raised (its
    original type, e.g. a HolodataError) after cancelling the rest. A worker that dies mid-task (a
    signal, the OOM killer) costs a rerun elsewhere (Dask's ``allowed-failures``, default 3); a task
    that kills every worker it lands on ends in one WorkerError line."""
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    from .progress import track

    futures = [client.submit(fn, *args, key=key, retries=retries, pure=False) for args, key in zip(calls, keys)]
    results = {}
    try:
        for fut in track(as_completed(futures), total=len(futures), description=description, quiet=quiet):
            results[fut.key] = fut.result()
    except KilledWorker as err:   # Dask reran the task on fresh workers and each one died: one line, not its repr
        from .parallel import WorkerError

        client.cancel(futures)
        raise WorkerError(f"{description or getattr(fn, '__name__', 'task')}: task {err.task!r} killed "
                          f"{err.allowed_failures + 1} Dask workers (killed by a signal or out of memory); "
                          f"given up") from err
    except BaseException:
        client.cancel(futures)
        raise
    return [results[k] for k in keys]


def worker_path(path_or_url) -> str:
    """A dataset/input location as workers must see it: URLs unchanged, local paths absolute
    (a worker's working directory is not the client's)."""
    from .dataset.store import is_url

    s = str(path_or_url)
    if is_url(s):
        return s
    return str(Path(s[len("file://"):] if s.startswith("file://") else s).expanduser().absolute())


def for_workers(human):
    """A human source whose file paths are absolute (HumanFile keeps its mesh in memory)."""
    import copy

    if getattr(human, "files", None):
        human = copy.copy(human)
        human.files = [Path(worker_path(f)) for f in human.files]
    elif isinstance(getattr(human, "url", None), str):  # HumanDataset: reopened by URL on the worker
        human = copy.copy(human)
        human.url = worker_path(human.url)
    return human


# ---------------------------------------------------------------------------------------- workers
_TUNED: list = []


def tune_malloc() -> None:
    """Undo, in this worker process, the cost of Dask's ``MALLOC_TRIM_THRESHOLD_=65536`` (set by the
    nanny): with it glibc serves every allocation above 128 KiB by mmap and unmaps it on free, so
    the per-frame arrays (hundreds of KiB to MiB) are page-faulted in again on every frame, which
    costs raytrace-gt much CPU (docs/design/performance.md). Large allocations come from the heap
    again (below 32 MiB) and the heap is trimmed only above 64 MiB of free memory. glibc only; a no-op elsewhere."""
    if _TUNED or not os.environ.get("MALLOC_TRIM_THRESHOLD_"):
        return
    _TUNED.append(True)
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 64 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


__all__ = ["cluster", "run_tasks", "n_workers", "worker_path", "for_workers", "tune_malloc"]
