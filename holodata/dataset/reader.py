"""Read-only, lazy access to a holodata dataset (local path or fsspec URL)."""
from __future__ import annotations

import json

import numpy as np

from ..conventions import FORMAT_VERSION, Grid, RangeBins
from ..errors import DatasetError
from ..safe_io import name_problem
from . import shards as sh
from .store import Store

SUPPORTED_MAJOR = int(FORMAT_VERSION.split(".")[0])


def _version(v) -> tuple[int, int]:
    try:
        major, minor = (int(x) for x in str(v).split(".")[:2])
        return major, minor
    except ValueError as err:
        raise DatasetError(f"unreadable format_version {v!r}") from err


def check_root(url: str, root: dict) -> dict:
    """The ``holodata`` root attributes of a parsed root ``zarr.json``, or a one-line DatasetError."""
    if root.get("zarr_format") != 3 or root.get("node_type") != "group":
        raise DatasetError(f"{url}: not a holodata dataset (root zarr.json is not a Zarr v3 group)")
    meta = root.get("attributes", {}).get("holodata")
    if not isinstance(meta, dict) or "format_version" not in meta:
        raise DatasetError(f"{url}: a Zarr group but not a holodata dataset (no 'holodata' root attribute)")
    try:
        major, _ = _version(meta["format_version"])
    except DatasetError as err:
        raise DatasetError(f"{url}: {err}") from err
    if major < SUPPORTED_MAJOR:
        raise DatasetError(f"{url}: format_version {meta['format_version']} is too old for this holodata "
                           f"(reads {SUPPORTED_MAJOR}.x); re-create the dataset with this holodata "
                           f"(re-run ingest / raytrace-gt)")
    if major > SUPPORTED_MAJOR:
        raise DatasetError(f"{url}: format_version {meta['format_version']} is too new for this holodata "
                           f"(reads {SUPPORTED_MAJOR}.x); upgrade holodata (pip install -U holodata)")
    for k in ("grid", "range_bins"):
        if not isinstance(meta.get(k), dict):
            raise DatasetError(f"{url}: holodata root attribute lacks {k!r}")
    return meta


def _read_json(store: Store, key: str) -> dict | None:
    b = store.get(key)
    if b is None:
        return None
    try:
        return json.loads(b)
    except ValueError as err:
        raise DatasetError(f"{store.url}: {key} is not valid JSON") from err


def list_nodes(store: Store, path: str) -> dict[str, tuple[str, dict]]:
    """Arrays and ragged groups under group ``path``: {relative name: (kind, zarr.json dict)} with
    kind 'frame' | 'array' | 'ragged' | 'zarr' (a plain zarr array written by something else)."""
    out: dict[str, tuple[str, dict]] = {}

    def walk(rel: str) -> None:
        base = f"{path}/{rel}" if rel else path
        for name in store.list(base):
            if name in ("c", sh.MANIFEST_DIR) or name.startswith("."):
                continue
            meta = _read_json(store, f"{base}/{name}/zarr.json")
            if meta is None:
                continue
            r = f"{rel}/{name}" if rel else name
            kind = meta.get("attributes", {}).get("holodata", {}).get("kind")
            if meta.get("node_type") == "array":
                out[r] = (kind if kind in ("frame", "array") else "zarr", meta)
            elif kind == "ragged":
                out[r] = ("ragged", meta)
            else:
                walk(r)

    walk("")
    return out


def unfinished_line(stage: str, rec: dict) -> str:
    """The validate line of a stage that marked its scene (or the dataset) unfinished."""
    if stage == "ingest" and (rec or {}).get("legacy"):
        return ("unfinished: ingest did not finish (scene attrs ingest.complete is false: rerun holodata ingest "
                "with the same recording and --scene-id to resume)")
    since = f" since {rec['since']}" if isinstance(rec, dict) and rec.get("since") else ""
    hint = (rec or {}).get("rerun") if isinstance(rec, dict) else None
    return f"unfinished: {stage} did not finish (interrupted, or still running{since}): {hint or f'rerun holodata {stage}'}"


def open_dataset(path_or_url) -> Dataset:
    """Open a dataset read-only and lazily. Bad paths raise a one-line :class:`DatasetError`."""
    return Dataset(path_or_url)


