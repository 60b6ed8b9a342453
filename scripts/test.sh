#!/usr/bin/env bash
# Run holodata's linter, type checker and test suite (sets up .venv first if needed). Extra arguments go to pytest
# (the fast tier: scripts/test.sh -m "not slow").
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check .   # lint (pyproject [tool.ruff]); a finding fails the run
.venv/bin/mypy            # types of the numeric cores (pyproject [tool.mypy]: files, overrides); an error fails the run
exec .venv/bin/python -m pytest -q "$@"
