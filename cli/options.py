"""Click options shared by several commands (one definition, the same wording everywhere)."""
from __future__ import annotations

import click


def dask_options(task: str, shared: str):
    """``--workers N`` / ``--scheduler ADDRESS`` for commands that can run ``task`` (e.g. "one task
    per shard") on a Dask cluster; ``shared`` says what the workers must be able to reach."""

    def decorate(fn):
        fn = click.option("--scheduler", metavar="ADDRESS",
                          help=f"Run {task} on an existing Dask cluster (tcp://host:8786 or a scheduler file); "
                               f"{shared}")(fn)
        return click.option("--workers", default=0, show_default=True, type=click.IntRange(0),
                            help=f"Run {task} on a local Dask cluster of N worker processes (0 = no Dask).")(fn)

    return decorate
