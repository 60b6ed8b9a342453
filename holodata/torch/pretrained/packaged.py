"""The shipped run's location and its bookkeeping: :func:`resolve` (the name ``"pretrained"`` or any run
path → a path), :func:`scores` (the numbers recorded per method) and :func:`install` (a run copied here
without optimiser state, with its record). The package face (:mod:`holodata.torch.pretrained`) says what
the weights are."""
from __future__ import annotations

import shutil
from pathlib import Path

NAME = "pretrained"
HERE = Path(__file__).resolve().parent
WEIGHTS = HERE / "weights"
# one run per beam grid ("HxW"), each in its own folder (a package listed in pyproject.toml);
# ``--checkpoint pretrained`` takes the one trained for the dataset's grid
GRID_DIRS = {"32x128": WEIGHTS, "64x512": HERE / "weights_64x512"}
DEFAULT_GRID = "32x128"
# the held-out corners tests/torch_/test_pretrained.py rebuilds (CorpusConfig fields; corpus seed 1000000 is
# the held-out rule of benchmarks/stage1_loss.py and benchmarks/nlos.py, never trained or tuned on)
CHECK_SET = {"corners": 2, "frames": 2, "seed": 1_000_000, "n_test": 2}
# the numbers recorded per method of ``holodata evaluate``'s metrics document (see :func:`scores`)
SCORE_KEYS = ("b1_median_cm", "b2_median_cm", "b3_median_cm", "los_f", "nlos_f", "human_f")
# the tensors stored as float16 by :func:`install` (``half=True``): the networks' weights; a model
# loads them into its float32 parameters (``load_state_dict`` converts)
HALF_KEYS = ("model_state", "rt_state", "refiner_state")


def grid_key(grid) -> str:
    """"HxW" of a :class:`holodata.conventions.Grid` (or such a string itself)."""
    return grid if isinstance(grid, str) else f"{grid.H}x{grid.W}"


def installed() -> dict[str, Path]:
    """{grid "HxW": run directory} of the shipped runs present in this installation."""
    return {k: d for k, d in GRID_DIRS.items() if (d / "checkpoint.pt").is_file()}


def resolve(spec, grid=None) -> Path:
    """The run directory or checkpoint file ``spec`` names: ``"pretrained"`` is the packaged run trained
    for ``grid`` (a Grid or "HxW"; None: the quick demo's 32x128). A grid holodata ships no weights for
    is one InputError line naming the grids it has."""
    from holodata.errors import InputError

    if str(spec) != NAME:
        return Path(spec)
    key = grid_key(grid) if grid is not None else DEFAULT_GRID
    have = installed()
    if key not in have:
        if not have:
            raise InputError(f"{WEIGHTS}: holodata's pretrained weights are not installed "
                             "(benchmarks/nlos.py --install writes them)")
        raise InputError(f"holodata ships no pretrained weights for the {key} beam grid (it has {', '.join(sorted(have))}); "
                         "train a model on this dataset (holodata train) or use a dataset of a grid it has")
    return have[key]


def scores(doc: dict) -> dict:
    """{method: {SCORE_KEYS}} of an evaluation document: range-image median error per bounce (cm)
    and the F-score of the LOS, NLOS and human point clouds."""
    out = {}
    for method, m in doc["methods"].items():
        rng, pts = m.get("range") or {}, m.get("points") or {}
        row = {f"b{b}_median_cm": (rng.get(f"bounce_{b}") or {}).get("median_cm") for b in (1, 2, 3)}
        row.update({f"{k}_f": (pts.get(k) or m.get(k) or {}).get("f_score") for k in ("los", "nlos")})
        row["human_f"] = (m.get("human") or {}).get("f_score")
        out[method] = {k: float(v) for k, v in row.items() if v is not None}
    return out


def install(run: Path, record: dict, dest: Path = WEIGHTS, half: bool = False) -> Path:
    """Copy ``run``'s checkpoint.pt and stage2.pt into ``dest`` (:data:`GRID_DIRS` of the run's grid)
    without optimiser state, with ``record`` (command, commit, data settings, scores) under the key
    ``"pretrained"``; ``half``: the networks' weights (:data:`HALF_KEYS`) stored as float16."""
    from holodata.safe_io import load_torch
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT
    from holodata.torch.train import CHECKPOINT, _atomic_save

    dest = Path(dest)
    tmp = dest.with_name(dest.name + ".tmp")
    for folder in (tmp, dest):   # replaced only when it is a shipped run install wrote
        _check_replaceable(folder)
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in (CHECKPOINT, STAGE2_CHECKPOINT):
        ck = load_torch(Path(run) / name, name)
        ck.pop("optimizer_state", None)
        ck["pretrained"] = record
        if half:
            for key in HALF_KEYS:
                if isinstance(ck.get(key), dict):
                    ck[key] = {k: v.half() if v.is_floating_point() else v for k, v in ck[key].items()}
        _atomic_save(ck, tmp / name)
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    return dest


def _check_replaceable(folder: Path) -> None:
    """InputError (one line) unless ``folder`` is absent or a real folder holding only the run files
    :func:`install` writes, each with its ``"pretrained"`` record: a symlink, a user's file or a
    checkpoint install did not write is never removed."""
    from holodata.errors import InputError
    from holodata.safe_io import load_torch
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT
    from holodata.torch.train import CHECKPOINT

    if not folder.exists() and not folder.is_symlink():
        return
    if folder.is_symlink() or not folder.is_dir():
        raise InputError(f"{folder}: not a folder install wrote (a symlink or a file); refusing to replace it")
    for entry in folder.iterdir():
        if entry.name not in (CHECKPOINT, STAGE2_CHECKPOINT) or entry.is_symlink() or not entry.is_file() \
                or "pretrained" not in load_torch(entry, entry.name):
            raise InputError(f"{entry}: not a file holodata's install wrote; refusing to replace {folder}")
