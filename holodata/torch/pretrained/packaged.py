"""The shipped run's location and its bookkeeping: :func:`resolve` (the name ``"pretrained"`` or any run
path → a path), :func:`scores` (the numbers recorded per method) and :func:`install` (a run copied here
without optimiser state, with its record). The package face (:mod:`holodata.torch.pretrained`) says what
the weights are."""
from __future__ import annotations

import shutil
from pathlib import Path

NAME = "pretrained"
WEIGHTS = Path(__file__).resolve().parent / "weights"
# the held-out corners tests/test_pretrained.py rebuilds (CorpusConfig fields; corpus seed 1000000 is
# the held-out rule of benchmarks/stage1_loss.py and benchmarks/nlos.py, never trained or tuned on)
CHECK_SET = {"corners": 2, "frames": 2, "seed": 1_000_000, "n_test": 2}
# the numbers recorded per method of ``holodata evaluate``'s metrics document (see :func:`scores`)
SCORE_KEYS = ("b1_median_cm", "b2_median_cm", "b3_median_cm", "los_f", "nlos_f", "human_f")


def resolve(spec) -> Path:
    """The run directory or checkpoint file ``spec`` names: ``"pretrained"`` is the packaged run."""
    from holodata.errors import InputError

    if str(spec) != NAME:
        return Path(spec)
    if not (WEIGHTS / "checkpoint.pt").exists():
        raise InputError(f"{WEIGHTS}: holodata's pretrained weights are not installed "
                         "(benchmarks/nlos.py --install writes them)")
    return WEIGHTS


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


def install(run: Path, record: dict, dest: Path = WEIGHTS) -> Path:
    """Copy ``run``'s checkpoint.pt and stage2.pt into ``dest`` without optimiser state, with
    ``record`` (command, commit, data settings, scores) under the key ``"pretrained"``."""
    from holodata.safe_io import load_torch
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT
    from holodata.torch.train import CHECKPOINT, _atomic_save

    tmp = dest.with_name(dest.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in (CHECKPOINT, STAGE2_CHECKPOINT):
        ck = load_torch(Path(run) / name, name)
        ck.pop("optimizer_state", None)
        ck["pretrained"] = record
        _atomic_save(ck, tmp / name)
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    return dest
