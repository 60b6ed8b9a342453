"""``holodata synth`` output folders as recordings: ``OUT/recording[.bag]`` (the data pass) beside
``OUT/truth/``, and ``OUT/mapping[.bag]`` (its mapping pass) when it has one."""
from __future__ import annotations

from pathlib import Path

SYNTH_RECORDINGS = ("recording", "recording.bag")  # holodata synth: OUT/recording[.bag] beside OUT/truth/
SYNTH_MAPPING = ("mapping", "mapping.bag")         # its mapping pass: OUT/mapping[.bag]


def synth_output_folder(path) -> Path | None:
    """``OUT`` when ``path`` is a ``holodata synth`` output folder (``OUT/truth/`` beside
    ``OUT/recording/`` or ``OUT/recording.bag``) or the recording inside one; else None."""
    p = Path(path)
    if p.name in SYNTH_RECORDINGS and (p.parent / "truth").is_dir():
        return p.parent
    if p.is_dir() and (p / "truth").is_dir() and any((p / n).exists() for n in SYNTH_RECORDINGS):
        return p
    return None


def synth_passes(path) -> list[Path]:
    """The recordings of a ``holodata synth`` output folder ``path``: its data pass, then its mapping
    pass when it has one; ``[path]`` for any other path (a recording itself)."""
    p, out = Path(path), synth_output_folder(path)
    if out is None or p != out:
        return [p]
    return [synth_output_recording(p)] + [out / n for n in SYNTH_MAPPING if (out / n).exists()][:1]


def synth_output_recording(path) -> Path:
    """The data-pass recording of a ``holodata synth`` output folder (:func:`synth_output_folder`);
    any other path unchanged."""
    p, out = Path(path), synth_output_folder(path)
    if out is None or p != out:
        return p
    return next(out / n for n in SYNTH_RECORDINGS if (out / n).exists())
