"""``holodata info``: scenes, frames, arrays (shape, dtype), stored vs raw size, compression, splits."""
from __future__ import annotations

import numpy as np

from ..beams import origin_summary
from . import shards as sh
from .reader import list_nodes, open_dataset, unfinished_line


def stored_bytes(store, path: str, kind: str, meta: dict) -> int:
    """Bytes on storage of the array at ``path``: from the manifest records for frame arrays (no
    listing), else by listing its chunks (ragged: values and offsets)."""
    if kind == "ragged":
        return _du(store, f"{path}/values/c") + _du(store, f"{path}/offsets/c")
    if kind == "frame":
        hd = meta.get("attributes", {}).get("holodata", {})
        if isinstance(hd.get("shards"), list):
            return int(sum(s.get("nbytes") or 0 for s in hd["shards"]))
        total = 0
        for n in store.list(f"{path}/{sh.MANIFEST_DIR}"):
            rec = store.get(f"{path}/{sh.MANIFEST_DIR}/{n}")
            if rec:
                import json

                total += int(json.loads(rec).get("nbytes") or 0)
        return total
    return _du(store, f"{path}/c")


def _du(store, key: str) -> int:
    if store.local:
        root = store.root / key
        return sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) if root.exists() else 0
    try:
        return int(store.fs.du(store._p(key)))
    except FileNotFoundError:
        return 0


def dataset_info(path_or_url) -> dict:
    """Summary dict of a dataset (see ``holodata info --json``)."""
    ds = open_dataset(path_or_url)
    scenes = []
    tot_raw = tot_stored = 0
    for sid in ds.scenes:
        s = ds.scene(sid)
        arrays = []
        for name, (kind, meta) in sorted(s.nodes().items()):
            path = f"{s.path}/{name}"
            if kind == "ragged":
                vm = list_nodes(ds.store, path).get("values", (None, {}))[1]
                om = list_nodes(ds.store, path).get("offsets", (None, {}))[1]
                shape, dtype = vm.get("shape", []), vm.get("data_type", "?")
                raw = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize + \
                    int(np.prod(om.get("shape", [0]), dtype=np.int64)) * 8
                stored = stored_bytes(ds.store, path, kind, meta)
                done = sum(1 for n in ds.store.list(f"{path}/{sh.MANIFEST_DIR}") if n.endswith(".json"))
                n_sh = meta.get("attributes", {}).get("holodata", {}).get("n_shards")
                entry = {"name": name, "kind": "ragged", "shape": shape, "dtype": dtype,
                         "offsets_shape": om.get("shape"), "shards_done": done, "shards": n_sh}
            else:
                shape, dtype = meta.get("shape", []), meta.get("data_type", "?")
                raw = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
                stored = stored_bytes(ds.store, path, kind, meta)
                entry = {"name": name, "kind": kind, "shape": shape, "dtype": dtype}
                if kind == "frame":
                    hd = meta.get("attributes", {}).get("holodata", {})
                    entry["shards"] = hd.get("n_shards")
                    entry["shards_done"] = sum(1 for n in ds.store.list(f"{path}/{sh.MANIFEST_DIR}")
                                               if n.endswith(".json"))
            entry.update({"dims": meta.get("attributes", {}).get("dims"), "units": meta.get("attributes", {}).get("units"),
                          "raw_bytes": raw, "stored_bytes": stored,
                          "compression_ratio": round(raw / stored, 2) if stored else None})
            arrays.append(entry)
            tot_raw += raw
            tot_stored += stored
        attrs = {k: v for k, v in s.attrs.items() if k not in ("gt",)}
        scenes.append({"scene": sid, "frames": s.n_frames, "attrs": attrs, "arrays": arrays,
                       "ingest_complete": s.ingest_complete, "unfinished": s.unfinished,
                       "beam_origin": origin_summary(dict(s.attrs))})
    return {"dataset": ds.url, "format_version": ds.format_version, "created_by": ds.meta.get("created_by"),
            "grid": ds.meta.get("grid"), "range_bins": ds.meta.get("range_bins"),
            "grid_source": ds.meta.get("grid_source"), "splits": ds.splits, "unfinished": ds.unfinished,
            "scenes": scenes, "frames": sum(s["frames"] for s in scenes),
            "raw_bytes": tot_raw, "stored_bytes": tot_stored,
            "compression_ratio": round(tot_raw / tot_stored, 2) if tot_stored else None}


