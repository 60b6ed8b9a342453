"""Many recordings at once: ``synth --count N`` and ``synth --workers/--scheduler``.

:func:`synth_scenes` writes ``count`` recordings ``out/scene_000``, ``out/scene_001`` ... of one
:class:`~holodata.synth.spec.SynthSpec` with consecutive seeds, in this process or one Dask task per
recording (:func:`synth_dask`, the ``synth`` task of :mod:`holodata.distributed`, which only runs it:
:func:`~holodata.distributed.run_tasks` on a :func:`~holodata.distributed.cluster`'s client).
"""
from __future__ import annotations

import uuid
from dataclasses import replace
from pathlib import Path

from ..distributed import run_tasks, tune_malloc, worker_path
from ..errors import InputError
from .spec import SynthSpec
from .synthesis import synthesize


def _synth_task(out_dir: str, spec: SynthSpec) -> dict:
    tune_malloc()
    return synthesize(out_dir, spec, quiet=True).summary()


def synth_dask(client, jobs: list[tuple[str, SynthSpec]], quiet: bool = True) -> list[dict]:
    """One Dask task per recording: ``jobs`` [(out_dir, spec)] → their summaries."""
    token = uuid.uuid4().hex[:8]
    keys = [f"synth-{Path(o).name}-{token}" for o, _ in jobs]
    return run_tasks(client, _synth_task, [(str(o), spec) for o, spec in jobs], keys, description="synth", quiet=quiet)


def synth_scenes(out, count: int, spec: SynthSpec = SynthSpec(), client=None, quiet: bool = True) -> list[dict]:
    """``count`` recordings ``out/scene_000``, ``out/scene_001`` ... of ``spec`` with seeds ``spec.seed``,
    ``spec.seed + 1`` ..., one task each on ``client`` or in this process. Returns their summaries.
    ``out`` must be reachable at the same path from every worker."""
    from ..progress import track

    if count < 1:
        raise InputError(f"--count must be >= 1, got {count}")
    out = Path(out)
    jobs = [(worker_path(out / f"scene_{i:03d}"), replace(spec, seed=spec.seed + i)) for i in range(count)]
    for o, _ in jobs:  # fail before any task starts
        if Path(o).exists() and any(Path(o).iterdir()):
            raise InputError(f"{o}: already exists and is not empty; choose an empty --out")
    if client is not None:
        return synth_dask(client, jobs, quiet=quiet)
    return [synthesize(o, job, quiet=True).summary()
            for o, job in track(jobs, total=len(jobs), description="synth", quiet=quiet)]


__all__ = ["synth_dask", "synth_scenes"]
