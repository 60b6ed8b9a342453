"""holodata's error types. Each also subclasses a builtin so callers can catch either.

The CLI turns a :class:`HolodataError` into one line on stderr and exit code 1; the message
must name the file (or scene/array) and the problem.
"""
from __future__ import annotations


class HolodataError(Exception):
    """Base class: a problem with the user's data or request, reported in one line."""


class InputError(HolodataError, ValueError):
    """A file or argument that cannot be used (missing, malformed, wrong kind)."""


class DatasetError(HolodataError, ValueError):
    """A dataset that is missing, not a holodata dataset, or inconsistent."""


class RecordingError(HolodataError, ValueError):
    """A recording that cannot be read or holds nothing usable."""


def one_line(err: BaseException, limit: int | None = None) -> str:
    """``err``'s message on one line (whitespace runs folded; at most ``limit`` characters), or its
    class name when it has none: what an error line quotes of the error that caused it."""
    msg = " ".join(str(err).split())[:limit]
    return msg or err.__class__.__name__
