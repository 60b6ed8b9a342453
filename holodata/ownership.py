"""What a command may delete or replace: only what holodata can prove it wrote (DESIGN.md §4 "Files").

One rule for every command that writes files outside a dataset (``synth``, ``export``, ``train``,
``evaluate``, ``demo``); datasets themselves are guarded by :mod:`holodata.dataset.store` (no write or
delete through a symlink out of the dataset) and :mod:`holodata.dataset.writer` (only Zarr nodes of
its own are replaced).

**The manifest.** An output folder holodata writes into holds ``.holodata-manifest.json``::

    {"format": "holodata-manifest/1", "created_by": "holodata synth", "whole": true,
     "entries": {"recording": {"kind": "dir", "ino": 1234, "names": "9f2c…", "by": "holodata synth"}, ...},
     "pending": {".recording.3f2a….partial": "holodata synth"}}

* ``entries``: each top-level name holodata put there, with what identifies it on disk (a folder's
  inode and a digest of the names directly in it; a file's inode, size and ``mtime_ns``). An entry
  counts as holodata's only while it still matches: a file the user edited, or a folder the user
  made anew under the same name, is theirs. Commands that share the folder with the user's own
  files (``synth``, ``export``) replace entries on this proof only.
* ``whole``: holodata created the folder, or it was empty when first claimed. A command that needs a
  folder of its own (a training run, a report, the demo: :func:`claim_folder`) takes only such a
  folder, and everything in it is then holodata's; :func:`remove_folder` removes only such a folder.
* ``pending``: hidden temp siblings (``.<name>.<uuid>.partial``) written before they are moved in
  place; a rerun after a kill removes the ones the manifest names, and nothing else.

Every refusal is one :class:`~holodata.errors.InputError` line naming the path, and ``--force`` (where
replacing is a user's real wish) lets a command replace a plain file or folder that is not holodata's.
Nothing here ever follows a symlink: an entry that is a symlink is never written through, replaced or
removed, with or without ``force``.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import uuid
from pathlib import Path

from .errors import InputError
from .safe_io import check_name, name_problem

MANIFEST = ".holodata-manifest.json"
FORMAT = "holodata-manifest/1"


def _identity(p: Path) -> dict | None:
    """What identifies ``p`` on disk (not following a symlink), None when absent."""
    try:
        st = p.lstat()
    except FileNotFoundError:
        return None
    if p.is_symlink():
        return {"kind": "symlink"}
    if p.is_dir():   # an inode is reused at once after a delete: the names in it tell a new folder apart
        names = hashlib.sha256("\0".join(sorted(os.listdir(p))).encode()).hexdigest()[:16]
        return {"kind": "dir", "ino": st.st_ino, "names": names}
    return {"kind": "file", "ino": st.st_ino, "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _remove(p: Path) -> None:
    """Remove file or folder ``p`` (a symlink: only the link). ``shutil.rmtree`` does not follow
    symlinks inside the folder."""
    if p.is_symlink() or not p.is_dir():
        p.unlink(missing_ok=True)
    else:
        shutil.rmtree(p)


def read_manifest(folder) -> dict | None:
    """The manifest of ``folder`` (see the module docstring), None when it has none; a manifest that
    is a symlink or not holodata's is one :class:`InputError` line."""
    m = Path(folder) / MANIFEST
    if m.is_symlink():
        raise InputError(f"{m}: is a symlink; holodata does not follow it (remove it or choose another --out)")
    try:
        d = json.loads(m.read_text())
    except (FileNotFoundError, NotADirectoryError):
        return None
    except (OSError, ValueError) as err:
        raise InputError(f"{m}: unreadable holodata manifest ({err.__class__.__name__}); remove it or choose "
                         f"another --out") from err
    if not isinstance(d, dict) or d.get("format") != FORMAT or not isinstance(d.get("entries", {}), dict) \
            or not isinstance(d.get("pending", {}), dict):
        raise InputError(f"{m}: not a holodata manifest ({FORMAT})")
    d.setdefault("entries", {})
    d.setdefault("pending", {})
    return d


