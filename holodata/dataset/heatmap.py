"""Radar heatmaps whatever their storage: linear amplitude (float16 / float32, what ingest writes from
a recording) or log-amplitude codes (uint8 with an ``encoding`` attribute,
:class:`holodata.conventions.LogCode`, what a training corpus stores). Every reader of
``radar/heatmap`` values goes through :func:`read_heatmap` (linear amplitude) or, for speed, reads
the stored frame and maps it with :func:`heatmap_code`'s table.
"""
from __future__ import annotations

import numpy as np

from ..conventions import LogCode
from ..errors import DatasetError
from .layout import RADAR_HEATMAP

ENCODING_ATTR = "encoding"


def code_of_meta(meta: dict) -> LogCode | None:
    """The :class:`LogCode` a heatmap's parsed ``zarr.json`` declares (None: linear amplitude).
    ValueError when a uint8 heatmap has no valid ``encoding`` or a float one has one."""
    attrs = meta.get("attributes") or {}
    enc = attrs.get(ENCODING_ATTR)
    if np.dtype(meta.get("data_type")) == np.uint8:
        return LogCode.from_attrs(enc)
    if enc is not None:
        raise ValueError(f"a {meta.get('data_type')} heatmap is linear amplitude; it has encoding {enc!r}")
    return None


def heatmap_code(sc) -> LogCode | None:
    """The :class:`LogCode` of scene ``sc``'s ``radar/heatmap`` (None: stored as linear amplitude)."""
    nodes = sc.nodes()
    if RADAR_HEATMAP not in nodes:
        raise DatasetError(f"{sc.ds.url}: scene {sc.id!r} has no {RADAR_HEATMAP} array")
    try:
        return code_of_meta(nodes[RADAR_HEATMAP][1])
    except ValueError as err:
        raise DatasetError(f"{sc.ds.url}: scene {sc.id!r} {RADAR_HEATMAP}: {err}") from None


def read_heatmap(sc, k: int) -> np.ndarray:
    """Frame ``k`` of scene ``sc``'s heatmap: (R, H, W) float32 linear amplitude."""
    raw = sc.frame(RADAR_HEATMAP, k)
    code = heatmap_code(sc)
    return code.decode(raw) if code is not None else raw.astype(np.float32, copy=False)
