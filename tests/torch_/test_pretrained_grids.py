"""The shipped weights per beam grid: ``pretrained`` names the run trained for the dataset's grid, a grid
without one is a one-line error naming the grids there are, every shipped run's folder is a package the
install carries, and ``install(half=True)`` stores the networks as float16 that a model loads back."""
import tomllib
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from _paths import REPO  # noqa: E402

from holodata.conventions import Grid  # noqa: E402
from holodata.errors import InputError  # noqa: E402
from holodata.torch import pretrained as P  # noqa: E402

ROOT = REPO


def test_pretrained_is_the_run_of_the_dataset_grid():
    assert "32x128" in P.installed()
    assert P.resolve("pretrained") == P.WEIGHTS == P.resolve("pretrained", Grid(32, 128))
    assert P.resolve("some/run") == Path("some/run")   # any other name is a path, whatever the grid
    with pytest.raises(InputError) as err:
        P.resolve("pretrained", Grid(16, 64))
    line = str(err.value)
    assert "\n" not in line and "16x64" in line and "32x128" in line


def test_every_grid_folder_with_weights_is_shipped():
    """A run installed into GRID_DIRS is installed with the package only if pyproject lists its folder."""
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())
    packages = set(conf["tool"]["setuptools"]["packages"])
    data = conf["tool"]["setuptools"]["package-data"]
    for key, folder in P.installed().items():
        name = "holodata." + ".".join(folder.relative_to(ROOT / "holodata").parts)
        assert name in packages and "*.pt" in data.get(name, []), f"{key} weights in {folder} would not be installed"


def test_install_half_stores_float16_that_a_model_loads(tmp_path):
    from holodata.torch.model import ModelConfig, MultiReturnUNet
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT
    from holodata.torch.train import CHECKPOINT

    cfg = ModelConfig(in_channels=16, depth=2, base_channels=4, max_channels=8, blocks=1)
    net = MultiReturnUNet(cfg)
    run = tmp_path / "run"
    run.mkdir()
    torch.save({"model_state": net.state_dict(), "optimizer_state": {"x": 1}, "epoch": 3}, run / CHECKPOINT)
    torch.save({"rt_state": {"w": torch.ones(3)}, "refiner_state": {"b": torch.zeros(2), "n": torch.tensor(7)}},
               run / STAGE2_CHECKPOINT)
    dest = P.install(run, {"command": "test"}, dest=tmp_path / "weights", half=True)
    ck = torch.load(dest / CHECKPOINT, weights_only=True)
    assert "optimizer_state" not in ck and ck["pretrained"] == {"command": "test"}
    assert all(v.dtype == torch.float16 for v in ck["model_state"].values() if v.is_floating_point())
    s2 = torch.load(dest / STAGE2_CHECKPOINT, weights_only=True)
    assert s2["rt_state"]["w"].dtype == torch.float16 and s2["refiner_state"]["n"].dtype == torch.int64
    back = MultiReturnUNet(cfg)
    back.load_state_dict(ck["model_state"])   # into float32 parameters
    for (name, a), b in zip(net.state_dict().items(), back.state_dict().values()):
        assert b.dtype == a.dtype, name
        if a.is_floating_point():
            assert torch.allclose(a, b, atol=1e-3, rtol=1e-3), name


def test_install_replaces_only_what_it_wrote(tmp_path):
    """A user's file in the destination, a foreign checkpoint or a symlink there: one-line refusal,
    nothing touched; a folder install wrote is replaced."""
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT
    from holodata.torch.train import CHECKPOINT

    run = tmp_path / "run"
    run.mkdir()
    torch.save({"model_state": {"w": torch.ones(2)}}, run / CHECKPOINT)
    torch.save({"rt_state": {"w": torch.ones(2)}}, run / STAGE2_CHECKPOINT)
    dest = P.install(run, {"command": "first"}, dest=tmp_path / "weights")
    assert P.install(run, {"command": "second"}, dest=dest) == dest   # its own folder: replaced
    assert torch.load(dest / CHECKPOINT, weights_only=True)["pretrained"] == {"command": "second"}

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(InputError, match="notes.txt"):
        P.install(run, {"command": "x"}, dest=mine)
    assert (mine / "notes.txt").read_text() == "keep me"
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    torch.save({"model_state": {}}, foreign / CHECKPOINT)
    with pytest.raises(InputError, match="not a file holodata's install wrote"):
        P.install(run, {"command": "x"}, dest=foreign)
    assert (foreign / CHECKPOINT).exists() and not (tmp_path / "foreign.tmp").exists()

    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "data.bin").write_bytes(b"1")
    link = tmp_path / "link"
    link.symlink_to(outside)
    with pytest.raises(InputError, match="symlink"):
        P.install(run, {"command": "x"}, dest=link)
    assert link.is_symlink() and (outside / "data.bin").read_bytes() == b"1"
