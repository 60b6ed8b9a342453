"""Raw rotating-radar samples → heatmaps: chirp/array configuration (:mod:`.chirp`), the
beamformer (:mod:`.beamform`, numpy/scipy; :mod:`.beamform_torch` for torch devices) and a raw
beat-signal simulator (:mod:`.simulate`). Arrays in, arrays out; no I/O."""
from .beam_geometry import BeamformParams, Motion, beam_indices
from .beamform import beamform, beamform_attrs, beamform_recorded, beamform_rotation, static_reflection
from .chirp import PANORADAR_CHIRP, SPEED_OF_LIGHT, ChirpConfig
from .simulate import RigEffects, point_at, simulate_chirps, simulate_rotation

__all__ = ["ChirpConfig", "PANORADAR_CHIRP", "SPEED_OF_LIGHT", "BeamformParams", "Motion", "beamform",
           "beamform_rotation", "beamform_recorded", "beamform_attrs", "beam_indices", "static_reflection", "simulate_chirps",
           "simulate_rotation", "point_at", "RigEffects"]
