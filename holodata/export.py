"""``holodata export``: hand a dataset's scenes to other tools, streamed frame by frame.

``panoradar`` — PanoRadar's processed layout (``process_raw_data.py`` / ``data/dataset.py``; what
:mod:`holodata.readers.npy_folder` reads back), one trajectory folder per scene::

    OUT/<scene>/rf_npy/00000.npy     (R, H, W) float32  log10(a + 1e-3) / 3 of radar/heatmap
    OUT/<scene>/lidar_npy/00000.npy  (1, H, W) float32  range / 10 m along the radar's beams, -1e3 none
    OUT/<scene>/gt_npy/00000.npy     (B, H, W) float32  holodata's multi-bounce gt/range (m), NaN none
    OUT/<scene>/label_npy/00000.npy  (B, H, W) uint8    gt/label (holodata.conventions labels)
    OUT/<scene>/holodata.json        what was exported from where, grid, range bins, columns

PanoRadar's LiDAR images are the LiDAR's ranges projected onto the radar's beam grid, the first
return along every beam; holodata's equivalent is ``gt/range`` bounce 1 (the mesh hit along each
beam), which is what ``lidar_npy`` holds (scenes without ground truth get no ``lidar_npy``). The
columns keep holodata's (and PanoRadar's) order: column j looks at azimuth −2πj/W (clockwise),
row 0 at the grid's top elevation.

``hdf5`` — one ``OUT/<scene>.h5`` per scene in the layout :mod:`holodata.readers.hdf5` reads
(``radar/heatmap`` + ``radar/timestamp_ns`` + ``radar/cycle_ns``, ``lidar``/``camera`` points with
offsets and stamps), and every other array of the scene under ``holodata/<name>`` (ragged ones as
``values`` + ``offsets``), the scene's and the arrays' attributes as JSON strings in HDF5 attributes.
"""
from __future__ import annotations

import json

import numpy as np

from .dataset.heatmap import read_heatmap
from .dataset.layout import (
    CAMERA_POINTS,
    GT_LABEL,
    GT_RANGE,
    LIDAR_POINT_TIME_NS,
    LIDAR_POINTS,
    RADAR_CYCLE_NS,
    RADAR_HEATMAP,
    TIME_TIMESTAMP_NS,
)
from .errors import DatasetError, InputError
from .ownership import OutputDir
from .safe_io import check_name

FORMATS = ("panoradar", "hdf5")
# arrays the HDF5 reader's layout carries itself (not copied again under holodata/)
IN_LAYOUT = (RADAR_HEATMAP, RADAR_CYCLE_NS, LIDAR_POINTS, LIDAR_POINT_TIME_NS, CAMERA_POINTS,
             "camera/point_time_ns")


def _scenes(ds, scene_ids, split):
    if scene_ids:
        missing = [s for s in scene_ids if s not in ds.scenes]
        if missing:
            raise DatasetError(f"{ds.url}: no scene {missing[0]!r} (have {', '.join(ds.scenes)})")
        return list(scene_ids)
    if split:
        splits = ds.splits
        if split not in splits:
            raise DatasetError(f"{ds.url}: no split {split!r} (have {', '.join(splits) or 'none'})")
        return list(splits[split])
    return list(ds.scenes)


def _ragged_frames(sc, name: str):
    """Frame arrays of ragged ``name`` in order (the reader loads each shard once)."""
    r = sc[name]
    for f in range(sc.n_frames):
        yield r[f]


