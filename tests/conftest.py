"""Session hooks for the test suite.

Tests marked ``browser`` render a page in a real headless Chromium (issue 27 point 4). Under ``-q``
pytest prints no line for a passing test, so the summary names each browser test that passed: CI's
log then shows the report was checked in a browser, not skipped.
"""
from __future__ import annotations

import sys
from pathlib import Path

# the helper modules (_recordings, _paths, ...) sit in tests/; tests in its subfolders import them by name
sys.path.insert(0, str(Path(__file__).resolve().parent))


def pytest_terminal_summary(terminalreporter) -> None:
    for report in terminalreporter.stats.get("passed", []):
        if report.when == "call" and "browser" in report.keywords:
            terminalreporter.write_line(f"browser test passed: {report.nodeid}")
