"""What a derived array was computed from: digests of a scene's input arrays, recorded beside the output.

A stage that derives arrays from others (``raytrace-gt``: the ground truth from the mesh, the radar
poses and rotation times, and the registered human) records ``{input name: digest}`` with its
output (:func:`inputs_record`). When a later run finds the record differs from the inputs as they are
now (the person was registered after the GT was traced, the mesh was rebuilt), the output is stale:
the stage traces again, and ``validate`` says so (:func:`stale_inputs`).

A digest is taken from the checksums the writer already recorded (:mod:`holodata.dataset.writer`):
a whole array's ``sha256``, or the list of a frame or ragged array's shard checksums. Nothing is
read but the arrays' ``zarr.json``, so it costs one small read per input, whatever the array's size.
An input absent from the scene has digest None (its appearing later changes the record too).
"""
from __future__ import annotations

import hashlib
import json

from .layout import (
    HUMAN_FACES,
    HUMAN_POINTS,
    HUMAN_VERTICES,
    MESH_FACE_CLASS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_RADAR,
    RADAR_CYCLE_NS,
    TIME_TIMESTAMP_NS,
)


def array_digest(meta: dict) -> str | None:
    """Digest of one array from its ``zarr.json`` dict (``meta``): the recorded whole-array sha256 or
    shard checksums with the data type and shape; "incomplete" while not every shard is recorded."""
    hd = (meta.get("attributes") or {}).get("holodata") or {}
    if "sha256" in hd:
        basis = {"sha256": hd["sha256"]}
    elif hd.get("shards"):
        basis = {"shards": [s.get("sha256") for s in hd["shards"]]}
    else:
        return "incomplete"
    basis.update(shape=meta.get("shape") or hd.get("shape"), dtype=meta.get("data_type") or hd.get("dtype"))
    return hashlib.sha256(json.dumps(basis, sort_keys=True).encode()).hexdigest()


def inputs_record(nodes: dict, names, config: dict | None = None) -> dict:
    """{name: digest or None} for each input array ``names`` of a scene whose arrays are ``nodes``
    ({name: (kind, zarr.json dict)}: ``Scene.nodes()``), plus ``"config"``: a digest of the settings
    that shape the output (``config``), when given."""
    rec = {n: (array_digest(nodes[n][1]) if n in nodes else None) for n in names}
    if config is not None:
        rec["config"] = hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()
    return rec


# the arrays a scene's ground truth is traced from (scene attrs gt.inputs records their digests)
GT_INPUTS = (MESH_VERTICES, MESH_FACES, MESH_FACE_CLASS, POSE_T_WORLD_RADAR, TIME_TIMESTAMP_NS, RADAR_CYCLE_NS,
             HUMAN_VERTICES, HUMAN_FACES, HUMAN_POINTS)


def gt_inputs(nodes: dict, gt_attrs: dict) -> dict:
    """The record of what a scene's ground truth is traced from: the digests of :data:`GT_INPUTS`
    among ``nodes`` and of the tracing settings ``gt_attrs`` (scene attrs ``gt`` less the codec, which
    changes no value, and the record itself)."""
    return inputs_record(nodes, GT_INPUTS, {k: v for k, v in gt_attrs.items() if k not in ("codec", "inputs")})


def stale_inputs(recorded: dict | None, now: dict) -> list[str]:
    """Names whose digest differs between the ``recorded`` record and ``now`` ([] when there is no
    record: an output written before records existed is not judged)."""
    if not recorded:
        return []
    return sorted(k for k in set(recorded) | set(now) if recorded.get(k) != now.get(k))