def export_panoradar(sc, out: OutputDir, grid, range_bins, force: bool = False) -> dict:
    """One scene as a PanoRadar processed trajectory folder ``out/<scene id>`` (see the module
    docstring), written under a temp name and moved in place when complete; an existing folder of that
    name is replaced only when holodata wrote it (or ``force``: :mod:`holodata.ownership`)."""
    if RADAR_HEATMAP not in sc:
        raise DatasetError(f"scene {sc.id!r} has no radar/heatmap: nothing to export as PanoRadar rf_npy")
    out.check_free(sc.id, force)
    tmp = out.temp(sc.id, folder=True)
    dirs = {"rf": tmp / "rf_npy"}
    has_gt = GT_RANGE in sc
    if has_gt:
        dirs.update(lidar=tmp / "lidar_npy", gt=tmp / "gt_npy", label=tmp / "label_npy")
    for d in dirs.values():
        d.mkdir(parents=True)
    gr = sc[GT_RANGE] if has_gt else None
    lab = sc[GT_LABEL] if GT_LABEL in sc else None  # noqa: SIM401 (a dataset scene, not a dict: no .get)
    for f in range(sc.n_frames):
        name = f"{f:05d}.npy"
        a = read_heatmap(sc, f)
        np.save(dirs["rf"] / name, (np.log10(np.maximum(a, 0) + 1e-3) / 3).astype(np.float32))
        if has_gt:
            r = np.asarray(gr[f], np.float32)
            first = np.where(np.isfinite(r[0]), r[0] / 10.0, -1e3).astype(np.float32)
            np.save(dirs["lidar"] / name, first[None])
            np.save(dirs["gt"] / name, r)
            if lab is not None:
                np.save(dirs["label"] / name, np.asarray(lab[f], np.uint8))
    meta = {"exported_by": "holodata export --format panoradar", "dataset": str(sc.ds.url), "scene": sc.id,
            "frames": sc.n_frames, "grid": grid.to_attrs(), "range_bins": range_bins.to_attrs(),
            "rf_npy": "log10(a + 1e-3) / 3 of radar/heatmap (linear amplitude), (range, elevation, azimuth)",
            "lidar_npy": "gt/range bounce 1 / 10 m along the radar beams, -1e3 = no return" if has_gt else None,
            "gt_npy": "gt/range (bounce, elevation, azimuth) metres, NaN = none" if has_gt else None,
            "label_npy": "gt/label (bounce, elevation, azimuth)" if lab is not None else None,
            "columns": "column j looks at azimuth -2*pi*j/W (clockwise); row 0 = top elevation",
            "timestamps_ns": ([int(t) for t in np.asarray(sc[TIME_TIMESTAMP_NS][...])]
                              if TIME_TIMESTAMP_NS in sc else None)}
    (tmp / "holodata.json").write_text(json.dumps(meta, indent=1))
    folder = out.install(tmp, sc.id, force)
    return {"scene": sc.id, "out": str(folder), "frames": sc.n_frames, "gt": has_gt}


