"""Run holodata's CLI from another source tree (a git worktree of an older commit), not the installed one.

Trees older than the move of ``cli/`` and ``schemas/`` into ``holodata/`` kept them beside the package
(the editable install mapped ``holodata.cli`` and ``holodata.schemas`` there); ``PYTHONPATH`` alone would
then mix the old tree's package with today's CLI. This loads all three from TREE (whichever layout it
has), then runs the CLI with the remaining arguments:

    git worktree add /tmp/old 3237efc
    PYTHONPATH=/tmp/old .venv/bin/python scripts/run_from_tree.py /tmp/old demo --quick --out /tmp/old-demo

(``PYTHONPATH`` too, so that worker processes started by spawn import the same tree.)
"""
from __future__ import annotations

import importlib.util
import os
import sys


def load_tree(tree: str) -> None:
    """Import ``holodata`` and its mapped sub-packages from ``tree``; fail loudly if another copy loads."""
    sys.path.insert(0, tree)
    import holodata

    if not holodata.__file__.startswith(tree):
        raise SystemExit(f"holodata was already imported from {holodata.__file__}")
    for name, folder in (("holodata.cli", "cli"), ("holodata.schemas", "schemas")):
        if not os.path.isdir(f"{tree}/{folder}"):
            continue   # a tree with holodata/cli/: the package import above finds it
        spec = importlib.util.spec_from_file_location(name, f"{tree}/{folder}/__init__.py",
                                                      submodule_search_locations=[f"{tree}/{folder}"])
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)


if __name__ == "__main__":
    load_tree(sys.argv.pop(1))
    from holodata.cli.main import main

    sys.argv[0] = "holodata"
    sys.exit(main())
