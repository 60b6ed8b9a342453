"""Issue 55: the README's "Your own recording" commands run as written, with default settings, on two
synthesised corners (a data and a mapping pass each), and then every example of every command's
``--help`` runs on the files they made (the help examples name the same ``lab/`` files).

Run as pasted, with two exceptions named here: a training example's ``--epochs`` is cut to 2, and the
examples that cannot run in a test (the whole demo, a server that runs until Ctrl-C, a cluster, a lab's
own bags) are only parsed: their options must exist."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from _paths import REPO
from click.testing import CliRunner

from holodata.cli.main import cli

README = REPO / "README.md"
MARK = "# your own recording"
# the order a user meets the commands in; each one's examples use what the ones before wrote
ORDER = ("synth", "ingest", "beamform", "slam", "register", "raytrace-gt", "split", "validate", "info", "train",
         "evaluate", "export", "view", "demo")
PARSE_ONLY = (("demo", "the whole demo takes minutes"), ("--web", "serves until Ctrl-C"),
              ("--scheduler", "needs a Dask cluster"), ("s3://", "needs an object store"),
              ("corner_01.bag", "a lab's own bags"))


def recipe() -> list[list[str]]:
    """The ``holodata`` command lines of the README's own-recording block, as argument lists."""
    block = next(b for b in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S) if MARK in b)
    out = []
    for line in block.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            words = shlex.split(line)
            assert Path(words[0]).name == "holodata", line
            out.append(words[1:])
    return out


def examples(command: str) -> list[list[str]]:
    """The example lines of ``holodata COMMAND --help`` (its text before the options)."""
    r = CliRunner().invoke(cli, [command, "--help"], terminal_width=200)
    assert r.exit_code == 0, r.output
    text = r.output.split("\nOptions:")[0]
    return [shlex.split(m)[1:] for m in re.findall(r"^\s+(holodata .+?)\s*$", text, flags=re.M)]


def _parse_only(words: list[str]) -> str | None:
    line = " ".join(words)
    return next((why for key, why in PARSE_ONLY if key in words or key in line), None)


def _run(words: list[str]):
    r = CliRunner().invoke(cli, words + ["--quiet"] if _takes_quiet(words[0]) else words)
    assert r.exit_code == 0, (words, r.output)
    return r


def _takes_quiet(command: str) -> bool:
    return any(o.name == "quiet" for o in cli.commands[command].params)


def test_every_command_has_examples():
    for command in cli.commands:
        assert examples(command), f"holodata {command} --help has no example"
        assert command in ORDER, f"add {command} to ORDER"


@pytest.mark.slow
def test_the_readme_recipe_and_every_help_example_run_as_written(tmp_path, monkeypatch):
    pytest.importorskip("torch")
    monkeypatch.chdir(tmp_path)
    for words in recipe():
        _run(words)
    from holodata.dataset import open_dataset
    from holodata.dataset.splits import scene_role

    ds = open_dataset("lab/ds.zarr")
    assert ds.splits["test"] == ["c2"] and ds.splits["train"] == ["c1"]
    assert [scene_role(ds.scene(s).attrs) for s in ds.scenes] == ["data", "mapping", "data", "mapping"]
    for sid in ("c1", "c2"):   # the person is in the GT wherever the truth has one in view
        import numpy as np

        lab = np.asarray(ds.scene(sid)["gt/label"][...])
        assert np.isin(lab, (3, 4)).any(), sid
    assert Path("lab/report/metrics.json").is_file()

    ran, parsed = 0, 0
    for command in ORDER:
        for words in examples(command):
            assert words[0] == command, (command, words)
            if _parse_only(words):
                cli.commands[command].make_context(command, words[1:])   # its options exist
                parsed += 1
                continue
            if command == "synth" and "--out" in words and Path(words[words.index("--out") + 1]).exists():
                continue   # the recipe ran this very synth (a second run refuses to replace the recording)
            if "--epochs" in words:   # (the recipe's run has 2: asking one that resumes it for fewer is refused)
                i = words.index("--epochs") + 1
                words[i] = str(min(int(words[i]), 2))
            _run(words)
            ran += 1
    assert ran >= 25 and parsed >= 4, (ran, parsed)
    # train --init pretrained fine-tuned stage two too, from the shipped stage2.pt and at its shapes
    import torch

    from holodata.torch.pretrained import WEIGHTS

    ck = torch.load("lab/finetuned/stage2.pt", weights_only=False)
    shipped = torch.load(WEIGHTS / "stage2.pt", weights_only=False)
    assert ck["meta"]["init"] == str(WEIGHTS / "stage2.pt") and ck["rt_config"] == shipped["rt_config"]
