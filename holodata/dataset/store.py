"""Key/value access to a dataset's storage (local folder or fsspec URL) with atomic puts.

Local folders: a put writes ``.<name>.<uuid>.partial`` next to the target and renames it over the
target (``os.replace``: atomic on POSIX), so a reader or a killed writer never leaves a half object
under the real key. Object stores (``s3://``, ``gs://``, ``az://``, ``memory://`` ...): one
``pipe_file`` call per object. There is no atomic rename on an object store (a "move" is copy +
delete), but a PUT is: the object becomes visible whole or not at all (multipart uploads only on
CompleteMultipartUpload), and S3/GCS/Azure reads after a PUT are strongly consistent. So the
shard-then-manifest commit protocol of :mod:`.writer` holds there without any rename. Other fsspec
filesystems (sftp, ftp, smb, hdfs ...) may write in place: there a put goes to a ``.partial``
sibling first and is then moved over the key. Keys are ``/``-separated, relative to the root.

Several processes (Dask workers, the client) write one dataset concurrently, so the fsspec
listings cache (which would hide another process's new objects) is bypassed: every
``exists``/``list`` asks the store. Credentials and endpoints come from the environment / fsspec
config (``AWS_*`` incl. ``AWS_ENDPOINT_URL``, ``FSSPEC_S3_*``), never from the URL or the CLI.
"""
from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Any

from ..errors import DatasetError

