"""PanoRadar raw trajectory folders: raw FMCW radar samples, beamformed here into heatmaps, plus the
LiDAR frames and the LiDAR→radar yaw (layout of ``panoradar_SP/dataset.py``; FIELD-NOTES §"Raw radar")::

    radar_data.npy    (chirp frames, chirps x TX, RX, samples) complex I/Q (int16 scale; / 32768)
    radar_ts.txt      one stamp per chirp frame, seconds
    data_params.npz   radar_sep (first chirp frame of every rotation), r_radar, transform (2x2 yaw,
                      xy_radar = xy_lidar @ transform), lidar_sep, imu_sep
    lidar_data.npy    (frames, rows, columns, 3) xyz, LiDAR frame     + lidar_ts.txt   (optional)
    imu_data.npy      (samples,) yaw rate, deg/s                      + imu_ts.txt     (optional)
    motion_output.npz v_esti, theta_v_esti, delta_s0_esti per rotation (moving trajectories, optional)

Topics: ``/panoradar/radar`` (one RadarHeatmap per rotation ``k``: the chirp frames
``radar_sep[k] .. radar_sep[k+1]``, beamformed by :func:`holodata.radar.beamform.beamform` on
decode), ``/panoradar/lidar`` (every LiDAR frame as an organised range image) and ``/tf_static``
(``base_link → radar`` identity, ``base_link → lidar`` the yaw of ``transform``; the release records
no LiDAR–radar offset, so the translation is zero).

How the rotations are imaged (all of it goes into :attr:`PanoRadarRawRecording.attrs` ``beamform``,
so the scene says how its heatmaps were made): static reflection = the mean over every chirp of the
trajectory (PanoRadar's ``static_refl``); a robot at rest (:func:`motion_rule`: "static" in the
trajectory folder's name or in its parent's, the building folder PanoRadar decides by, or the caller's
override) is imaged with circular padding and no motion term, as PanoRadar; otherwise every rotation takes its beams' outer
chirps from the neighbouring rotations, and the motion term uses ``motion_output.npz``'s travel per
chirp and heading when the folder has it (PanoRadar's sign unwrapping of ``v_esti``; not its
empirical −5.5° heading offset). A moving trajectory without it is imaged as if at rest, and the
recording says so in ``problems``. The first and last rotations of a moving trajectory need
``n_syn // 2`` chirps beyond them: rotations without them are left out (``problems`` says how many).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..errors import InputError, RecordingError
from ..radar.beam_geometry import BeamformParams, Motion
from ..radar.beamform import beamform, beamform_attrs, static_reflection
from ..radar.chirp import ChirpConfig
from .base import (
    RADAR_MSG,
    RANGE_IMAGE_TYPE,
    DecodeError,
    Header,
    RadarHeatmapMsg,
    RangeImageMsg,
    RawMessage,
    RawRotation,
    Recording,
    TopicInfo,
    rate_of,
)
from .sizes import check_npy, check_npz

RADAR_TOPIC = "/panoradar/radar"
LIDAR_TOPIC = "/panoradar/lidar"
TF_TOPIC = "/tf_static"
TF_TYPE = "tf2_msgs/msg/TFMessage"
INT16_SCALE = 32768.0
REQUIRED = ("radar_data.npy", "radar_ts.txt", "data_params.npz")
MOTIONS = ("static", "moving")


def motion_rule(folder, override: str | None = None) -> tuple[bool, str]:
    """Whether the trajectory in ``folder`` was recorded by a robot at rest, and the rule that decided
    it: (static, "static: parent folder 'bldg_static'"). ``override`` ("static" | "moving") decides
    when given; else "static" (any case) in the trajectory folder's own name or in its parent's.
    PanoRadar's ``process_raw_data.py`` (``process_dataset``) and ``motion_estimation.py`` decide
    from the *building* folder holding the trajectories (``'static' in in_building_folder.name``:
    every trajectory inside is static), hence the parent; the folder's own name is holodata's older
    rule, kept so that single trajectories named ``static_01`` still read as static. The path is
    resolved first, so that ``.`` and relative paths see the real folder names."""
    if override is not None:
        if override not in MOTIONS:
            raise InputError(f"robot motion must be one of {', '.join(MOTIONS)}, got {override!r}")
        return override == "static", f"{override}: given (--beamform-motion {override})"
    p = Path(folder).resolve()
    if "static" in p.name.lower():
        return True, f"static: folder '{p.name}'"
    if "static" in p.parent.name.lower():
        return True, f"static: parent folder '{p.parent.name}'"
    return False, f"moving: neither folder '{p.name}' nor its parent '{p.parent.name}' names 'static'"


def _load_npy(path: Path, mmap: bool = True) -> np.ndarray:
    check_npy(path)      # the shape its header declares against the bytes after it, before np.load reserves it
    try:
        return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except FileNotFoundError as err:
        raise RecordingError(f"{path}: missing (a PanoRadar raw trajectory needs {', '.join(REQUIRED)})") from err
    except (OSError, ValueError, EOFError) as err:
        raise RecordingError(f"{path}: not a readable .npy array, truncated? "
                             f"({' '.join(str(err).split())[:120]})") from err


def _load_stamps(path: Path, n: int, what: str) -> np.ndarray:
    try:
        t = np.atleast_1d(np.loadtxt(path, dtype=np.float64))
    except FileNotFoundError as err:
        raise RecordingError(f"{path}: missing (one stamp in seconds per {what})") from err
    except ValueError as err:
        raise RecordingError(f"{path}: not a column of stamps in seconds ({' '.join(str(err).split())[:100]})") from err
    if t.ndim != 1 or t.size != n:
        raise RecordingError(f"{path}: {t.size} stamps for {n} {what}s")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise RecordingError(f"{path}: stamps must be finite and non-decreasing")
    return t


def _separators(params_path: Path, params, key: str, n: int, what: str, required: bool) -> np.ndarray | None:
    if key not in params:
        if required:
            raise RecordingError(f"{params_path}: no {key!r} (first {what} of every rotation)")
        return None
    sep = np.asarray(params[key])
    if sep.ndim != 1 or sep.dtype.kind not in "iu" or sep.size < 2:
        raise RecordingError(f"{params_path}: {key} must be >= 2 integer indices, got {sep.shape} {sep.dtype}")
    sep = sep.astype(np.int64)
    if np.any(np.diff(sep) <= 0):
        k = int(np.nonzero(np.diff(sep) <= 0)[0][0])
        raise RecordingError(f"{params_path}: {key} out of order ({key}[{k}] = {sep[k]}, [{k + 1}] = {sep[k + 1]})")
    if sep[0] < 0 or sep[-1] > n:
        raise RecordingError(f"{params_path}: {key} reaches beyond the data ({sep[0]}..{sep[-1]} for {n} {what}s)")
    return sep


class PanoRadarRawRecording(Recording):
    kind = "panoradar-raw"

    def __init__(self, path: Path, beamform_params: BeamformParams | None = None, device: str = "cpu",
                 motion: str | None = None):
        """``motion``: "static" | "moving" overrides :func:`motion_rule`'s reading of the folder names."""
        super().__init__(path)
        p = self.path
        for name in REQUIRED:
            if not (p / name).exists():
                raise RecordingError(f"{p / name}: missing (a PanoRadar raw trajectory needs {', '.join(REQUIRED)})")
        raw = self._read_radar(p)
        params, r_radar = self._read_params(p)
        n_chirps = self._read_chirp(p, raw, r_radar)
        self.params = beamform_params or BeamformParams()
        self.device = device
        rule = self._decide_motion(p, motion, params)
        n_in_file = self._imageable_rotations(p, motion, rule)
        self._refl = None
        self._read_lidar(p)
        self.files = [p / n for n in ("radar_data.npy", "radar_ts.txt", "data_params.npz", "lidar_data.npy",
                                      "lidar_ts.txt", "imu_data.npy", "imu_ts.txt", "motion_output.npz")
                      if (p / n).exists()]
        self.attrs = self._describe(n_chirps, rule, n_in_file)

    def _read_radar(self, p: Path) -> np.ndarray:
        """radar_data.npy, memory-mapped (``radar``: (C, V, S), a view of it), and its stamps
        ``radar_ts``; the array as stored."""
        raw = _load_npy(p / "radar_data.npy")
        if raw.dtype.kind != "c" or raw.ndim not in (3, 4):
            raise RecordingError(f"{p / 'radar_data.npy'}: expected complex I/Q (chirp frames, chirps x TX, RX, samples), "
                                 f"got {raw.shape} {raw.dtype}")
        self.radar = raw.reshape(raw.shape[0], -1, raw.shape[-1])      # (C, V, S), a view of the memory map
        self.radar_ts = _load_stamps(p / "radar_ts.txt", self.radar.shape[0], "chirp frame")
        return raw

    def _read_params(self, p: Path) -> tuple[dict, float]:
        """data_params.npz: the first chirp frame of every rotation (``sep``) and the LiDAR→radar yaw
        (``transform``); (all its arrays, the rotation radius r_radar in m)."""
        C = self.radar.shape[0]
        check_npz(p / "data_params.npz")
        try:
            with np.load(p / "data_params.npz", allow_pickle=False) as z:
                params = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError) as err:
            raise RecordingError(f"{p / 'data_params.npz'}: not a readable .npz ({' '.join(str(err).split())[:100]})") from err
        pp = p / "data_params.npz"
        self.sep = _separators(pp, params, "radar_sep", C, "chirp frame", True)
        try:
            r_radar = float(np.asarray(params.get("r_radar", 0.105)).reshape(()))
            transform = np.asarray(params.get("transform", np.eye(2)), np.float64).reshape(2, 2)
        except (ValueError, TypeError) as err:
            raise RecordingError(f"{pp}: r_radar must be a number and transform 2x2 ({err})") from err
        self.transform = transform
        return params, r_radar

    def _read_chirp(self, p: Path, raw: np.ndarray, r_radar: float) -> int:
        """``chirp``: the rig's chirp (PanoRadar's constants) with this folder's array size, radius and
        rotation rate (from the median rotation's duration); the median chirp frames per rotation."""
        C, V, S = self.radar.shape
        n_chirps = int(np.median(np.diff(self.sep)))
        dt = np.diff(self.radar_ts)
        self._dt = float(np.median(dt)) if dt.size else 0.0
        period = float(np.median(np.diff(self._stamp_at(self.sep))))
        if not period > 0:
            raise RecordingError(f"{p / 'radar_ts.txt'}: rotations have no duration (stamps at radar_sep equal)")
        n_tx = raw.shape[1] if raw.ndim == 4 else 1
        n_rx = raw.shape[2] if raw.ndim == 4 else V
        try:
            self.chirp = ChirpConfig(n_samples=S, n_tx=n_tx, n_rx=n_rx, rotation_radius_m=r_radar,
                                     chirps_per_rotation=n_chirps, rotation_hz=1.0 / period)
        except ValueError as err:
            raise RecordingError(f"{p}: {err}") from err
        return n_chirps

    def _decide_motion(self, p: Path, motion: str | None, params: dict) -> str:
        """Whether the robot was at rest (``static``, :func:`motion_rule`; the rule is returned and kept in
        ``decisions``), its ``motion`` per rotation when moving (motion_output.npz), and where each
        rotation ends (``end``): the next start, or (moving, with an IMU) one turn of the radar relative
        to the world, from the platform's yaw rate (PanoRadar's __find_radar_end_frame_sep)."""
        self.static, rule = motion_rule(p, motion)
        self.decisions["motion"] = rule
        self.problems = []
        self.motion = None
        if not self.static and (p / "motion_output.npz").exists():
            self.motion = self._motion(p / "motion_output.npz", len(self.sep) - 1)
        elif not self.static:
            self.problems.append(f"{p}: moving trajectory without motion_output.npz: rotations imaged as if at rest")
        self.end = self.sep[1:].copy()
        self.yaw_source = "none"
        if not self.static and (p / "imu_data.npy").exists() and "imu_sep" in params:
            self.end = self._ends_from_imu(p, params, self.radar.shape[0])
            self.yaw_source = "imu_data.npy"
        return rule

    def _imageable_rotations(self, p: Path, motion: str | None, rule: str) -> int:
        """``rotations``: the ones that can be imaged (a moving one needs n_syn//2 chirps on either side;
        the others are left out, ``problems`` says how many); RecordingError when none can. Returns the
        number of rotations in the file."""
        lens = self.end - self.sep[:-1]
        C = self.radar.shape[0]
        self.rotations = list(range(len(lens)))
        if not self.static:
            half = [(self.params.syn_count(int(n)) - 1) // 2 for n in lens]
            keep = [k for k in self.rotations if self.sep[k] - half[k] >= 0 and self.end[k] + half[k] <= C]
            if len(keep) < len(self.rotations):
                self.problems.append(f"{p}: {len(self.rotations) - len(keep)} rotation(s) at the ends lack the "
                                     f"neighbouring chirps their beams need; left out")
            self.rotations = keep
        if not self.rotations:
            hint = "" if self.static or motion else "; a robot at rest: --beamform-motion static"
            raise RecordingError(f"{p}: no rotation can be imaged ({len(lens)} rotation(s), {rule}{hint})")
        return len(lens)

    def _read_lidar(self, p: Path) -> None:
        """``lidar`` (frames, rows, columns, 3) xyz and its stamps ``lidar_ts`` (None without lidar_data.npy)."""
        self.lidar = self.lidar_ts = None
        if (p / "lidar_data.npy").exists():
            li = _load_npy(p / "lidar_data.npy")
            if li.ndim != 4 or li.shape[-1] != 3 or li.dtype.kind != "f":
                raise RecordingError(f"{p / 'lidar_data.npy'}: expected (frames, rows, columns, 3) float xyz, "
                                     f"got {li.shape} {li.dtype}")
            self.lidar = li
            self.lidar_ts = _load_stamps(p / "lidar_ts.txt", li.shape[0], "LiDAR frame")

    def _describe(self, n_chirps: int, rule: str, n_in_file: int) -> dict:
        """The recording's attrs: how its heatmaps are made (all of it: the scene says how its heatmaps
        were made) and the LiDAR→radar transform."""
        mode = f"none ({rule})" if self.static else ("motion_output.npz" if self.motion else "none (as if at rest)")
        return {
            "format": "PanoRadar raw trajectory",
            "radar_scaling": f"stored int16-scaled I/Q; divided by {INT16_SCALE:g}",
            "beamform": beamform_attrs(self.chirp, self.params, n_chirps, motion_compensation=mode,
                                       padding="circular" if self.static else "neighbouring rotations",
                                       rotation_end="next radar_sep" if self.yaw_source == "none" else
                                       "one turn relative to the world: radar_sep + round(2*pi / (dtheta0 - dt*omega)), "
                                       "omega the mean yaw rate of imu_data.npy over the rotation",
                                       static_reflection="mean over every chirp of the trajectory", motion=rule,
                                       rotations_imaged=len(self.rotations), rotations_in_file=n_in_file,
                                       frequency_note="PanoRadar's imaging uses linspace(77, 81 GHz, n_samples)"),
            "lidar_to_radar_transform": self.transform.tolist(),
        }

    def _ends_from_imu(self, p: Path, params: dict, C: int) -> np.ndarray:
        """Rotation ends from the IMU yaw rate (deg/s, counter-clockwise +): the radar turns at
        ``dtheta0`` per chirp relative to the robot, so relative to the world a full turn takes
        ``round(2π / (dtheta0 − dt·ω))`` chirps (PanoRadar's ``RadarFrames.__find_radar_end_frame_sep``,
        with its outlier filter and Gaussian smoothing of the yaw rate)."""
        from scipy.ndimage import gaussian_filter1d

        imu = _load_npy(p / "imu_data.npy", mmap=False)
        if imu.ndim != 1 or imu.dtype.kind not in "fiu":
            raise RecordingError(f"{p / 'imu_data.npy'}: expected (samples,) yaw rates in deg/s, got {imu.shape} {imu.dtype}")
        isep = _separators(p / "data_params.npz", params, "imu_sep", imu.size, "IMU sample", True)
        if isep.size < self.sep.size:
            raise RecordingError(f"{p / 'data_params.npz'}: imu_sep has {isep.size} entries for {self.sep.size} radar_sep")
        w = np.asarray(imu, np.float64).copy()
        jump = np.flatnonzero(np.abs(np.r_[np.diff(w), 0.0]) > 20.0)      # PanoRadar: jitter > 20 deg/s ...
        jump = np.maximum(jump, 2)
        w[jump] = w[jump - 2]                                              # ... takes the value 2 samples back
        w = np.deg2rad(gaussian_filter1d(w, sigma=2.0, truncate=6.0))
        dtheta0 = float(np.mean(2 * np.pi / np.diff(self.sep)))
        stamps = self.radar_ts[np.minimum(self.sep, C - 1)]
        dt = float(np.mean(np.diff(stamps) / np.diff(self.sep)))
        ends = []
        for k in range(self.sep.size - 1):
            omega = float(np.mean(w[isep[k]:max(isep[k + 1], isep[k] + 1)]))
            ends.append(int(self.sep[k]) + int(round(2 * np.pi / (dtheta0 - dt * omega))))
        return np.asarray(ends, np.int64)

    # -- motion -------------------------------------------------------------------------------------
    def _motion(self, path: Path, n_rot: int) -> dict:
        check_npz(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                v = np.asarray(z["v_esti"], np.float64).reshape(-1)
                th = np.asarray(z["theta_v_esti"], np.float64).reshape(-1)
                ds0 = np.asarray(z["delta_s0_esti"], np.float64).reshape(-1)
        except KeyError as err:
            raise RecordingError(f"{path}: no {err.args[0]!r} (v_esti, theta_v_esti, delta_s0_esti per rotation)") from err
        except (OSError, ValueError, EOFError) as err:
            raise RecordingError(f"{path}: not a readable .npz ({' '.join(str(err).split())[:100]})") from err
        if not (v.size == th.size == ds0.size) or v.size < n_rot:
            raise RecordingError(f"{path}: {v.size}/{th.size}/{ds0.size} values for {n_rot} rotations")
        th = np.where(v < 0, th + np.pi, th)            # PanoRadar's get_motion_params: -v is +180°
        return {"ds0": np.abs(ds0), "theta_v": np.mod(th + np.pi, 2 * np.pi) - np.pi}

    # -- topics -------------------------------------------------------------------------------------
    def _stamp_at(self, i) -> np.ndarray:
        """Stamps (s) of chirp frames ``i``; index ``len`` (the end of the last rotation) is one median
        chirp period after the last frame."""
        i = np.asarray(i, np.int64)
        C = len(self.radar_ts)
        return np.where(i < C, self.radar_ts[np.minimum(i, C - 1)], self.radar_ts[-1] + (i - C + 1) * self._dt)

    def _rot_stamps(self, k: int) -> tuple[int, int]:
        t0, t1 = self._stamp_at([self.sep[k], self.end[k]])
        return int(round(t0 * 1e9)), int(round(t1 * 1e9))

    def _topics(self) -> list[TopicInfo]:
        ks = self.rotations
        lo, hi = (sum(self._rot_stamps(ks[0])) // 2, sum(self._rot_stamps(ks[-1])) // 2)
        out = [TopicInfo(RADAR_TOPIC, RADAR_MSG, len(ks), rate_of(len(ks), lo, hi), "radar", "npy", True,
                         "radar_data.npy (beamformed)", lo, hi),
               TopicInfo(TF_TOPIC, TF_TYPE, 1, None, "base_link", "npy", True, "data_params.npz transform",
                         int(self.radar_ts[0] * 1e9), int(self.radar_ts[0] * 1e9))]
        if self.lidar is not None:
            t = (self.lidar_ts * 1e9).round().astype(np.int64)
            out.append(TopicInfo(LIDAR_TOPIC, RANGE_IMAGE_TYPE, len(t), rate_of(len(t), int(t[0]), int(t[-1])),
                                 "lidar", "npy", True, "lidar_data.npy", int(t[0]), int(t[-1])))
        return out

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        want = None if topics is None else set(topics)
        items = []
        if want is None or TF_TOPIC in want:
            items.append((int(self.radar_ts[0] * 1e9), TF_TOPIC, TF_TYPE, ("tf", 0)))
        if want is None or RADAR_TOPIC in want:
            items += [(sum(self._rot_stamps(k)) // 2, RADAR_TOPIC, RADAR_MSG, ("radar", k)) for k in self.rotations]
        if self.lidar is not None and (want is None or LIDAR_TOPIC in want):
            items += [(int(round(t * 1e9)), LIDAR_TOPIC, RANGE_IMAGE_TYPE, ("lidar", i)) for i, t in enumerate(self.lidar_ts)]
        for t, topic, ty, obj in sorted(items, key=lambda x: x[0]):
            yield RawMessage(topic, ty, t, None, "npy", obj)

    def decode(self, raw: RawMessage):
        what, i = raw.obj
        if what == "radar":
            return self.heatmap(i)
        if what == "lidar":
            xyz = np.asarray(self.lidar[i], np.float32)
            r = np.linalg.norm(xyz, axis=-1)
            r[~(r > 0)] = np.nan
            return RangeImageMsg(r, np.where(np.isfinite(r)[..., None], xyz, 0).astype(np.float32), "lidar")
        return self._tf()

    def _tf(self):
        yaw = math.atan2(self.transform[0, 1], self.transform[0, 0])   # R_radar_lidar = transform.T
        stamp = SimpleNamespace(sec=int(self.radar_ts[0]), nanosec=int((self.radar_ts[0] % 1) * 1e9))

        def ts(child, angle):
            q = SimpleNamespace(x=0.0, y=0.0, z=math.sin(angle / 2), w=math.cos(angle / 2))
            return SimpleNamespace(header=SimpleNamespace(stamp=stamp, frame_id="base_link"), child_frame_id=child,
                                   transform=SimpleNamespace(translation=SimpleNamespace(x=0.0, y=0.0, z=0.0), rotation=q))

        return SimpleNamespace(transforms=[ts("radar", 0.0), ts("lidar", yaw)])

    # -- imaging ------------------------------------------------------------------------------------
    def static_refl(self) -> np.ndarray:
        """(V, S) complex64: the trajectory's static reflection (computed once, in blocks)."""
        if self._refl is None:
            self._refl = static_reflection(self.radar) / np.complex64(INT16_SCALE)
        return self._refl

    def rotation_iq(self, k: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(rotation, before, after) of rotation ``k``, unit scale (before/after None when static)."""
        a, b = int(self.sep[k]), int(self.end[k])
        rot = np.asarray(self.radar[a:b], np.complex64) / np.complex64(INT16_SCALE)
        if self.static:
            return rot, None, None
        h = (self.params.syn_count(b - a) - 1) // 2
        before = np.asarray(self.radar[a - h:a], np.complex64) / np.complex64(INT16_SCALE)
        after = np.asarray(self.radar[b:b + h], np.complex64) / np.complex64(INT16_SCALE)
        return rot, before, after

    def heatmap(self, k: int) -> RotationHeatmap:
        """Rotation ``k`` as a RadarHeatmap (float32, linear amplitude, ranges from the rotation
        centre) that is beamformed when its ``data`` is first read: ingest's index pass only checks
        the rotation's raw samples (:meth:`RotationHeatmap.check`), so each rotation is imaged once."""
        t0, t1 = self._rot_stamps(k)
        p, g = self.params, self.params.grid
        return RotationHeatmap(Header((t0 + t1) // 2, "radar"), t0, t1, p.n_range or self.chirp.n_samples,
                               g.H, g.W, self.chirp.range_resolution_m,
                               math.radians(g.elev_max_deg), math.radians(g.elev_min_deg),
                               self.chirp.rotation_radius_m, "float32", None, rec=self, k=k)

    def image(self, k: int) -> tuple[np.ndarray, RawRotation]:
        """Rotation ``k`` beamformed: ((n_range, H, W) float32, the RawRotation it was formed from)."""
        rot, before, after = self.rotation_iq(k)
        a, b = int(self.sep[k]), int(self.end[k])
        t0, t1 = self._rot_stamps(k)
        period = (t1 - t0) / 1e9 / (b - a)
        velocity, ds0, th = None, 0.0, 0.0
        if self.motion is not None:
            ds0, th = float(self.motion["ds0"][k]), float(self.motion["theta_v"][k])
            velocity = Motion(ds0, th).velocity(period)
        try:
            hm = beamform(rot, self.chirp, self.params, neighbours=(before, after), velocity=velocity,
                          chirp_period_s=period, static_refl=self.static_refl(), device=self.device)
        except ValueError as err:
            raise RecordingError(f"{self.path / 'radar_data.npy'}: rotation {k}: {err}") from err
        return hm, RawRotation(*self._pads(before, rot, after), motion=(ds0, th))

    def check_rotation(self, k: int) -> None:
        """The index pass's check of rotation ``k`` without imaging it: finite raw samples (a
        beamformed magnitude of finite samples is finite and non-negative)."""
        for part in self.rotation_iq(k):
            if part is not None and not np.isfinite(part.view(np.float32)).all():
                raise DecodeError(f"{self.path / 'radar_data.npy'}: rotation {k} holds NaN/inf samples")

    def _pads(self, before, rot, after):
        empty = np.zeros((0,) + rot.shape[1:], np.complex64)
        return (empty if before is None else before), rot, (empty if after is None else after)

    def iq_shape(self) -> tuple[int, int, int]:
        """(chirps, V, S): room for the longest imaged rotation with its neighbouring chirps."""
        longest = 0
        for k in self.rotations:
            n = int(self.end[k] - self.sep[k])
            longest = max(longest, n + (0 if self.static else self.params.syn_count(n) - 1))
        return longest, self.radar.shape[1], self.radar.shape[2]


__all__ = ["PanoRadarRawRecording", "motion_rule", "MOTIONS"]


class RotationHeatmap(RadarHeatmapMsg):
    """A RadarHeatmap of one PanoRadar rotation, beamformed on first access to ``data`` (or ``iq``);
    ``check()`` validates its raw samples without imaging. ``nbytes``: the payload's size."""

    def __init__(self, *fields, rec: PanoRadarRawRecording, k: int):
        super().__init__(*fields)
        self._rec, self._k, self._img = rec, k, None

    def _imaged(self):
        if self._img is None:
            hm, iq = self._rec.image(self._k)
            self._img = (np.ascontiguousarray(hm, "<f4").reshape(-1).view(np.uint8), iq)
        return self._img

    @property
    def nbytes(self) -> int:
        return self.n_range * self.n_elevation * self.n_azimuth * 4

    def check(self) -> None:
        self._rec.check_rotation(self._k)

    data = property(lambda self: self._imaged()[0], lambda self, v: None)
    iq = property(lambda self: self._imaged()[1], lambda self, v: None)
