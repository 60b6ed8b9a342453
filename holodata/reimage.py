"""``holodata beamform``: re-image a scene's stored raw radar samples (``radar/iq``, written by
``holodata ingest --keep-iq``) into ``radar/heatmap`` with other imaging parameters or another
source of the platform's motion.

Steps (:func:`beamform_scene`): read the chirp configuration the recording was imaged with (scene
attrs ``source.beamform.chirp``) and the requested :class:`~holodata.radar.beam_geometry.BeamformParams`
(the dataset's grid: heatmaps stay on the beams the ground truth is traced for); take every
rotation's motion from ``motion`` — ``"recorded"`` (what ingest imaged with, ``radar/iq_motion``),
``"slam"`` (:func:`motion_from_poses` on ``pose/T_world_radar``) or ``"none"`` (at rest); beamform
each rotation (:func:`holodata.radar.beamform.beamform`, the trajectory's static reflection
``radar/iq_static`` subtracted as at ingest) and write the heatmaps shard by shard (an
interrupted run leaves shards that ``validate`` reports unwritten; the same command resumes); record
what was done in the scene attrs ``source.beamform`` (``rebeamformed`` says by what and from which
motion).
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace

import numpy as np

from .dataset.layout import (
    POSE_T_WORLD_RADAR,
    RADAR_CYCLE_NS,
    RADAR_HEATMAP,
    RADAR_IQ,
    RADAR_IQ_MOTION,
    RADAR_IQ_SPAN,
    RADAR_IQ_STATIC,
    TIME_TIMESTAMP_NS,
)
from .errors import DatasetError, InputError
from .radar.beam_geometry import BeamformParams, Motion
from .radar.beamform import beamform, beamform_attrs
from .radar.chirp import ChirpConfig

MOTIONS = ("recorded", "slam", "none")


def motion_from_poses(T_world_radar: np.ndarray, t_ns: np.ndarray, cycles_ns: np.ndarray,
                      chirps: np.ndarray) -> np.ndarray:
    """(T, 2) float64 [travel per chirp (m), heading (rad, counter-clockwise from beam 0 = the radar
    frame's +x)] per rotation from radar poses (T, 4, 4) at the frame stamps ``t_ns``: the velocity
    is the central difference of the positions (one-sided at the ends), expressed in the frame's
    radar frame; ``cycles_ns`` (T, 2) rotation start/end and ``chirps`` (T,) chirp frames per
    rotation give the chirp period."""
    P = np.asarray(T_world_radar, float)
    t = np.asarray(t_ns, np.float64) * 1e-9
    T = len(P)
    out = np.zeros((T, 2))
    if T < 2:
        return out
    pos = P[:, :3, 3]
    for k in range(T):
        a, b = max(k - 1, 0), min(k + 1, T - 1)
        dt = t[b] - t[a]
        if not dt > 0:
            continue
        v = P[k, :3, :3].T @ ((pos[b] - pos[a]) / dt)          # radar frame of frame k
        period = (cycles_ns[k, 1] - cycles_ns[k, 0]) * 1e-9 / max(int(chirps[k]), 1)
        out[k] = (math.hypot(v[0], v[1]) * period, math.atan2(v[1], v[0]))
    return out


def _fingerprint(attrs: dict, motion: str) -> str:
    return hashlib.sha256(json.dumps({"beamform": attrs, "motion": motion}, sort_keys=True,
                                     default=str).encode()).hexdigest()[:16]


def beamform_scene(url: str, scene_id: str, params: BeamformParams | None = None, motion: str = "recorded",
                   device: str = "cpu", quiet: bool = True, client=None) -> dict:
    """Re-image scene ``scene_id`` of dataset ``url`` from ``radar/iq``; returns a summary
    {scene, frames, motion, n_syn, seconds, skipped?}. ``params``: grid fields are taken from the
    dataset (pass the others: field of view, n_syn, windows, static removal, decimation, motion
    reference). ``client`` (a ``distributed.Client``): one Dask task per shard (:func:`image_shard`
    on the scene the worker opens; the dataset must be reachable from the workers)."""
    import time

    from .dataset import FrameStorage, create_dataset, open_dataset
    from .progress import track

    if motion not in MOTIONS:
        raise InputError(f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}")
    t0 = time.perf_counter()
    ds = open_dataset(url)
    sc = ds.scene(scene_id)
    sc.require_complete("beamform")
    for name in (RADAR_IQ, RADAR_IQ_SPAN, RADAR_CYCLE_NS):
        if name not in sc:
            raise DatasetError(f"{ds.url}: scene {scene_id!r} has no {name} (ingest its raw recording with --keep-iq)")
    src = (sc.attrs.get("source") or {}).get("beamform") or {}
    if "chirp" not in src:
        raise DatasetError(f"{ds.url}: scene {scene_id!r} says nothing about its chirp (source.beamform.chirp)")
    chirp = ChirpConfig.from_attrs(src["chirp"])
    g = ds.grid
    base = params or BeamformParams.from_attrs(src.get("params") or {})
    params = replace(base, grid=g, n_range=ds.range_bins.n)
    span = np.asarray(sc[RADAR_IQ_SPAN][...], np.int64)
    cycles = np.asarray(sc[RADAR_CYCLE_NS][...], np.int64)
    T = sc.n_frames
    if motion == "recorded":
        mot = np.asarray(sc[RADAR_IQ_MOTION][...], np.float64) if RADAR_IQ_MOTION in sc else np.zeros((T, 2))
    elif motion == "slam":
        if POSE_T_WORLD_RADAR not in sc:
            raise DatasetError(f"{ds.url}: scene {scene_id!r} has no pose/T_world_radar (run holodata slam first, "
                               f"or --motion recorded/none)")
        mot = motion_from_poses(sc[POSE_T_WORLD_RADAR][...], sc[TIME_TIMESTAMP_NS][...], cycles, span[:, 1])
    else:
        mot = np.zeros((T, 2))
    n_chirps = int(np.median(span[:, 1]))
    attrs = beamform_attrs(chirp, params, n_chirps, **{k: v for k, v in src.items()
                                                       if k not in ("chirp", "params", "n_syn", "focus", "rebeamformed")})
    fp = _fingerprint(attrs, motion)
    w = create_dataset(url)
    scw = w.scene(scene_id)
    hm_meta = sc.nodes().get(RADAR_HEATMAP, (None, {}))[1].get("attributes", {})
    if hm_meta.get("beamform_fingerprint") == fp and "beamform" not in sc.unfinished and \
            all(sc.is_done(RADAR_HEATMAP, k) for k in range(hm_meta.get("holodata", {}).get("n_shards", 0))):
        return {"scene": scene_id, "frames": T, "motion": motion, "skipped": "already imaged with these parameters"}
    # marked unfinished before the first write, finished with the scene's new source.beamform after the last
    scw.begin("beamform", rerun=f"rerun holodata beamform DATASET --scene {scene_id} with the same settings to finish it")
    if hm_meta.get("beamform_fingerprint") != fp and RADAR_HEATMAP in sc:
        scw.remove(RADAR_HEATMAP)
    R = params.n_range or chirp.n_samples
    hm = scw.frame_array(RADAR_HEATMAP, (R, g.H, g.W), "float32",
                         attrs={"amplitude": "linear", "beamform_fingerprint": fp, "source": "holodata beamform"},
                         storage=FrameStorage(max(1, min(w.shard_frames, (64 << 20) // (4 * R * g.H * g.W))), "lz4"))
    job = {"chirp": chirp.to_attrs(), "params": params.to_attrs(), "motion": mot, "device": device}
    todo = [k for k in range(hm.n_shards) if not hm.is_done(k)]
    if client is None:
        for k in track(todo, total=len(todo), description=f"beamform {scene_id}", quiet=quiet, unit="shards"):
            image_shard(sc, k, job, hm)
    else:
        from .distributed import run_tasks, worker_path

        run_tasks(client, _image_shard_task, [(worker_path(url), scene_id, k, job) for k in todo],
                  [f"beamform-{scene_id}-shard{k}-{fp}" for k in todo], description=f"beamform {scene_id}", quiet=quiet)
    src_new = {**attrs, "rebeamformed": {"by": "holodata beamform", "motion": motion, "fingerprint": fp}}
    scw.finish("beamform", {"source": {**(sc.attrs.get("source") or {}), "beamform": src_new}})
    return {"scene": scene_id, "frames": T, "motion": motion, "n_syn": attrs["n_syn"],
            "seconds": round(time.perf_counter() - t0, 2)}


def _image_shard_task(url: str, scene_id: str, k: int, job: dict) -> int:
    """The Dask task of :func:`beamform_scene`: :func:`image_shard` of the scene opened on the worker."""
    from .dataset import open_dataset

    return image_shard(open_dataset(url).scene(scene_id), k, job)


def image_shard(sc, k: int, job: dict, hm_w=None) -> int:
    """Beamform and commit shard ``k`` of ``radar/heatmap`` (which exists) from ``radar/iq`` of scene
    ``sc`` (a read handle); ``job``: {chirp, params (attrs), motion (T, 2), device}; ``hm_w``: the
    heatmap's :class:`~holodata.dataset.FrameArrayWriter` (None: opened here on ``sc``'s dataset).
    Returns the frames written."""
    from .dataset import create_dataset

    url, scene_id = sc.ds.url, sc.id
    chirp, params = ChirpConfig.from_attrs(job["chirp"]), BeamformParams.from_attrs(job["params"])
    if hm_w is None:
        hm_w = create_dataset(url).scene(scene_id).frame_array(
            RADAR_HEATMAP, tuple(sc[RADAR_HEATMAP].shape[1:]), "float32")
    T = sc.n_frames
    fr = range(*hm_w.frames(k).indices(T))
    span = np.asarray(sc[RADAR_IQ_SPAN][fr.start:fr.stop], np.int64)
    cycles = np.asarray(sc[RADAR_CYCLE_NS][fr.start:fr.stop], np.int64)
    refl = np.asarray(sc[RADAR_IQ_STATIC][...], np.complex64) if RADAR_IQ_STATIC in sc else None
    iq = sc[RADAR_IQ]
    out = np.empty((len(fr),) + hm_w.shape[1:], np.float32)
    for j, f in enumerate(fr):
        b, n, a = (int(v) for v in span[j])
        cube = np.asarray(iq[f], np.complex64)
        before = cube[:b] if b else None
        after = cube[b + n:b + n + a] if a else None
        period = (cycles[j, 1] - cycles[j, 0]) * 1e-9 / n
        ds0, th = (float(v) for v in job["motion"][f])
        vel = Motion(ds0, th).velocity(period)
        if vel is not None and (before is None or after is None):
            raise DatasetError(f"{url}: scene {scene_id!r} frame {f}: a moving rotation needs the neighbouring "
                               f"chirps, and radar/iq holds only the rotation (a static recording)")
        out[j] = beamform(cube[b:b + n], chirp, params, neighbours=(before, after), velocity=vel,
                          chirp_period_s=period, static_refl=refl, device=job["device"])
    hm_w.write_shard(k, out)
    return len(fr)