# protocols whose single-object PUT is atomic (no in-place partial writes)
ATOMIC_PUT_PROTOCOLS = {"s3", "s3a", "gs", "gcs", "az", "abfs", "abfss", "adl", "oss", "memory", "r2", "b2"}


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
        self.fs: Any        # the fsspec filesystem of a URL, None for a local root
        self.root: Any      # a Path (local) or the fsspec path str (URL)
        if self.local:
            self.root = Path(s).expanduser()
            self.fs = None
        else:
            import fsspec

            try:
                self.fs, self.root = fsspec.core.url_to_fs(s)
            except (ImportError, ValueError) as err:
                raise DatasetError(f"{s}: cannot open URL ({err})") from err
            self.root = self.root.rstrip("/")
            protos = self.fs.protocol if isinstance(self.fs.protocol, (tuple, list)) else (self.fs.protocol,)
            self.atomic_put = bool(set(protos) & ATOMIC_PUT_PROTOCOLS)

    def _fresh(self, key: str = "") -> str:
        """Path of ``key`` with fsspec's listings cache for it dropped (other processes write too)."""
        p = self._p(key)
        self.fs.invalidate_cache(p)
        return p

    # -- paths ---------------------------------------------------------------------------------
    def _p(self, key: str):
        if self.local:
            return self.root / key if key else self.root
        return f"{self.root}/{key}" if key else self.root

    _real_root: str | None = None

    def _w(self, key: str):
        """Path of ``key`` for a write or delete: on a local root, refused (one :class:`DatasetError`
        line) when a symlink under the root lies on the way, which could lead the write outside the
        dataset (a ``scenes`` linked to ``../..``, say). The root itself may be a link (the user's
        choice of where the dataset lives)."""
        if ".." in key.split("/"):
            raise DatasetError(f"{self.url}: key {key!r} refused: '..' would name a path outside the dataset")
        p = self._p(key)
        if self.local and key:
            if self._real_root is None:
                self._real_root = os.path.realpath(self.root)
            want = os.path.join(self._real_root, os.path.normpath(key))
            if os.path.realpath(p) != want:
                raise DatasetError(f"{self.url}: {key} goes through a symlink inside the dataset (to "
                                   f"{os.path.realpath(p)}); holodata does not write or delete through it")
        return p

    def walk(self, key: str) -> tuple[list[str], list[str]]:
        """(files, symlinks) under folder ``key``, as keys relative to it; symlinks are not followed
        (object stores have none)."""
        files: list[str] = []
        links: list[str] = []
        if self.local:
            base = self._p(key)
            for d, dirs, names in os.walk(base, followlinks=False):
                rel = os.path.relpath(d, base)
                for n in dirs + names:
                    r = n if rel == "." else f"{rel}/{n}"
                    if os.path.islink(os.path.join(d, n)):
                        links.append(r)
                    elif n in names:
                        files.append(r)
        else:
            base = self._fresh(key).rstrip("/")
            files = [f[len(base) + 1:] for f in self.fs.find(base)]
        return sorted(files), sorted(links)

    def get(self, key: str) -> bytes | None:
        try:
            if self.local:
                return (self.root / key).read_bytes()
            return self.fs.cat_file(self._p(key))
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            return None

    def get_range(self, key: str, start: int, stop: int) -> bytes:
        """Bytes ``start:stop`` of object ``key`` (a shard's index or one chunk of it, without
        reading the rest); fewer when the object is shorter. FileNotFoundError when absent."""
        if self.local:
            with open(self.root / key, "rb") as f:
                f.seek(start)
                return f.read(max(stop - start, 0))
        return self.fs.cat_file(self._p(key), start=start, end=stop)

    _dirs: set | None = None

    def put(self, key: str, data) -> None:
        """Write ``data`` (bytes, or a list of bytes-like parts written one after the other) under
        ``key`` in one atomic step."""
        if isinstance(data, (list, tuple)) and not self.local:
            data = b"".join(data)
        if self.local:
            p = self._w(key)
            if self._dirs is None:
                self._dirs = set()
            if p.parent not in self._dirs:   # one mkdir per folder, not per put
                p.parent.mkdir(parents=True, exist_ok=True)
                self._dirs.add(p.parent)
            tmp = p.parent / f".{p.name}.{uuid.uuid4().hex}.partial"
            try:
                try:
                    f = open(tmp, "wb")  # noqa: SIM115 - closed by the "with f:" below, once it opened
                except FileNotFoundError:    # folder removed since (SceneWriter.remove): make it again
                    p.parent.mkdir(parents=True, exist_ok=True)
                    f = open(tmp, "wb")  # noqa: SIM115
                with f:
                    if isinstance(data, (list, tuple)):
                        f.writelines(data)
                    else:
                        f.write(data)
                os.replace(tmp, p)
            finally:
                if tmp.exists():
                    tmp.unlink()
        elif self.atomic_put:
            self.fs.pipe_file(self._p(key), bytes(data))
        else:
            p = self._p(key)
            d, name = p.rsplit("/", 1) if "/" in p else ("", p)
            tmp = f"{d}/.{name}.{uuid.uuid4().hex}.partial" if d else f".{name}.{uuid.uuid4().hex}.partial"
            if d:
                self.fs.makedirs(d, exist_ok=True)
            self.fs.pipe_file(tmp, bytes(data))
            try:
                self.fs.mv(tmp, p)
            finally:
                if self.fs.exists(tmp):
                    self.fs.rm_file(tmp)

    def exists(self, key: str) -> bool:
        if self.local:
            return (self.root / key).exists()
        return self.fs.exists(self._fresh(key))

    def is_file(self, key: str) -> bool:
        if self.local:
            return (self.root / key).is_file()
        return self.fs.isfile(self._fresh(key))

    def is_dir(self, key: str = "") -> bool:
        if self.local:
            return (self.root / key).is_dir()
        return self.fs.isdir(self._fresh(key))

    def delete(self, key: str) -> None:
        try:
            if self.local:
                self._w(key).unlink()
            else:
                self.fs.rm_file(self._p(key))
        except FileNotFoundError:
            pass

    def delete_tree(self, key: str) -> None:
        """Remove folder ``key`` and everything under it (absent: nothing happens)."""
        import shutil

        if self.local:
            self._dirs = None
            p = self._w(key)
            if p.is_symlink():
                raise DatasetError(f"{self.url}: {key} is a symlink; holodata does not delete through it")
            shutil.rmtree(p, ignore_errors=True)
        elif self.fs.exists(self._p(key)):
            self.fs.rm(self._p(key), recursive=True)

    def sweep_partials(self, key: str, older_than_s: float = 3600.0) -> int:
        """Remove the ``.partial`` temp objects under folder ``key`` left by writers killed mid-put
        and older than ``older_than_s`` (a younger one may belong to a writer still running, e.g.
        another Dask worker). Object stores with atomic PUTs never hold any. Returns how many went."""
        import time

        if not self.local and self.atomic_put:
            return 0
        now, n = time.time(), 0
        if self.local:
            d = self.root / key
            found = list(d.rglob(".*.partial")) if d.is_dir() else []
        else:
            found = [p for p in self.fs.find(self._fresh(key)) if p.rsplit("/", 1)[-1].startswith(".")
                     and p.endswith(".partial")]
        for p in found:
            try:
                if self.local:
                    mtime = p.stat().st_mtime
                else:
                    mtime = self.fs.modified(p).timestamp()
                if now - mtime > older_than_s:
                    self._w(str(p.relative_to(self.root))).unlink() if self.local else self.fs.rm_file(p)
                    n += 1
            except FileNotFoundError:   # finished or swept by another process meanwhile
                pass
        return n

    def list(self, key: str) -> list[str]:
        """Names (not paths) directly under folder ``key``; [] when absent. The ``.partial`` temp
        objects of puts in flight (or of writers killed mid-put) are not listed: they hold no data."""
        try:
            if self.local:
                d = self.root / key
                names = [p.name for p in d.iterdir()] if d.is_dir() else []
            else:
                names = [p.rstrip("/").rsplit("/", 1)[-1] for p in self.fs.ls(self._fresh(key), detail=False)]
        except (FileNotFoundError, NotADirectoryError):
            return []
        return sorted(n for n in names if not (n.startswith(".") and n.endswith(".partial")))

    def size(self, key: str) -> int:
        if self.local:
            return (self.root / key).stat().st_size
        return int(self.fs.size(self._fresh(key)))

    def zarr_store(self, read_only: bool):
        import zarr

        if self.local:
            return zarr.storage.LocalStore(self.root, read_only=read_only)
        return zarr.storage.FsspecStore.from_url(self.url, read_only=read_only)

    def __str__(self) -> str:
        return self.url


