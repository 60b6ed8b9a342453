"""The README's code runs as written: every ```python block is executed (against a small dataset
where the README expects `holodata demo`'s), and every `holodata …` line of its ```bash blocks names
a command and options that exist."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
import pytest
from _paths import REPO

from holodata.cli.main import cli

README = REPO / "README.md"


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README.read_text(), flags=re.S)


@pytest.mark.slow
def test_readme_python_blocks_run_as_written(tmp_path, monkeypatch):
    pytest.importorskip("torch")
    import _eval_dataset as E

    blocks = _blocks("python")
    assert blocks, "the README has no Python example"
    monkeypatch.chdir(tmp_path)
    E.build(str(tmp_path / "holodata-demo" / "dataset.zarr"))
    for i, code in enumerate(blocks):
        if "dask_jobqueue" in code:   # the SLURM recipe needs a cluster: parsed, not run
            compile(code, f"README python block {i}", "exec")
            continue
        exec(compile(code, f"README python block {i}", "exec"), {"__name__": f"readme_{i}"})
    # the bash lines that use what the Python blocks wrote (the raw-radar trajectory: ingest, beamform) run as written
    from click.testing import CliRunner

    ran = 0
    for words in _command_lines():
        if words[:1] in (["ingest"], ["beamform"]) and len(words) > 1 and \
                (tmp_path / words[-1 if words[1] == "--list" else 1]).exists():
            r = CliRunner().invoke(cli, words + (["--quiet"] if "--out" in words or words[0] == "beamform" else []))
            assert r.exit_code == 0, (words, r.output)
            ran += 1
    assert ran >= 4


def _command_lines() -> list[list[str]]:
    out = []
    for block in _blocks("bash"):
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = line.split("#", 1)[0].strip()
            for part in re.split(r"&&|\|\||;", line):
                first = part.split()[:1]
                if first and Path(first[0]).name == "holodata":
                    out.append(shlex.split(part.replace("…", "x").replace("&", ""))[1:])
    return out


def test_readme_shell_commands_exist_with_their_options():
    lines = _command_lines()
    assert any(w[:1] == ["demo"] for w in lines)
    for words in lines:
        args = [w for w in words if w != "--debug"]
        cmd = cli.get_command(click.Context(cli), args[0])
        assert cmd is not None, f"README: no command holodata {args[0]}"
        try:
            cmd.make_context(args[0], args[1:])
        except click.BadParameter as err:      # a path the README's reader has, this test does not
            assert "does not exist" in str(err), (words, err)
        except click.UsageError as err:
            raise AssertionError(f"README line 'holodata {' '.join(words)}': {err}") from err