def _mb(n: int) -> str:
    if n < 1000:
        return f"{n} B"
    return f"{n / 1e6:,.1f} MB" if n >= 1e5 else f"{n / 1e3:,.1f} kB"


def plural(n: int, word: str) -> str:
    """``1 frame``, ``2 frames``."""
    return f"{n} {word}" + ("" if n == 1 else "s")


def format_info(summary: dict) -> str:
    g = summary.get("grid") or {}
    rb = summary.get("range_bins") or {}
    lines = [f"{summary['dataset']}  (holodata format {summary['format_version']}, created by {summary.get('created_by')})",
             (f"grid {g.get('H')}×{g.get('W')} beams, elevation {g.get('elev_deg')} deg; {rb.get('n')} range bins of "
              f"{rb.get('dr')} m" if summary.get("grid_source") != "default" else
              "grid: no radar yet (the default 64×512 of docs/format.md §2 until a radar recording is ingested)"),
             f"{plural(len(summary['scenes']), 'scene')}, {plural(summary['frames'], 'frame')}; stored "
             f"{_mb(summary['stored_bytes'])} "
             f"of {_mb(summary['raw_bytes'])} raw (ratio {summary['compression_ratio']})"]
    for stage, rec in sorted((summary.get("unfinished") or {}).items()):
        lines.append(f"INCOMPLETE: {unfinished_line(stage, rec).split(': ', 1)[1]}")
    for s in summary["scenes"]:
        extra = ", ".join(f"{k}={v}" for k, v in s["attrs"].items() if k != "n_frames" and not isinstance(v, (dict, list)))
        lines.append(f"scene {s['scene']}: {plural(s['frames'], 'frame')}" + (f" ({extra})" if extra else ""))
        for stage, rec in sorted((s.get("unfinished") or {}).items()):
            lines.append(f"  INCOMPLETE: {unfinished_line(stage, rec).split(': ', 1)[1]}")
        if not s.get("unfinished") and not s.get("ingest_complete", True):
            lines.append("  INCOMPLETE: ingest did not finish (rerun holodata ingest with the same recording and "
                         "--scene-id to resume)")
        bo = s.get("beam_origin")
        if bo:
            lines.append(f"  beams: radar {bo['radar']}; gt {bo['gt'] or 'not traced'}")
            if bo["note"]:
                lines.append(f"  note: {bo['note']}")
        if s["arrays"]:
            lines.append(f"  {'array':<24} {'kind':<6} {'shape':<22} {'dtype':<8} {'unit':<4} {'stored':>10} / "
                         f"{'raw':>10}  ratio  shards")
        for a in s["arrays"]:
            shp = "x".join(str(v) for v in a["shape"]) or "scalar"
            done = f"{a['shards_done']}/{a['shards']}" if a.get("shards") is not None else "-"
            ratio = f"x{a['compression_ratio']}" if a["compression_ratio"] is not None else "-"
            lines.append(f"  {a['name']:<24} {a['kind']:<6} {shp:<22} {a['dtype']:<8} {a.get('units') or '':<4} "
                         f"{_mb(a['stored_bytes']):>10} / {_mb(a['raw_bytes']):>10}  {ratio:<6} {done}")
    splits = summary.get("splits") or {}
    lines.append("splits: " + ("; ".join(f"{k}: {', '.join(v) or '-'}" for k, v in splits.items()) or "none"))
    return "\n".join(lines)
