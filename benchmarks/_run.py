"""How a benchmark was run, in one line: :func:`header` prints the command, the commit and the machine.

Each benchmark calls it at the start of its ``main`` (after parsing its arguments), so that a result
pasted into ``benchmarks/results/`` carries what is needed to run it again and to compare it:

    run: python benchmarks/segment.py --seeds 1 | commit 1a2b3c4 | 2 CPUs (AMD EPYC 7B13), 7.8 GiB RAM

Imported as ``from _run import header``: ``python benchmarks/x.py`` puts this folder on ``sys.path``.
"""
from __future__ import annotations

import contextlib
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def command(argv: list[str] | None = None) -> str:
    """The command line as typed from the repository root: ``python benchmarks/x.py ARGS``, shell-quoted."""
    argv = list(sys.argv if argv is None else argv)
    if argv:
        script = Path(argv[0])
        with contextlib.suppress(OSError, ValueError):   # outside the repository (or not a file): as given
            argv[0] = str(script.resolve().relative_to(ROOT))
    return shlex.join(["python", *argv])


def commit() -> str:
    """The checkout's short commit hash, with ``+dirty`` when tracked files differ from it; ``unknown``
    when git cannot say (no git, not a checkout)."""
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10)
        if head.returncode != 0 or not head.stdout.strip():
            return "unknown"
        dirty = subprocess.run(["git", "-C", str(ROOT), "diff", "--quiet", "HEAD", "--"], capture_output=True,
                               timeout=30)
        return head.stdout.strip() + ("+dirty" if dirty.returncode == 1 else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _proc_value(path: str, key: str) -> str | None:
    """The value of the first ``key: value`` line of a /proc file, or None."""
    try:
        with open(path) as f:
            for line in f:
                k, sep, v = line.partition(":")
                if sep and k.strip() == key:
                    return v.strip()
    except OSError:
        pass
    return None


def machine() -> str:
    """CPU count and model, total RAM, and the CUDA device when torch is already imported and sees one
    (torch is not imported here: it takes seconds)."""
    cpu = _proc_value("/proc/cpuinfo", "model name") or platform.processor() or platform.machine() or "unknown CPU"
    parts = [f"{os.cpu_count() or '?'} CPUs ({cpu})"]
    mem = _proc_value("/proc/meminfo", "MemTotal")
    if mem and mem.split()[0].isdigit():
        parts.append(f"{int(mem.split()[0]) / 2**20:.1f} GiB RAM")
    torch = sys.modules.get("torch")
    if torch is not None:
        try:
            if torch.cuda.is_available():
                parts.append(f"GPU {torch.cuda.get_device_name()}")
        except Exception:  # noqa: BLE001 - a broken CUDA set-up: leave the GPU out of the line
            pass
    return ", ".join(parts)


def header(argv: list[str] | None = None) -> str:
    """Print (and return) one line: the command, the commit and the machine."""
    line = f"run: {command(argv)} | commit {commit()} | {machine()}"
    print(line, flush=True)
    return line


def best_of(fn, repeat: int = 3) -> float:
    """Best wall time (s) of ``repeat`` calls of ``fn()``: the least disturbed run of the same work."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)