def close_filesystems(timeout: float = 5.0) -> int:
    """Close the HTTP sessions of this process's s3fs filesystems and drop them from fsspec's instance
    cache; returns how many sessions were closed. Call it when a command is done with its object store.

    Left to interpreter shutdown, aiohttp prints "Unclosed client session" / "client_session:
    <aiohttp.client.ClientSession ...>" on stderr for every session that is collected unclosed: s3fs
    closes a synchronous filesystem's session at exit only if that takes under 0.1 s (its fallback
    does not reach aiobotocore's connector any more), and never closes the asynchronous filesystems
    that zarr's ``FsspecStore`` opens to read arrays (their session lives on zarr's event loop). Here
    each session is closed on the event loop it was made on, while that loop still runs. A filesystem
    made later (the next command in this process) opens a new session."""
    import sys

    if "s3fs" not in sys.modules:
        return 0
    import asyncio

    import s3fs
    from fsspec.asyn import sync

    zarr_loop = None
    if "zarr.core.sync" in sys.modules:
        zloop = sys.modules["zarr.core.sync"].loop[0]
        zarr_loop = zloop if zloop is not None and zloop.is_running() else None
    closed = 0
    for fs in list(s3fs.S3FileSystem._cache.values()):
        creator = getattr(fs, "_s3creator", None)
        if getattr(fs, "_s3", None) is None or creator is None:
            continue
        try:
            if not fs.asynchronous:          # its session lives on fsspec's IO loop
                sync(fs.loop, creator.__aexit__, None, None, None, timeout=timeout)
            elif zarr_loop is not None:      # zarr's FsspecStore: its session lives on zarr's loop
                asyncio.run_coroutine_threadsafe(creator.__aexit__(None, None, None), zarr_loop).result(timeout)
            else:
                continue
        except Exception:  # noqa: BLE001 - a session that cannot be closed now is left as it was
            continue
        fs._s3 = None
        closed += 1
    s3fs.S3FileSystem.clear_instance_cache()
    return closed