class OutputDir:
    """The output folder ``path`` of command ``command`` (e.g. ``"holodata export"``).

    ``whole=True``: the command needs the whole folder (a run, a report): the folder must be new, empty,
    or already wholly holodata's, else :class:`InputError`. Otherwise it may share the folder with the
    user's own files and claims entries one by one. The folder is created when missing; ``path``
    itself may be a symlink the user made (their choice of where outputs go), names under it may not.
    """

    def __init__(self, path, command: str, whole: bool = False):
        self.path = Path(path).expanduser()
        self.command = command
        self.claimed_whole = whole
        self.manifest_path = self.path / MANIFEST
        if self.path.exists() and not self.path.is_dir():
            raise InputError(f"{self.path}: is a file, not a folder")
        created = not self.path.exists()
        self.path.mkdir(parents=True, exist_ok=True)
        self.data = read_manifest(self.path)
        if self.data is None:
            empty = created or not any(self.path.iterdir())
            if whole and not empty:
                raise InputError(f"{self.path}: not empty and not written by holodata (no {MANIFEST}); "
                                 f"{command} needs a new or empty folder: choose another --out")
            self.data = {"format": FORMAT, "created_by": command, "whole": empty, "entries": {}, "pending": {}}
            self._save()
        elif whole and not self.data.get("whole"):
            raise InputError(f"{self.path}: holds files holodata did not write; {command} needs a new or empty "
                             f"folder: choose another --out")
        if whole:   # the command writes names of its own choosing here: none may lead elsewhere
            link = next((c for c in self.path.iterdir() if c.is_symlink()), None)
            if link is not None:
                raise InputError(f"{link}: is a symlink; holodata does not write through it (remove it or choose "
                                 f"another --out)")
        self._sweep()

    # -- the manifest ----------------------------------------------------------------------------
    def _save(self) -> None:
        tmp = self.path / f".{MANIFEST}.{uuid.uuid4().hex}.partial"
        tmp.write_text(json.dumps(self.data, indent=1))
        os.replace(tmp, self.manifest_path)

    def _sweep(self) -> None:
        """Remove the temp siblings a killed run of any holodata command left (the manifest names them)."""
        pend = self.data.get("pending") or {}
        for name in pend:
            if name_problem(name) is None and name.endswith(".partial"):
                p = self.path / name
                if p.exists() or p.is_symlink():
                    _remove(p)
        if pend:
            self.data["pending"] = {}
            self._save()

    # -- ownership -------------------------------------------------------------------------------
    @property
    def whole(self) -> bool:
        """The command claimed the whole folder (``whole=True``) and it is wholly holodata's."""
        return self.claimed_whole and bool(self.data.get("whole"))

    def owns(self, name: str) -> bool:
        """Entry ``name`` is holodata's: recorded in the manifest and still what was written (or the
        command claimed the whole folder, which is wholly holodata's). A symlink never is."""
        p = self.path / check_name(name, "output name", self.path)
        ident = _identity(p)
        if ident is None or ident["kind"] == "symlink":
            return False
        if self.whole:
            return True
        rec = self.data["entries"].get(name)
        return rec is not None and {k: rec.get(k) for k in ident} == ident

    def check_free(self, name: str, force: bool = False) -> Path:
        """Path of entry ``name``, which the command may (re)write: absent, holodata's, or (``force``)
        a plain file or folder of the user's. Else one :class:`InputError` line naming it."""
        p = self.path / check_name(name, "output name", self.path)
        ident = _identity(p)
        if ident is None or self.owns(name):
            return p
        if ident["kind"] == "symlink":
            raise InputError(f"{p}: is a symlink; holodata does not write through or replace it (remove it or "
                             f"choose another --out)")
        if force:
            return p
        raise InputError(f"{p}: exists and was not written by holodata; move it away, choose another --out, or "
                         f"pass --force to replace it")

    def remove(self, name: str, force: bool = False) -> None:
        """Remove entry ``name`` if the command may (see :meth:`check_free`)."""
        p = self.check_free(name, force)
        if p.exists() or p.is_symlink():
            _remove(p)
        if self.data["entries"].pop(name, None) is not None:
            self._save()

    # -- writing ---------------------------------------------------------------------------------
    def temp(self, name: str, folder: bool = False) -> Path:
        """A new hidden temp sibling for entry ``name`` (``.<name>.<uuid>.partial``), recorded as pending
        first, so that a rerun after a kill removes it; a folder when ``folder``."""
        check_name(name, "output name", self.path)
        t = f".{name}.{uuid.uuid4().hex}.partial"
        self.data["pending"][t] = self.command
        self._save()
        p = self.path / t
        if folder:
            p.mkdir()
        return p

    def install(self, tmp: Path, name: str, force: bool = False) -> Path:
        """Move ``tmp`` (from :meth:`temp`, or any path on the same file system) to entry ``name``,
        replacing what was there if the command may (:meth:`check_free`), and record it."""
        p = self.check_free(name, force)
        if p.is_dir() and not p.is_symlink():   # os.replace cannot replace a folder: the old one goes aside first
            old = self.path / f".{name}.{uuid.uuid4().hex}.old.partial"
            self.data["pending"][old.name] = self.command
            self._save()
            os.replace(p, old)
            os.replace(tmp, p)
            shutil.rmtree(old)
        else:
            os.replace(tmp, p)
        self.record(name)
        return p

    def record(self, name: str) -> None:
        """Record entry ``name`` (written by this command) as holodata's, and drop its finished temps."""
        p = self.path / check_name(name, "output name", self.path)
        ident = _identity(p)
        if ident is None or ident["kind"] == "symlink":
            raise InputError(f"{p}: missing or a symlink after writing it")
        self.data["entries"][name] = {**ident, "by": self.command,
                                      "at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        pend = self.data["pending"]
        for t in [t for t in pend if not (self.path / t).exists()]:
            pend.pop(t)
        self._save()


def write_file(path, command: str, write, force: bool = False) -> Path:
    """Write the single output file ``path`` with ``write(temp_path)``: under a temp name beside it,
    moved in place when complete, replacing only a file holodata wrote there (or ``force``): the
    :class:`OutputDir` rule for a command's one file (``slam --ply``, ``slam --tum``)."""
    p = Path(path).expanduser()
    od = OutputDir(p.parent, command)
    od.check_free(p.name, force)
    tmp = od.temp(p.name)
    write(tmp)
    return od.install(tmp, p.name, force)


def claim_folder(path, command: str) -> OutputDir:
    """The whole folder ``path`` for ``command`` (a run, a report, the demo): new, empty or already
    holodata's, else one :class:`InputError` line."""
    return OutputDir(path, command, whole=True)


def remove_folder(path, command: str) -> None:
    """Remove folder ``path`` only when it is wholly holodata's (its manifest says so), else one
    :class:`InputError` line. Absent: nothing happens. A symlink is never followed or removed."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        return
    data = None if p.is_symlink() or not p.is_dir() else read_manifest(p)
    if data is None or not data.get("whole"):
        raise InputError(f"{p}: {command} would remove it, but holodata did not write it (no {MANIFEST} "
                         f"claiming the whole folder); move it away or choose another --out")
    shutil.rmtree(p)
