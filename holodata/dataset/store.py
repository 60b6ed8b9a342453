"""Key/value access to a dataset's storage (local folder or fsspec URL) with atomic puts.

Local folders: a put writes ``.<name>.<uuid>.partial`` next to the target and renames it over the
target (``os.replace``: atomic on POSIX), so a reader or a killed writer never leaves a half object
under the real key. fsspec URLs: one ``pipe_file`` call per object (object stores PUT atomically;
``memory://`` assigns the whole buffer). Keys are ``/``-separated, relative to the dataset root.
"""
from __future__ import annotations

import os
import uuid
from pathlib import Path

from ..errors import DatasetError


def is_url(path_or_url: str) -> bool:
    s = str(path_or_url)
    return "://" in s and not s.startswith("file://")


class Store:
    """A dataset root: ``get``/``put``(atomic)/``exists``/``delete``/``list`` plus a zarr store."""

    def __init__(self, path_or_url: str | os.PathLike):
        s = str(path_or_url)
        if s.startswith("file://"):
            s = s[len("file://"):]
        self.url = s
        self.local = not is_url(s)
        if self.local:
            self.root = Path(s).expanduser()
            self.fs = None
        else:
            import fsspec

            try:
                self.fs, self.root = fsspec.core.url_to_fs(s)
            except (ImportError, ValueError) as err:
                raise DatasetError(f"{s}: cannot open URL ({err})") from None
            self.root = self.root.rstrip("/")

    # -- paths ---------------------------------------------------------------------------------
    def _p(self, key: str):
        if self.local:
            return self.root / key if key else self.root
        return f"{self.root}/{key}" if key else self.root

    def get(self, key: str) -> bytes | None:
        try:
            if self.local:
                return (self.root / key).read_bytes()
            return self.fs.cat_file(self._p(key))
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            return None

    def put(self, key: str, data: bytes) -> None:
        """Write ``data`` under ``key`` in one atomic step."""
        if self.local:
            p = self.root / key
            p.parent.mkdir(parents=True, exist_ok=True)
            tmp = p.parent / f".{p.name}.{uuid.uuid4().hex}.partial"
            try:
                with open(tmp, "wb") as f:
                    f.write(data)
                os.replace(tmp, p)
            finally:
                if tmp.exists():
                    tmp.unlink()
        else:
            self.fs.pipe_file(self._p(key), bytes(data))

    def exists(self, key: str) -> bool:
        if self.local:
            return (self.root / key).exists()
        return self.fs.exists(self._p(key))

    def is_file(self, key: str) -> bool:
        if self.local:
            return (self.root / key).is_file()
        return self.fs.isfile(self._p(key))

    def is_dir(self, key: str = "") -> bool:
        if self.local:
            return (self.root / key).is_dir()
        return self.fs.isdir(self._p(key))

    def delete(self, key: str) -> None:
        try:
            if self.local:
                (self.root / key).unlink()
            else:
                self.fs.rm_file(self._p(key))
        except FileNotFoundError:
            pass

    def delete_tree(self, key: str) -> None:
        """Remove folder ``key`` and everything under it (absent: nothing happens)."""
        import shutil

        if self.local:
            shutil.rmtree(self.root / key, ignore_errors=True)
        elif self.fs.exists(self._p(key)):
            self.fs.rm(self._p(key), recursive=True)

    def list(self, key: str) -> list[str]:
        """Names (not paths) directly under folder ``key``; [] when absent."""
        try:
            if self.local:
                d = self.root / key
                return sorted(p.name for p in d.iterdir()) if d.is_dir() else []
            return sorted(p.rstrip("/").rsplit("/", 1)[-1] for p in self.fs.ls(self._p(key), detail=False))
        except (FileNotFoundError, NotADirectoryError):
            return []

    def size(self, key: str) -> int:
        if self.local:
            return (self.root / key).stat().st_size
        return int(self.fs.size(self._p(key)))

    def zarr_store(self, read_only: bool):
        import zarr

        if self.local:
            return zarr.storage.LocalStore(self.root, read_only=read_only)
        return zarr.storage.FsspecStore.from_url(self.url, read_only=read_only)

    def __str__(self) -> str:
        return self.url
