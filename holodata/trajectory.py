"""Trajectories: TUM text files and pose interpolation.

TUM lines are ``timestamp tx ty tz qx qy qz qw`` (seconds; quaternion x y z w). Poses are
``T_world_sensor`` (N, 4, 4) float64; timestamps are int64 nanoseconds.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .conventions import ns_to_seconds, seconds_to_ns
from .errors import InputError
from .geometry.rotations import matrix_from_quat, quat_from_matrix, slerp


@dataclass
class Trajectory:
    """``timestamp_ns``: (N,) int64, strictly increasing; ``poses``: (N, 4, 4) float64 T_world_sensor."""

    timestamp_ns: np.ndarray
    poses: np.ndarray
    # the poses' quaternions for SLERP, made at the first interpolate (poses are not to be edited in place after)
    _quats: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.timestamp_ns)

    def interpolate(self, t_ns: np.ndarray) -> np.ndarray:
        """Poses at times ``t_ns`` (any shape): linear translation, SLERP rotation; clamped at the ends.

        Returns ``t_ns.shape + (4, 4)`` float64.
        """
        t_ns = np.asarray(t_ns, dtype=np.int64)
        flat = t_ns.reshape(-1)
        if len(self) == 1:
            out = np.broadcast_to(self.poses[0], (flat.size, 4, 4)).copy()
            return out.reshape(t_ns.shape + (4, 4))
        ts = self.timestamp_ns.astype(np.float64)
        q = np.clip(flat.astype(np.float64), ts[0], ts[-1])
        if self._quats is None:
            self._quats = quat_from_matrix(self.poses[:, :3, :3])
        out = np.zeros((flat.size, 4, 4))
        out[:, :3, :3] = matrix_from_quat(slerp(ts, self._quats, q))
        for k in range(3):
            out[:, k, 3] = np.interp(q, ts, self.poses[:, k, 3])
        out[:, 3, 3] = 1.0
        return out.reshape(t_ns.shape + (4, 4))


def poses_from_tum_rows(rows: np.ndarray) -> np.ndarray:
    """(N, 7) ``tx ty tz qx qy qz qw`` to (N, 4, 4) float64."""
    poses = np.zeros((len(rows), 4, 4))
    poses[:, :3, :3] = matrix_from_quat(rows[:, 3:7])
    poses[:, :3, 3] = rows[:, :3]
    poses[:, 3, 3] = 1.0
    return poses


def _stamp_ns(token: str, value: float) -> int:
    """Seconds as written (e.g. ``1735693200.548947099``) to int64 ns without the ~0.2 µs a float64
    loses at epoch scale; exponent notation falls back to the float value."""
    sign, digits = (-1, token[1:]) if token.startswith("-") else (1, token.lstrip("+"))
    whole, _, frac = digits.partition(".")
    if whole.isdigit() and (frac.isdigit() or not frac):
        return sign * (int(whole) * 1_000_000_000 + int((frac + "000000000")[:9]))
    return int(seconds_to_ns(np.array([value]))[0])


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory; comments (``#``) and blank lines are skipped.

    Raises :class:`InputError` naming the file and line for malformed content.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read trajectory ({err.__class__.__name__}: {err})") from err
    stamps, rows = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(f"{path}:{lineno}: expected 8 numbers (t tx ty tz qx qy qz qw), got {len(parts)}")
        try:
            vals = [float(p) for p in parts]
        except ValueError as err:
            raise InputError(f"{path}:{lineno}: not a number in {line!r}") from err
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}:{lineno}: non-finite value")
        q = np.array(vals[4:8])
        if abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise InputError(f"{path}:{lineno}: quaternion is not unit length (|q| = {np.linalg.norm(q):.4f})")
        stamps.append(_stamp_ns(parts[0], vals[0]))
        rows.append(vals[1:])
    if not rows:
        raise InputError(f"{path}: trajectory has no poses")
    t_ns = np.array(stamps, dtype=np.int64)
    bad = np.nonzero(np.diff(t_ns) <= 0)[0]
    if bad.size:
        raise InputError(f"{path}: timestamps not strictly increasing at pose {bad[0] + 1}")
    return Trajectory(t_ns, poses_from_tum_rows(np.array(rows)))


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """Write a TUM trajectory (timestamps in seconds with ns precision)."""
    q = quat_from_matrix(traj.poses[:, :3, :3])
    t = traj.poses[:, :3, 3]
    with open(path, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for ts, ti, qi in zip(traj.timestamp_ns, t, q):
            sec, nsec = divmod(int(ts), 1_000_000_000)
            f.write(f"{sec}.{nsec:09d} " + " ".join(f"{v:.9f}" for v in (*ti, *qi)) + "\n")


__all__ = ["Trajectory", "read_tum", "write_tum", "poses_from_tum_rows", "ns_to_seconds"]