class Dataset:
    """``attrs``, ``grid``, ``range_bins``, ``scenes`` (ids), ``splits``, ``scene(id)``."""

    def __init__(self, path_or_url):
        self.url = str(path_or_url)
        self.store = store = Store(path_or_url)
        try:
            if store.local:
                if not store.root.exists():
                    raise DatasetError(f"{self.url}: no such dataset (path does not exist)")
                if not store.root.is_dir():
                    raise DatasetError(f"{self.url}: is a file, not a dataset folder")
            elif not store.exists(""):
                raise DatasetError(f"{self.url}: no such dataset (URL does not exist)")
            root = _read_json(store, "zarr.json")
        except PermissionError as err:
            raise DatasetError(f"{self.url}: permission denied") from err
        if root is None:
            if not store.is_dir():
                raise DatasetError(f"{self.url}: is a file, not a dataset folder")
            raise DatasetError(f"{self.url}: not a holodata dataset (no zarr.json)")
        self.meta = check_root(self.url, root)
        self.attrs = root.get("attributes", {})
        self.format_version = self.meta["format_version"]
        self.grid = Grid.from_attrs(self.meta["grid"])
        self.range_bins = RangeBins.from_attrs(self.meta["range_bins"])
        self.splits = {k: list(v) for k, v in (self.meta.get("splits") or {}).items()}
        self.provenance = self.meta.get("provenance") or {}
        self.unfinished = dict(self.meta.get("unfinished") or {})   # root marks (DatasetWriter.begin)
        self._zgroup = None

    @property
    def zgroup(self):
        if self._zgroup is None:
            import zarr

            self._zgroup = zarr.open_group(self.store.zarr_store(read_only=True), mode="r")
        return self._zgroup

    @property
    def scenes(self) -> list[str]:
        return [n for n in self.store.list("scenes") if self.store.is_file(f"scenes/{n}/zarr.json")]

    def scene(self, scene_id: str) -> Scene:
        why = name_problem(scene_id)   # '..' would be the dataset root, 'a\\b' a nested group
        if why is not None:
            raise DatasetError(f"{self.url}: scene id {scene_id!r} refused: {why}")
        meta = _read_json(self.store, f"scenes/{scene_id}/zarr.json")
        if meta is None:
            raise DatasetError(f"{self.url}: no scene {scene_id!r} (have: {', '.join(self.scenes) or 'none'})")
        return Scene(self, scene_id, meta)

    def __repr__(self) -> str:
        return f"<holodata Dataset {self.url} v{self.format_version} scenes={self.scenes}>"


class Scene:
    """One scene: ``attrs``, ``n_frames``, ``arrays()``, ``s[name]`` (lazy zarr array, or a
    :class:`Ragged` for ragged arrays), ``ragged(name, frame)``."""

    def __init__(self, ds: Dataset, scene_id: str, meta: dict):
        self.ds, self.id = ds, scene_id
        self.path = f"scenes/{scene_id}"
        self.attrs = meta.get("attributes", {})
        self.n_frames = int(self.attrs.get("n_frames", 0))
        self._nodes: dict[str, tuple[str, dict]] | None = None
        self._ragged: dict[str, Ragged] = {}
        self._shard_index: dict = {}   # shard key -> its parsed index (read_frame)

    def nodes(self) -> dict[str, tuple[str, dict]]:
        if self._nodes is None:
            self._nodes = list_nodes(self.ds.store, self.path)
        return self._nodes

    def arrays(self) -> list[str]:
        """Names of the scene's arrays ('gt/range', 'lidar/points', ...), sorted."""
        return sorted(self.nodes())

    def __contains__(self, name: str) -> bool:
        return name in self.nodes()

    def __getitem__(self, name: str):
        nodes = self.nodes()
        if name not in nodes:
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} has no array {name!r}")
        if nodes[name][0] == "ragged":
            return self._get_ragged(name)
        return self.ds.zgroup[f"{self.path}/{name}"]

    def frame(self, name: str, k: int) -> np.ndarray:
        """Frame ``k`` of array ``name`` as stored (its own dtype: a uint8 heatmap stays codes,
        :func:`holodata.dataset.heatmap.read_heatmap` decodes). Holodata's frame arrays are read
        chunk by chunk straight from the shard (:func:`holodata.dataset.shards.read_frame`), any
        other array through zarr. A damaged shard raises a one-line DatasetError."""
        nodes = self.nodes()
        if name not in nodes or nodes[name][0] == "ragged":
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} has no frame array {name!r}")
        kind, meta = nodes[name]
        if not 0 <= int(k) < int(meta["shape"][0]):
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} array {name!r} has no frame {k} "
                               f"({meta['shape'][0]} frames)")
        if kind == "frame":
            try:
                out = sh.read_frame(self.ds.store, f"{self.path}/{name}", meta, int(k), self._shard_index)
            except ValueError as err:
                raise DatasetError(f"{self.ds.url}: scene {self.id!r} array {name!r} frame {k}: {err}") from err
            if out is not None:
                return out
        return np.asarray(self[name][int(k)])

    def _get_ragged(self, name: str) -> Ragged:
        if name not in self._ragged:
            self._ragged[name] = Ragged(self, name)
        return self._ragged[name]

    def ragged(self, name: str, frame: int) -> np.ndarray:
        """Frame ``frame`` of ragged array ``name``: (Ni, width)."""
        if name not in self.nodes() or self.nodes()[name][0] != "ragged":
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} has no ragged array {name!r}")
        return self._get_ragged(name)[frame]

    @property
    def unfinished(self) -> dict:
        """{stage: {since, rerun}}: the stages that marked this scene unfinished before their first
        write and have not cleared the mark after their last (interrupted, or still running; scene
        attribute ``unfinished``, :meth:`holodata.dataset.SceneWriter.begin`). Scenes written before
        the mark existed: an ``ingest`` whose ``ingest.complete`` is false counts as unfinished."""
        out = dict(self.attrs.get("unfinished") or {})
        ing = self.attrs.get("ingest")
        if isinstance(ing, dict) and not ing.get("complete", True) and "ingest" not in out:
            by = str(ing.get("by") or "ingest")
            out["ingest"] = {"rerun": f"rerun {'holodata ' if not by.startswith('holodata') else ''}{by} with the same "
                                      f"inputs to finish it", "legacy": "ingest.complete false"}
        return out

    @property
    def ingest_complete(self) -> bool:
        """False while the ``ingest`` that made this scene has not finished (interrupted, or still
        running); True for scenes made by other writers."""
        return "ingest" not in self.unfinished

    def require_complete(self, stage: str) -> None:
        """Raise :class:`DatasetError` (one line) when another stage left this scene unfinished
        (:attr:`unfinished`): ``stage`` would otherwise run on arrays that stage had not finished
        writing. A mark of ``stage`` itself does not stop it: its rerun resumes and clears it."""
        left = {k: v for k, v in self.unfinished.items() if k != stage}
        if not left:
            return
        if "ingest" in left:
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} was not ingested completely (interrupted?): rerun "
                               f"holodata ingest with the same recording and --scene-id to finish it before {stage}")
        name, rec = next(iter(sorted(left.items())))
        raise DatasetError(f"{self.ds.url}: scene {self.id!r} is unfinished: {name} did not finish (interrupted?): "
                           f"{(rec or {}).get('rerun') or f'rerun holodata {name}'} before {stage}")

    def is_done(self, name: str, k: int) -> bool:
        """Shard ``k`` of frame/ragged array ``name`` is committed."""
        return self.ds.store.exists(sh.manifest_key(f"{self.path}/{name}", k))

    def __repr__(self) -> str:
        return f"<holodata Scene {self.id} frames={self.n_frames} arrays={self.arrays()}>"


