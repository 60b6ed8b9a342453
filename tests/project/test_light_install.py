"""A light install for CI jobs (issue 50): ``pip install holodata`` is the dataset core (the format,
``validate``, ``info``, the reader API); each stage's dependencies come with an extra named for the
user's task (holodata/extras.py, mirrored by pyproject.toml), and a command whose extra is missing says
which one in one line, exit 1, no traceback.

The core install is checked here without building a venv: each command runs in a subprocess whose
import system refuses every package that only an extra installs (scipy, open3d, torch, dask, s3fs, ...),
as if they were not installed, and records any attempt to import one. docs/install.md has the same
check done in a fresh venv, with its size and time.
"""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
import tomllib

import pytest
from _paths import REPO
from click.testing import CliRunner

from holodata.cli.main import cli
from holodata.extras import ALL, COMMAND_EXTRAS, CORE, EXTRAS, all_requirements, extra_of, installed

ROOT = REPO
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
IMPORT_NAME = {"pyyaml": "yaml", "opencv-python-headless": "cv2", "kiss-icp": "kiss_icp", "rerun-sdk": "rerun",
               "dask": "distributed"}
# imported by holodata, installed by no extra of its own: why that is right
NOT_AN_EXTRA = {
    "google_crc32c": "zarr's own dependency (the shard index checksum)",
    "lz4": "mcap's and rosbags' dependency (compressed chunks)",
    "zstandard": "mcap's dependency",
    "threadpoolctl": "optional: holodata/radar/_steps.py runs without it",
    "ouster": "Ouster's SDK, installed --no-deps by scripts/setup.sh (holodata.readers.ouster.INSTALL_COMMAND)",
}
# what a core install lacks: every module only an extra brings, and what those pull in
NOT_IN_CORE = sorted({m for reqs in EXTRAS.values() for m in reqs.values()} - set(CORE)
                     | {"dask", "llvmlite", "pandas", "botocore", "aiobotocore", "aiohttp", "ouster", "mcap_ros2",
                        "PIL", "sklearn", "rerun_bindings"})


def _name(req: str) -> str:
    return re.split(r"[<>=!~\[;\s]", req, maxsplit=1)[0].lower()


# ------------------------------------------------------------------------------ the extras table
def test_pyproject_extras_mirror_the_table():
    deps = PYPROJECT["project"]["optional-dependencies"]
    assert set(deps) == set(EXTRAS) | {ALL, "dev"}
    for extra, reqs in EXTRAS.items():
        assert sorted(deps[extra]) == sorted(reqs), f"pyproject.toml's [{extra}] is not holodata/extras.py's"
        for req, module in reqs.items():
            assert IMPORT_NAME.get(_name(req), _name(req).replace("-", "_")) == module, req
    assert sorted(deps[ALL]) == sorted(all_requirements())
    assert "torch==2.13.0" in deps["train"]      # exactly: the CPU wheel on disk; any other spec fetches CUDA's
    core = [_name(r) for r in PYPROJECT["project"]["dependencies"]]
    assert sorted(IMPORT_NAME.get(n, n) for n in core) == sorted(CORE)
    assert not set(CORE) & set(NOT_IN_CORE)
    assert set(COMMAND_EXTRAS) <= set(cli.commands) and all(set(v) <= set(EXTRAS) for v in COMMAND_EXTRAS.values())


def test_every_third_party_import_is_in_the_core_or_an_extra():
    stdlib = set(sys.stdlib_module_names)
    known = set(CORE) | {m for reqs in EXTRAS.values() for m in reqs.values()} | set(NOT_AN_EXTRA)
    stray = {}
    for p in sorted((ROOT / "holodata").rglob("*.py")):
        for n in ast.walk(ast.parse(p.read_text())):
            names = [a.name for a in n.names] if isinstance(n, ast.Import) else \
                [n.module] if isinstance(n, ast.ImportFrom) and not n.level and n.module else []
            for name in names:
                top = name.split(".")[0]
                if top not in stdlib and top != "holodata" and top not in known:
                    stray.setdefault(top, f"{p.relative_to(ROOT)}:{n.lineno}")
    assert not stray, f"add these to an extra in holodata/extras.py and pyproject.toml: {stray}"


