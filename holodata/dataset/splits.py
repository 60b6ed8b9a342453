"""Scene roles and the dataset's train/test splits.

**Roles.** A scene is a *data pass* (a radar recording: ground truth is traced for it, models train
and are scored on it) or a *mapping pass* (a LiDAR-only drive through the empty corner before the
data pass, as HoloRadar maps each corner first; ``slam --map-scene`` builds the mesh from it). Ingest
records the role in the scene attribute ``role``; a scene without one (written by other tools or an
older holodata) is a mapping pass when its frames are LiDAR scans (``frame_sensor: lidar``), else a
data pass: :func:`scene_role`.

**Splits** are set explicitly (``holodata split DS --test ID ...``; :func:`set_splits`) and hold data
passes only; a split that is missing or empty is an error naming that command, never a silent
fallback, and training on a scene of the test split (leakage) is refused: :func:`split_scenes`.
"""
from __future__ import annotations

from ..errors import DatasetError, InputError

ROLES = ("data", "mapping")
DATA, MAPPING = ROLES
ALL = "all"   # every data pass, whatever the splits say (e.g. scoring a whole dataset with --oracle)


def scene_role(attrs: dict) -> str:
    """The role of a scene with attributes ``attrs`` (module docstring)."""
    role = attrs.get("role")
    if role in ROLES:
        return role
    return MAPPING if attrs.get("frame_sensor") == "lidar" else DATA


def data_scenes(ds) -> list[str]:
    """Ids of the data passes of reader dataset ``ds``, in the dataset's order."""
    return [s for s in ds.scenes if scene_role(ds.scene(s).attrs) == DATA]


def _hint(url) -> str:
    return f"set the splits with: holodata split {url} --test SCENE [--test SCENE ...]"


def split_scenes(ds, split: str) -> list[str]:
    """Scene ids of split ``split`` of reader dataset ``ds`` (``"all"``: every data pass). A split the
    dataset does not record, an empty one, a mapping pass in it, or a scene in both train and test is
    one :class:`DatasetError` line."""
    if split == ALL:
        ids = data_scenes(ds)
        if not ids:
            raise DatasetError(f"{ds.url}: no data pass (every scene is a LiDAR-only mapping pass)")
        return ids
    splits = getattr(ds, "splits", None) or {}
    ids = list(splits.get(split) or [])
    if not ids:
        have = ", ".join(f"{k} ({len(v)})" for k, v in splits.items() if v) or "none set"
        raise DatasetError(f"{ds.url}: split {split!r} is {'empty' if split in splits else 'not recorded'} "
                           f"(splits: {have}); {_hint(ds.url)}")
    missing = [s for s in ids if s not in ds.scenes]
    if missing:
        raise DatasetError(f"{ds.url}: split {split!r} names unknown scene(s): {', '.join(missing)}")
    maps = [s for s in ids if scene_role(ds.scene(s).attrs) == MAPPING]
    if maps:
        raise DatasetError(f"{ds.url}: split {split!r} holds mapping pass {maps[0]!r} (LiDAR only, no radar to train "
                           f"or score on); {_hint(ds.url)}")
    if split == "train":   # training on a scene the model is then scored on
        both = [s for s in ids if s in set(splits.get("test") or [])]
        if both:
            raise DatasetError(f"{ds.url}: scene {both[0]!r} is in both the train and the test split (train/test "
                               f"leakage); {_hint(ds.url)}")
    return ids


def set_splits(url, test: list[str], train: list[str] | None = None) -> dict:
    """Record the dataset's splits: ``test`` (data passes held out) and ``train`` (default: every other
    data pass). Mapping passes are left out of both; a mapping pass named, an unknown scene, a scene in
    both, or an empty split is one :class:`InputError` line. Returns {"train": [...], "test": [...]}."""
    from .reader import open_dataset
    from .writer import create_dataset

    ds = open_dataset(url)
    data = data_scenes(ds)
    named = list(test) + list(train or [])
    unknown = [s for s in named if s not in ds.scenes]
    if unknown:
        raise InputError(f"{ds.url}: no scene {unknown[0]!r} (data passes: {', '.join(data) or 'none'})")
    maps = [s for s in named if s not in data]
    if maps:
        raise InputError(f"{ds.url}: scene {maps[0]!r} is a mapping pass (LiDAR only): it goes in no split")
    test = list(dict.fromkeys(test))
    train = list(dict.fromkeys(train)) if train else [s for s in data if s not in test]
    both = [s for s in train if s in test]
    if both:
        raise InputError(f"{ds.url}: scene {both[0]!r} is given for both train and test")
    for name, ids in (("test", test), ("train", train)):
        if not ids:
            raise InputError(f"{ds.url}: the {name} split would be empty (data passes: {', '.join(data) or 'none'})")
    create_dataset(url, created_by="holodata split").set_splits(train=train, test=test)
    return {"train": train, "test": test}
