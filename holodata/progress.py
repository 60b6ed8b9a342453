"""Progress bars for long work: rich on a TTY, silent otherwise or when ``quiet``."""
from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def progress_enabled(quiet: bool = False) -> bool:
    return not quiet and sys.stderr.isatty()


def track(items: Iterable[T], total: int | None = None, description: str = "", quiet: bool = False,
          unit: str = "") -> Iterator[T]:
    """Yield ``items`` while showing a progress bar on stderr when it is a TTY and not ``quiet``
    (``12/40 frames`` with ``unit="frames"``); no bar when there is nothing to do (``total`` 0)."""
    if not progress_enabled(quiet) or total == 0:
        yield from items
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn(unit),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=False,
    ) as bar:
        task = bar.add_task(description, total=total)
        for item in items:
            yield item
            bar.advance(task)