# ------------------------------------------------------------------------ a core install's commands
# sys.path's finder, less the blocked packages: importing one fails as if it were not installed, and
# importlib.util.find_spec finds nothing for it (as a library probing for optional packages expects)
BLOCKER = """
import json, os, sys
from importlib.machinery import PathFinder

BLOCKED = set(os.environ["HOLODATA_TEST_BLOCKED"].split(","))
TRIED = []

class NotInstalled:
    invalidate_caches = staticmethod(PathFinder.invalidate_caches)
    find_distributions = staticmethod(PathFinder.find_distributions)

    @staticmethod
    def find_spec(name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            TRIED.append(name)
            return None
        return PathFinder.find_spec(name, path, target)

sys.meta_path[sys.meta_path.index(PathFinder)] = NotInstalled

def _tried():
    with open(os.environ["HOLODATA_TEST_TRIED"], "w") as f:
        json.dump(sorted(set(TRIED)), f)

import atexit
atexit.register(_tried)
"""


def core_run(tmp_path, code: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    """Run ``code`` in a fresh interpreter that cannot import :data:`NOT_IN_CORE`; returns the process
    and the modules it tried to import."""
    tried = tmp_path / f"tried_{len(list(tmp_path.glob('tried_*')))}.json"
    env = {**__import__("os").environ, "HOLODATA_TEST_BLOCKED": ",".join(NOT_IN_CORE), "HOLODATA_TEST_TRIED": str(tried)}
    r = subprocess.run([sys.executable, "-c", BLOCKER + code], capture_output=True, text=True, env=env, cwd=tmp_path,
                       timeout=120)
    return r, json.loads(tried.read_text()) if tried.is_file() else ["(no record)"]


def core_cli(tmp_path, *args: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    return core_run(tmp_path, f"sys.argv = ['holodata', *{list(args)!r}]\nfrom holodata.cli.main import main\nmain()\n")


@pytest.fixture(scope="module")
def core_dataset(tmp_path_factory):
    """A small dataset written and read back through the API in a core-only interpreter."""
    tmp = tmp_path_factory.mktemp("core")
    r, tried = core_run(tmp, """
import holodata
from holodata.dataset.synthetic import write_toy_dataset
write_toy_dataset("toy.zarr", n_frames=6)
ds = holodata.open_dataset("toy.zarr")
sc = ds.scene(ds.scenes[0])
print(json.dumps({"scenes": ds.scenes, "range": list(sc["gt/range"][1:3].shape),
                  "lidar": list(sc["lidar/points"][1].shape), "arrays": sc.arrays()}))
""")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["scenes"] == ["c1"] and out["range"] == [2, 3, 8, 32] and out["lidar"][1] == 3
    assert tried == [], f"the reader API tried to import {tried}"
    return tmp, tmp / "toy.zarr"


def test_core_help_validate_and_info(core_dataset):
    tmp, ds = core_dataset
    r, tried = core_cli(tmp, "--help")
    assert r.returncode == 0 and "validate" in r.stdout and "slam" in r.stdout and tried == [], (r.stderr, tried)
    r, tried = core_cli(tmp, "validate", str(ds), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ok"] is True and tried == [], tried
    r, tried = core_cli(tmp, "info", str(ds))
    assert r.returncode == 0 and "gt/range" in r.stdout and tried == [], (r.stderr, tried)


def _one_line(r: subprocess.CompletedProcess, extra: str, command: str) -> None:
    assert r.returncode == 1 and r.stdout == "", (r.returncode, r.stdout)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert lines[0].startswith(f"error: holodata {command} needs the '{extra}' extra")
    assert lines[0].endswith(f"pip install 'holodata[{extra}]'"), lines[0]


def test_core_refuses_a_stage_in_one_line_naming_its_extra(core_dataset):
    tmp, ds = core_dataset
    r, _ = core_cli(tmp, "slam", str(ds))                     # checked before the command starts
    _one_line(r, "mapping", "slam")
    r, _ = core_cli(tmp, "validate", "s3://holodata-test-bucket/d.zarr", "--json")
    _one_line(r, "s3", "validate")
    out = tmp / "h5"
    r, tried = core_cli(tmp, "export", str(ds), "--format", "hdf5", "--out", str(out))   # met inside the command
    _one_line(r, "export", "export")
    assert "h5py" in tried


# ----------------------------------------------------------------- the same, in this process
@pytest.fixture
def toy(tmp_path):
    from holodata.dataset.synthetic import write_toy_dataset

    return write_toy_dataset(str(tmp_path / "toy.zarr"), n_frames=4)


def test_a_module_set_to_none_counts_as_missing(monkeypatch):
    assert installed("numpy")
    monkeypatch.setitem(sys.modules, "open3d", None)
    assert not installed("open3d") and not installed("holodata_no_such_module")
    assert extra_of("h5py") == "export" and extra_of("h5py", ("ingest",)) == "ingest" and extra_of("ouster") is None


def test_the_extras_a_command_needs_follow_its_options():
    from holodata.extras import command_extras

    assert command_extras("info", {"dataset": "d.zarr"}) == []
    assert command_extras("validate", {"dataset": "s3://b/d.zarr"}) == ["s3"]
    assert command_extras("ingest", {"recordings": ("a.mcap",), "out": "S3://b/d.zarr", "workers": 2,
                                     "scheduler": None}) == ["ingest", "s3", "dask"]
    assert command_extras("raytrace-gt", {"workers": 0, "scheduler": "tcp://127.0.0.1:8786"}) == ["gt", "dask"]
    assert command_extras("train", {"workers": 4}) == ["train"]        # DataLoader workers, not Dask's
    assert command_extras("view", {"checkpoint": None, "report": "rep"}) == ["view", "train"]
    assert command_extras("export", {"fmt": "hdf5"}) == ["export"] and command_extras("export", {"fmt": "panoradar"}) == []
    assert command_extras("demo", {}) == ["synth", "ingest", "mapping", "gt", "train"]


def test_precheck_names_every_missing_extra_of_the_command(monkeypatch, toy, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.setitem(sys.modules, "torch", None)
    r = CliRunner().invoke(cli, ["synth", "--out", str(tmp_path / "s"), "--frames", "1", "--workers", "2"])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
    assert "needs the 'dask' extra (distributed is not installed): pip install 'holodata[dask]'" in r.output
    assert not (tmp_path / "s").exists()                                  # refused before any work
    r = CliRunner().invoke(cli, ["train", toy, "--out", str(tmp_path / "run")])
    assert r.exit_code == 1 and "holodata train needs the 'train' extra (torch is not installed)" in r.output
    r = CliRunner().invoke(cli, ["train", "--help"])                       # help needs no extra
    assert r.exit_code == 0


def test_a_module_missing_inside_a_command_names_its_extra(monkeypatch):
    """The CLI's error boundary: a module of an extra met after the check (here a command that checks
    nothing) is named by its extra, also through a chain of errors (fsspec's "Install s3fs" ImportError)."""
    import click

    from holodata.errors import DatasetError
    from holodata.extras import missing_extra_line

    @click.command("needs-h5")
    def needs_h5():
        import h5py  # noqa: F401

    monkeypatch.setitem(sys.modules, "h5py", None)
    monkeypatch.setitem(cli.commands, "needs-h5", needs_h5)
    r = CliRunner().invoke(cli, ["needs-h5"])
    assert r.exit_code == 1, r.output
    assert r.output.strip() == ("error: holodata needs-h5 needs the 'export' extra (h5py is not installed): "
                                "pip install 'holodata[export]'")
    monkeypatch.setitem(sys.modules, "s3fs", None)
    try:
        try:
            try:
                import s3fs  # noqa: F401
            except ImportError as e:
                raise ImportError("Install s3fs to access S3") from e
        except ImportError as e:
            raise DatasetError("s3://b/d.zarr: cannot open URL (Install s3fs to access S3)") from e
    except DatasetError as err:
        assert missing_extra_line(err, "info") == ("holodata info needs the 's3' extra (s3fs is not installed): "
                                                   "pip install 'holodata[s3]'")
    assert missing_extra_line(ValueError("x"), "info") is None
    assert missing_extra_line(ModuleNotFoundError("No module named 'ouster'", name="ouster"), "ingest") is None