def export_hdf5(sc, out: OutputDir, grid, range_bins, force: bool = False) -> dict:
    """One scene as an HDF5 file ``out/<scene id>.h5`` in holodata's HDF5 reader layout plus every
    array (module docstring); replaces only a file holodata wrote (or ``force``), like
    :func:`export_panoradar`."""
    import h5py

    fname = f"{sc.id}.h5"
    out.check_free(fname, force)
    tmp = out.temp(fname)
    arrays = sc.arrays()
    nodes = sc.nodes()
    with h5py.File(tmp, "w") as h:
        h.attrs["holodata_scene_attrs"] = json.dumps(sc.attrs, default=str)
        h.attrs["grid"] = json.dumps(grid.to_attrs())
        h.attrs["range_bins"] = json.dumps(range_bins.to_attrs())
        if TIME_TIMESTAMP_NS in sc:
            t = np.asarray(sc[TIME_TIMESTAMP_NS][...], np.int64)
        else:   # a scene without stamps (written by other tools): mid-cycle stamps of a 2 Hz radar, said so
            t = ((np.arange(sc.n_frames) + 0.5) * 5e8).astype(np.int64)
            h.attrs["timestamps"] = "synthesised: frame i at (i + 0.5) x 0.5 s (the scene has no time/timestamp_ns)"
        if RADAR_HEATMAP in sc:
            src = sc[RADAR_HEATMAP]   # linear amplitude, as the format states (uint8 codes decoded)
            dt = src.dtype if src.dtype.kind == "f" else np.dtype(np.float32)
            d = h.create_dataset(RADAR_HEATMAP, shape=src.shape, dtype=dt, chunks=(1,) + src.shape[1:],
                                 compression="lzf")
            for f in range(sc.n_frames):
                d[f] = read_heatmap(sc, f).astype(dt, copy=False)
            d.attrs.update({"range_resolution_m": range_bins.dr, "elevation_max_deg": grid.elev_max_deg,
                            "elevation_min_deg": grid.elev_min_deg, "scaling": "linear",
                            "range_origin": "rotation_centre", "frame_id": "radar"})
            h["radar/timestamp_ns"] = t
            if RADAR_CYCLE_NS in sc:
                h[RADAR_CYCLE_NS] = np.asarray(sc[RADAR_CYCLE_NS][...], np.int64)
        for role in ("lidar", "camera"):
            if f"{role}/points" not in sc:
                continue
            stamps = np.asarray(sc[f"{role}/timestamp_ns"][...], np.int64) if f"{role}/timestamp_ns" in sc else t
            pts = h.create_dataset(f"{role}/points", shape=(0, 3), maxshape=(None, 3), dtype="float32",
                                   chunks=(65536, 3), compression="lzf")
            times = (h.create_dataset(f"{role}/point_time_ns", shape=(0,), maxshape=(None,), dtype="int64",
                                      chunks=(65536,)) if f"{role}/point_time_ns" in sc else None)
            offsets, keep = [0], []
            for f, p in enumerate(_ragged_frames(sc, f"{role}/points")):
                if stamps[f] <= 0:        # no scan synced to this frame
                    continue
                n = len(p)
                pts.resize(offsets[-1] + n, axis=0)
                pts[offsets[-1]:] = p
                if times is not None:
                    pt = np.asarray(sc[f"{role}/point_time_ns"][f], np.int64).reshape(-1)
                    times.resize(offsets[-1] + n, axis=0)
                    times[offsets[-1]:] = pt
                offsets.append(offsets[-1] + n)
                keep.append(int(stamps[f]))
            h[f"{role}/offsets"] = np.asarray(offsets, np.int64)
            h[f"{role}/timestamp_ns"] = np.asarray(keep, np.int64)
            h[role].attrs["frame_id"] = role
        for name in arrays:
            kind, meta = nodes[name]
            if name in IN_LAYOUT and name in h:     # already there in the reader's layout: its attrs only
                h[name].attrs["holodata_attrs"] = json.dumps(meta.get("attributes", {}), default=str)
                continue
            g = f"holodata/{name}"
            if kind == "ragged":
                r = sc[name]
                h[f"{g}/offsets"] = np.asarray(r.offsets[...], np.int64)
                h.create_dataset(f"{g}/values", data=np.asarray(r.values[...]), compression="lzf")
            elif kind == "frame" and len(sc[name].shape) > 1 and sc.n_frames:   # frame by frame: flat memory
                src = sc[name]
                d = h.create_dataset(g, shape=src.shape, dtype=src.dtype, chunks=(1,) + tuple(src.shape[1:]),
                                     compression="lzf")
                for f in range(sc.n_frames):
                    d[f] = np.asarray(src[f])
            else:                                                                  # small or whole arrays
                h.create_dataset(g, data=np.asarray(sc[name][...]), compression="lzf" if len(sc[name].shape) else None)
            h[g].attrs["holodata_attrs"] = json.dumps(meta.get("attributes", {}), default=str)
    path = out.install(tmp, fname, force)
    return {"scene": sc.id, "out": str(path), "frames": sc.n_frames, "arrays": len(arrays)}


def export_dataset(url, fmt: str, out, scene_ids=None, split: str | None = None, quiet: bool = True,
                   force: bool = False) -> dict:
    """Export scenes of dataset ``url`` (``scene_ids``, or a split's, or all) as ``fmt`` into folder
    ``out`` (created). Each scene is written under a temp name and moved in place when complete; a
    scene's folder or file already in ``out`` is replaced only when holodata wrote it, or with
    ``force`` when it is a plain file or folder (never a symlink): :mod:`holodata.ownership`."""
    from .dataset import open_dataset
    from .progress import track

    if fmt not in FORMATS:
        raise InputError(f"export format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    ds = open_dataset(url)
    todo = _scenes(ds, scene_ids, split)
    for sid in todo:   # each names a folder/file under OUT (a split list is the dataset's, from elsewhere)
        check_name(sid, "scene id", ds.url)
    out = OutputDir(out, "holodata export")
    for sid in todo:   # refuse before writing anything
        out.check_free(sid if fmt == "panoradar" else f"{sid}.h5", force)
    done = []
    skipped = []
    for sid in track(todo, total=len(todo), description=f"export {fmt}", quiet=quiet, unit="scenes"):
        sc = ds.scene(sid)
        sc.require_complete("export")
        if fmt == "panoradar" and RADAR_HEATMAP not in sc and not scene_ids:
            skipped.append({"scene": sid, "why": "no radar/heatmap (a LiDAR-only scene, e.g. a mapping pass)"})
            continue
        if fmt == "panoradar":
            done.append(export_panoradar(sc, out, ds.grid, ds.range_bins, force))
        else:
            done.append(export_hdf5(sc, out, ds.grid, ds.range_bins, force))
    return {"dataset": ds.url, "format": fmt, "out": str(out.path), "scenes": done, "skipped": skipped}