class Ragged:
    """Ragged array: ``values`` (N, width) and ``offsets`` (T+1,) lazy zarr arrays; ``r[i]`` is
    frame i's (Ni, width) rows, read-only (a view of the shard read at once when frames are read in
    order; frames of uncommitted shards raise DatasetError); ``r[a:b]`` is the list of those frames'
    arrays."""

    def __init__(self, scene: Scene, name: str):
        self.scene, self.name = scene, name
        path = f"{scene.path}/{name}"
        g = scene.ds.zgroup
        self.values = g[f"{path}/values"]
        self.offsets = g[f"{path}/offsets"]
        hd = scene.nodes()[name][1].get("attributes", {}).get("holodata", {})
        self.width = int(hd.get("width", self.values.shape[1]))
        self.shard_frames = int(hd.get("shard_frames", 1))
        self._off = None
        self._done: set[int] = set()
        self._last = -2        # last frame read: sequential reads load the rest of the shard at once
        self._block = None     # (first frame, end frame, first row, rows) of that shard's remainder

    def __len__(self) -> int:
        return self.scene.n_frames

    def __getitem__(self, frame):
        T = self.scene.n_frames
        if isinstance(frame, slice):
            return [self[i] for i in range(*frame.indices(T))]
        if not isinstance(frame, (int, np.integer)):
            raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r}: index with a frame number or a slice "
                               f"(frames a..b-1: [a:b]), not {type(frame).__name__}")
        frame = int(frame)
        if not -T <= frame < T:
            raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r}: frame {frame} out of range 0..{T - 1}")
        frame %= T
        k = frame // self.shard_frames
        if k not in self._done:
            if not self.scene.is_done(self.name, k):
                raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r} frame {frame}: shard {k} not written")
            self._done.add(k)
            self._off = None
        if self._off is None:
            self._off = np.asarray(self.offsets[...])
            self._block = None
        a, b = int(self._off[frame]), int(self._off[frame + 1])
        sequential, self._last = frame == self._last + 1, frame
        blk = self._block
        if blk is None or not blk[0] <= frame < blk[1]:
            if not sequential:   # random access: only this frame's rows
                rows = np.asarray(self.values[a:b])
                rows.flags.writeable = False
                return rows
            # a frame's rows straddle compressed chunks: one read per shard instead of one per frame
            end = min((k + 1) * self.shard_frames, T)
            rows = np.asarray(self.values[a:int(self._off[end])])
            rows.flags.writeable = False   # frames are handed out as views of it, not copies
            blk = self._block = (frame, end, a, rows)
        return blk[3][a - blk[2]:b - blk[2]]
