"""Files from elsewhere: datasets, checkpoints and recordings come from other labs.

No load path may run code from a file, and no name read from one (or given on the command line)
may write outside the output:

* torch files load with ``weights_only=True`` (tensors, numbers, strings, lists, tuples, dicts):
  :func:`load_torch`. A pickled Python object in one is refused, before anything of it runs.
* ``.npy`` / ``.npz`` load with ``allow_pickle=False`` (object arrays are refused).
* YAML is read with ``yaml.safe_load`` (a ``!!python/...`` tag is refused).
* A scene id, topic or archive member that becomes a file or folder name passes :func:`check_name`:
  not empty, not ``.`` or ``..``, no path separator (``/`` or ``\\``, so never absolute) and no NUL.

Each refusal is one :class:`~holodata.errors.InputError` line naming the file (or name) and why.
"""
from __future__ import annotations

import re
from pathlib import Path

from .errors import InputError

# what a name that becomes one path component may not hold (zarr and fsspec also read "\\" as "/")
_SEPARATORS = ("/", "\\")


def name_problem(name) -> str | None:
    """Why ``name`` cannot be one file or folder name under an output, or None when it can."""
    if not isinstance(name, str):
        return f"not a string ({type(name).__name__})"
    if not name:
        return "empty"
    if "\0" in name:
        return "holds a NUL character"
    if any(s in name for s in _SEPARATORS):
        return "holds a path separator ('/' or '\\'): it would name a file outside its folder"
    if name in (".", ".."):
        return f"is {name!r}: it would name a folder outside the output"
    return None


def check_name(name, what: str = "scene id", where=None, error=InputError) -> str:
    """``name`` when it is safe as one path component (see :func:`name_problem`); else ``error``
    (one line: ``where``, ``what`` and the reason)."""
    why = name_problem(name)
    if why is not None:
        raise error(f"{f'{where}: ' if where else ''}{what} {name!r} refused: {why}")
    return name


_GLOBAL = re.compile(r"Unsupported global: GLOBAL ([\w.]+)")


def load_torch(path, what: str = "checkpoint") -> dict:
    """A torch file of tensors and plain data as a dict, loaded with ``weights_only=True`` onto the
    CPU. A file that pickles any other object (which could run code on load) is refused, as is a
    file that is not a torch file or holds no dict: one :class:`InputError` line each."""
    import pickle

    import torch

    p = Path(path)
    try:
        obj = torch.load(p, map_location="cpu", weights_only=True)
    except FileNotFoundError as err:
        raise InputError(f"{p}: no such {what}") from err
    except pickle.UnpicklingError as err:
        m = _GLOBAL.search(str(err))
        if m:
            raise InputError(f"{p}: {what} refused: it pickles a Python object ({m.group(1)}), which could run code "
                             "when loaded; holodata loads only tensors and plain data (torch.load weights_only=True)"
                             ) from err
        raise InputError(f"{p}: not a holodata {what} (not a torch file of tensors and plain data)") from err
    except Exception as err:  # noqa: BLE001 - corrupt/truncated file
        raise InputError(f"{p}: not a holodata {what} ({err.__class__.__name__})") from err
    if not isinstance(obj, dict):
        raise InputError(f"{p}: not a holodata {what} (holds a {type(obj).__name__}, not a dict)")
    return obj


def load_npz(path, what: str = ".npz file") -> dict:
    """All arrays of an ``.npz`` as a dict, without pickles (object arrays refused): one
    :class:`InputError` line when the file cannot be read so."""
    import numpy as np

    p = Path(path)
    try:
        z = np.load(p, allow_pickle=False)
    except FileNotFoundError as err:
        raise InputError(f"{p}: no such {what}") from err
    except (OSError, ValueError, EOFError) as err:
        raise InputError(f"{p}: not a readable {what} ({' '.join(str(err).split())[:120]})") from err
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise InputError(f"{p}: not a readable {what} (one array, not an .npz archive)")
    with z:
        try:
            return {k: z[k] for k in z.files}
        except Exception as err:  # noqa: BLE001 - object arrays (pickles), truncated members
            raise InputError(f"{p}: not a readable {what} ({' '.join(str(err).split())[:120]})") from err
