"""Radar stream decoders: RadarHeatmap messages as recorded, and raw rotations (RadarRawRotation)
beamformed into heatmaps on the way in (:mod:`holodata.radar`); the beam-origin model a message
states."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..dataset.validate import frames_not_finite_nonneg
from ..readers.base import DecodeError
from .streams import _Stream


def radar_beam_origin(msg, topic: str = "radar"):
    """The beam-origin model (:class:`holodata.beams.OriginModel`) a RadarHeatmap message states:
    ``range_origin`` "rotation_centre" (or empty, as in recordings older than the field) → ranges
    from the rotation centre; "antenna" → from the rotation circle of ``rotation_radius``. Columns
    are formed at their own times within ``cycle_start_ns``..``cycle_end_ns`` either way."""
    from ..beams import OriginModel
    from ..messages import RANGE_ORIGINS

    ro = str(getattr(msg, "range_origin", "") or "rotation_centre")
    if ro not in RANGE_ORIGINS:
        raise DecodeError(f"topic {topic}: RadarHeatmap range_origin {ro!r} is not one of {', '.join(RANGE_ORIGINS)}")
    return OriginModel(float(msg.rotation_radius) if ro == "antenna" else 0.0, column_time=True)


@dataclass
class RadarFrame:
    heatmap: np.ndarray      # (R, H, W) float16|float32
    cycle: tuple[int, int]
    iq: object = None        # readers of raw samples: the RawRotation (stored with --keep-iq)


class RadarStream(_Stream):
    role = "radar"

    def __init__(self, rec, topic, time):
        super().__init__(rec, topic, time)
        self.shape = None
        self.dtype = None
        self.first = None     # first decoded message (for grid / attrs)

    def convert(self, raw, keep):
        msg = self.rec.decode(raw)
        enc = str(msg.encoding)
        dt = {"float16": np.dtype("<f2"), "float32": np.dtype("<f4")}.get(enc)
        if dt is None:
            raise DecodeError(f"topic {self.topic}: RadarHeatmap encoding {enc!r} is not float16/float32")
        shape = (int(msg.n_range), int(msg.n_elevation), int(msg.n_azimuth))
        n = int(np.prod(shape)) * dt.itemsize
        lazy = hasattr(msg, "check")   # a reader's heatmap imaged on access (PanoRadar raw): check its raw samples
        if lazy and not keep:
            msg.check()
            data = None
            size = msg.nbytes
        else:
            data = msg.data
            size = data.size if isinstance(data, np.ndarray) else len(data)
        if size != n:
            raise DecodeError(f"topic {self.topic}: RadarHeatmap payload is {size} bytes, {shape} {enc} needs {n}")
        if self.first is None:
            radar_beam_origin(msg, self.topic)  # an unknown range_origin stops here, naming the topic
            self.first = msg
            self.shape, self.dtype = shape, dt
        elif shape != self.shape:
            raise DecodeError(f"topic {self.topic}: RadarHeatmap shape {shape} differs from the first message's "
                              f"{self.shape}")
        if data is None:
            return None
        buf = data if isinstance(data, np.ndarray) else np.frombuffer(bytes(data), np.uint8)
        hm = buf.view(dt).reshape(shape)
        # the layout's value rule (validate's): a heatmap with NaN/inf or negative amplitudes is a
        # damaged message, dropped here (counted) rather than written into a dataset validate rejects;
        # checked once, in the index pass, whose verdict the write pass keeps (same file, same bytes)
        if self._converting not in self.checked and len(frames_not_finite_nonneg(hm[None])):
            raise DecodeError(f"topic {self.topic}: RadarHeatmap at {raw.log_ns} ns holds NaN/inf or negative "
                              f"amplitudes (damaged message)")
        if not keep:
            return None
        return RadarFrame(hm, (int(msg.cycle_start_ns), int(msg.cycle_end_ns)), getattr(msg, "iq", None))



class RawRadarStream(RadarStream):
    """``holodata_msgs/msg/RadarRawRotation`` messages: each rotation's raw samples, checked on the index
    pass (no imaging there) and beamformed (:func:`holodata.radar.beamform.beamform`) when kept.
    ``params``: :class:`~holodata.radar.beam_geometry.BeamformParams` (default 64 x 512). The static
    reflection is each rotation's own mean (a bag carries no trajectory mean)."""

    def __init__(self, rec, topic, time, params=None):
        from ..radar.beam_geometry import BeamformParams

        super().__init__(rec, topic, time)
        p = params or BeamformParams()
        if p.static_removal == "trajectory":   # no trajectory mean in a stream of messages
            p = dataclasses.replace(p, static_removal="rotation")
        self.params = p
        self.chirp = None
        self.max_chirps = 0
        self.attrs: dict = {}

    def _chirp_of(self, msg, raw):
        from ..radar.chirp import ChirpConfig

        try:
            return ChirpConfig(start_frequency_hz=float(msg.start_frequency), slope_hz_per_s=float(msg.slope),
                               n_samples=int(msg.n_samples), sample_rate_hz=float(msg.sample_rate), n_tx=int(msg.n_tx),
                               n_rx=int(msg.n_rx), antenna_spacing_m=float(msg.antenna_spacing),
                               rotation_radius_m=float(msg.rotation_radius),
                               chirps_per_rotation=max(int(msg.n_rotation), 3))
        except ValueError as err:
            raise DecodeError(f"topic {self.topic}: RadarRawRotation at {raw.log_ns} ns has no usable chirp "
                              f"configuration ({err})") from err

    def convert(self, raw, keep):
        from types import SimpleNamespace

        from ..radar.beam_geometry import Motion
        from ..radar.beamform import beamform_attrs, beamform_recorded
        from ..readers.base import RawRotation

        msg = self.rec.decode(raw)
        if str(msg.encoding) != "complex64":
            raise DecodeError(f"topic {self.topic}: RadarRawRotation encoding {msg.encoding!r} is not complex64")
        chirp = self._chirp_of(msg, raw)
        nb, nr, na = int(msg.n_before), int(msg.n_rotation), int(msg.n_after)
        V, S = chirp.n_virtual, chirp.n_samples
        data = msg.data
        size = data.size if isinstance(data, np.ndarray) else len(data)
        if nr < 3 or size != (nb + nr + na) * V * S * 8:
            raise DecodeError(f"topic {self.topic}: RadarRawRotation at {raw.log_ns} ns holds {size} bytes, "
                              f"({nb}+{nr}+{na}) chirps x {V} antennas x {S} samples x 8 need {(nb + nr + na) * V * S * 8}")
        try:
            n_syn = self.params.syn_count(nr)
        except ValueError as err:
            raise DecodeError(f"topic {self.topic}: RadarRawRotation at {raw.log_ns} ns: {err}") from err
        self.max_chirps = max(self.max_chirps, nb + nr + na)
        R = self.params.n_range or S
        if self.first is None:
            p = self.params
            self.chirp = chirp
            self.first = SimpleNamespace(__msgtype__="holodata_msgs/msg/RadarRawRotation (beamformed by ingest)",
                                         encoding="float32", range_origin="rotation_centre",
                                         rotation_radius=chirp.rotation_radius_m,
                                         elevation_max=math.radians(p.grid.elev_max_deg),
                                         elevation_min=math.radians(p.grid.elev_min_deg),
                                         range_resolution=chirp.range_resolution_m, header=msg.header)
            self.shape, self.dtype = (R, p.grid.H, p.grid.W), np.dtype("<f4")
            self.attrs = beamform_attrs(chirp, p, nr, motion_compensation="the messages' travel_per_chirp/heading",
                                        padding="neighbouring rotations (n_before/n_after) when given, else circular",
                                        static_reflection="each rotation's own mean",
                                        source_topic=self.topic)
        elif chirp != self.chirp and dataclasses.replace(chirp, chirps_per_rotation=self.chirp.chirps_per_rotation) != self.chirp:
            raise DecodeError(f"topic {self.topic}: RadarRawRotation at {raw.log_ns} ns has another chirp configuration "
                              f"than the first message's")
        if not keep:
            return None
        buf = data if isinstance(data, np.ndarray) else np.frombuffer(bytes(data), np.uint8)
        cube = buf.view("<c8").reshape(nb + nr + na, V, S)
        ds0, th = float(msg.travel_per_chirp), float(msg.heading)
        cycle_s = (int(msg.cycle_end_ns) - int(msg.cycle_start_ns)) * 1e-9
        if Motion(ds0, th).velocity(cycle_s / nr) is not None and (nb < n_syn // 2 or na < n_syn // 2):
            raise DecodeError(f"topic {self.topic}: RadarRawRotation at {raw.log_ns} ns moves but carries {nb}/{na} "
                              f"neighbouring chirps, its beams need {n_syn // 2}")
        hm = beamform_recorded(cube, (nb, nr, na), (ds0, th), cycle_s, chirp, self.params)
        return RadarFrame(hm, (int(msg.cycle_start_ns), int(msg.cycle_end_ns)),
                          RawRotation(cube[:nb], cube[nb:nb + nr], cube[nb + nr:], motion=(ds0, th)))

    def iq_shape(self) -> tuple[int, int, int]:
        return self.max_chirps, self.chirp.n_virtual, self.chirp.n_samples


def radar_stream(rec, topic: str, time, msgtype: str, beamform=None) -> RadarStream:
    """The stream for a radar topic: heatmaps as recorded, or raw rotations beamformed with ``beamform``."""
    from .roles import RAW_SUFFIX

    if msgtype.endswith(RAW_SUFFIX):
        return RawRadarStream(rec, topic, time, beamform)
    return RadarStream(rec, topic, time)
