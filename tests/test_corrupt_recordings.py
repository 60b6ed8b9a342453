"""Corrupt recordings never become invalid datasets: seeded mutants (bytes overwritten, spans zeroed,
spans cut) of a holodata synth MCAP and of real fixtures written by other tools either ingest into a
dataset that ``validate`` accepts, or fail with one line that names the file (never a Python
exception class)."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from holodata.conventions import Grid
from holodata.dataset import validate_dataset

FIXTURES = Path(__file__).resolve().parents[2] / "shared" / "fixtures"
HOLODATA = [sys.executable, "-m", "holodata.cli.main"]
EXC_NAME = re.compile(r"\b[A-Z][A-Za-z]+(Error|Exception)\b")


def mutate(data: bytes, rng: np.random.Generator, kind: int, lo: int) -> bytes:
    """kind 0: 1-64 random bytes overwritten within 4 KB; 1: a 16 B-4 KB span zeroed; 2: cut out."""
    d = bytearray(data)
    pos = int(rng.integers(lo, max(lo + 1, len(d) - 4200)))
    if kind == 0:
        for j in rng.integers(pos, pos + 4096, int(rng.integers(1, 65))):
            d[min(int(j), len(d) - 1)] = int(rng.integers(256))
    elif kind == 1:
        n = int(rng.integers(16, 4096))
        d[pos:pos + n] = bytes(n)
    else:
        del d[pos:pos + int(rng.integers(16, 4096))]
    return bytes(d)


@pytest.fixture(scope="module")
def synth_mcap(tmp_path_factory) -> Path:
    from holodata.synth import synthesize

    out = tmp_path_factory.mktemp("corrupt") / "L"
    synthesize(out, corner="L", frames=6, seed=5, grid=Grid(16, 64), lidar_shape=(16, 128), camera_shape=(48, 64),
               quiet=True)
    return out / "recording"


def _cases(synth: Path) -> list[tuple[Path, Path]]:
    """(recording to copy, file in it to damage)."""
    out = [(synth, next(synth.glob("*.mcap")))]
    for rel in ("mcap/rosbag2_2025_09_10-13_03_56_0.mcap", "ros1/luminar-test.bag"):
        p = FIXTURES / rel
        if p.is_file():
            out.append((p, p))
    return out


@pytest.mark.slow
def test_mutants_ingest_into_valid_datasets_or_fail_in_one_line(synth_mcap, tmp_path):
    rng = np.random.default_rng(2026)
    n_ok = n_failed = 0
    for rec, victim in _cases(synth_mcap):
        data = victim.read_bytes()
        for i in range(6):
            work = tmp_path / f"{victim.stem}_{i}"
            if rec.is_dir():
                shutil.copytree(rec, work)
                target = work / victim.name
            else:
                work.mkdir()
                target = work / victim.name
            target.write_bytes(mutate(data, rng, i % 3, lo=min(1000, len(data) // 4)))
            src = work if rec.is_dir() else target
            url = tmp_path / f"{victim.stem}_{i}.zarr"
            r = subprocess.run(HOLODATA + ["ingest", str(src), "--out", str(url), "--quiet"],
                               capture_output=True, text=True, timeout=300)
            if r.returncode == 0:
                rep = validate_dataset(str(url))
                assert rep["ok"], f"{victim.name} mutant {i}: ingest exit 0 but validate: {rep['problems'][0]['line']}"
                n_ok += 1
            else:
                assert r.returncode == 1, r.stderr[-400:]
                err = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
                assert len(err) == 1 and "Traceback" not in r.stderr, r.stderr[-400:]
                assert not EXC_NAME.search(err[0]) or "(run with --debug" not in err[0], err[0]
                assert not (url.exists() and validate_dataset(str(url))["ok"])
                n_failed += 1
    assert n_ok >= 3   # most damage is survivable: the readable part is ingested
