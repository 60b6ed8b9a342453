"""Where the tests find the repository, themselves and the shared fixtures, whichever folder of
tests/ a test module sits in (not a test module)."""
from pathlib import Path

TESTS = Path(__file__).resolve().parent                  # tests/: the helper modules (_recordings, ...)
REPO = TESTS.parent                                      # the repository root (holodata/, README.md, ...)
FIXTURES = REPO.parent / "shared" / "fixtures"           # real recordings written by other tools
