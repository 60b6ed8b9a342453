"""Chirp and antenna-array configuration of a rotating FMCW radar (PanoRadar / HoloRadar rig).

Defaults are the rig of HoloRadar's appendix A and PanoRadar's ``panoradar_SP/dataset.py``
(``/work/shared/FIELD-NOTES.md`` §"Raw radar"): a TI cascade board sweeping from 77 GHz at
79.951 MHz/µs, 256 ADC samples at 5120 ksps (bandwidth 3.9975 GHz, range bins of 3.7497 cm, so
256 bins reach 9.6 m), 2 TX × 4 RX = 8 virtual antennas in a vertical column, rotated at 2 Hz on a
10.5 cm radius with 1024 chirp frames per rotation.

Antenna geometry. ``antenna_spacing_m`` (1.9 mm ≈ λ/2) is the spacing of the *virtual* array:
the two-way path to a target at elevation θ differs by ``antenna_spacing_m · sin θ`` between
neighbouring virtual antennas (PanoRadar's vertical compensation ``exp(−j2π·d_v/λ_i)`` with
``d_v = 1.9 mm · sin θ · (7 − v)``). Antenna ``v = 7`` is the vertical phase reference (d_v = 0)
and the others sit below it. A monostatic model with the same phases puts virtual antenna ``v``
at height ``(v − 7) · antenna_spacing_m / 2`` (:meth:`ChirpConfig.antenna_heights`), which is what
:mod:`holodata.radar.simulate` uses. Every antenna faces outwards on the rotation circle of
``rotation_radius_m``; chirp ``n`` of a rotation faces azimuth ``−2πn/N`` (clockwise seen from above,
chirp 0 along the radar frame's +x, docs/format.md §2).

Per-sample frequency: sample ``i`` is taken ``i / sample_rate_hz`` after the ramp starts, at
``f_i = start_frequency_hz + slope · i / sample_rate_hz`` (PanoRadar uses ``linspace(77, 81 GHz,
256)``; the two differ by 0.45 % of the sweep at the last sample — holodata uses the physical ramp).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

SPEED_OF_LIGHT = 299_792_458.0  # m/s


@dataclass(frozen=True)
class ChirpConfig:
    """FMCW chirp, virtual array and rotation of the radar. Units: Hz, Hz/s, s, m."""

    start_frequency_hz: float = 77e9
    slope_hz_per_s: float = 79.951e12        # 79.951 MHz/µs
    n_samples: int = 256                      # ADC samples per chirp
    sample_rate_hz: float = 5.12e6            # 5120 ksps
    n_tx: int = 2
    n_rx: int = 4
    antenna_spacing_m: float = 1.9e-3         # virtual-array spacing (two-way path per element per sin θ)
    rotation_radius_m: float = 0.105
    chirps_per_rotation: int = 1024           # nominal; a rotation may hold a few more or fewer
    rotation_hz: float = 2.0

    def __post_init__(self) -> None:
        if self.n_samples < 2 or self.n_tx < 1 or self.n_rx < 1 or self.chirps_per_rotation < 3:
            raise ValueError(f"chirp config: n_samples >= 2, n_tx/n_rx >= 1 and chirps_per_rotation >= 3 needed, "
                             f"got {self.n_samples}, {self.n_tx}, {self.n_rx}, {self.chirps_per_rotation}")
        for name in ("start_frequency_hz", "slope_hz_per_s", "sample_rate_hz", "antenna_spacing_m", "rotation_hz"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"chirp config: {name} must be > 0, got {getattr(self, name)}")
        if not float(self.rotation_radius_m) >= 0:
            raise ValueError(f"chirp config: rotation_radius_m must be >= 0, got {self.rotation_radius_m}")

    # -- derived ----------------------------------------------------------------------------------
    @property
    def n_virtual(self) -> int:
        """Virtual antennas (TX × RX), stacked vertically."""
        return self.n_tx * self.n_rx

    @property
    def bandwidth_hz(self) -> float:
        """Swept bandwidth over the sampled part of the ramp: slope · n_samples / fs (3.9975 GHz)."""
        return self.slope_hz_per_s * self.n_samples / self.sample_rate_hz

    @property
    def range_resolution_m(self) -> float:
        """Range-bin size c / (2 B) in metres (0.037497 m for the defaults)."""
        return SPEED_OF_LIGHT / (2.0 * self.bandwidth_hz)

    @property
    def max_range_m(self) -> float:
        return self.n_samples * self.range_resolution_m

    @property
    def chirp_period_s(self) -> float:
        """Nominal time between two chirp frames: 1 / (rotation_hz · chirps_per_rotation)."""
        return 1.0 / (self.rotation_hz * self.chirps_per_rotation)

    def frequencies(self) -> np.ndarray:
        """(n_samples,) float64 Hz: instantaneous frequency of each ADC sample."""
        return self.start_frequency_hz + self.slope_hz_per_s * np.arange(self.n_samples) / self.sample_rate_hz

    def wavelengths(self) -> np.ndarray:
        """(n_samples,) float64 metres: λ_i = c / f_i."""
        return SPEED_OF_LIGHT / self.frequencies()

    def antenna_heights(self) -> np.ndarray:
        """(n_virtual,) float64 metres: monostatic-equivalent heights of the virtual antennas,
        ``(v − (n_virtual − 1)) · antenna_spacing_m / 2`` (antenna n_virtual − 1 at 0, the vertical
        phase reference of the beamformer)."""
        v = np.arange(self.n_virtual)
        return (v - (self.n_virtual - 1)) * self.antenna_spacing_m / 2.0

    # -- attributes -------------------------------------------------------------------------------
    def to_attrs(self) -> dict:
        """JSON-able dict (scene attrs); derived values included for readers of the dataset."""
        d = {k: (float(v) if isinstance(v, float) else int(v)) for k, v in asdict(self).items()}
        d["derived"] = {"n_virtual": self.n_virtual, "bandwidth_hz": self.bandwidth_hz,
                        "range_resolution_m": self.range_resolution_m, "chirp_period_s": self.chirp_period_s,
                        "frequency_model": "f_i = start_frequency_hz + slope_hz_per_s * i / sample_rate_hz",
                        "antenna_model": "virtual antenna v: two-way path shorter by antenna_spacing_m*(v-7)*sin(elev) "
                                         "than antenna 7 (the phase reference); all face outwards on the rotation "
                                         "circle"}
        return d

    @classmethod
    def from_attrs(cls, attrs: dict) -> ChirpConfig:
        """Inverse of :meth:`to_attrs` (unknown keys, e.g. ``derived``, are ignored)."""
        names = {f.name: f.type for f in fields(cls)}
        kw = {}
        for k, v in attrs.items():
            if k in names:
                kw[k] = int(v) if k in ("n_samples", "n_tx", "n_rx", "chirps_per_rotation") else float(v)
        return cls(**kw)


PANORADAR_CHIRP = ChirpConfig()
