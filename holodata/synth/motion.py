"""Robot motion: a true trajectory approaching the corner and drifting odometry.

The robot starts at rest, accelerates (≤ 0.4 m/s²) to a cruise speed in 0.3–0.5 m/s, slows down
and stops before the corner; a slow lateral weave and yaw wobble make it less ideal. Poses are
``T_world_base`` (base_link on the floor, REP-103). Odometry integrates the true body-frame
increments with a scale error, a yaw-rate bias and random walk, starting at identity in ``odom``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..conventions import yaw_rad
from ..trajectory import Trajectory


def pose_xy_yaw(x, y, yaw, z=0.0) -> np.ndarray:
    """(N,4,4) planar poses from arrays x, y, yaw (rad)."""
    x, y, yaw = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(yaw, float))
    T = np.zeros(x.shape + (4, 4))
    c, s = np.cos(yaw), np.sin(yaw)
    T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1] = c, -s, s, c
    T[..., 2, 2] = 1.0
    T[..., 0, 3], T[..., 1, 3], T[..., 2, 3] = x, y, z
    T[..., 3, 3] = 1.0
    return T


def speed_profile(t: np.ndarray, distance: float, v_max: float, accel: float, t_start: float) -> np.ndarray:
    """Arc length s(t) (m) of a trapezoidal speed profile starting at rest at ``t_start`` that
    covers ``distance`` and then stays stopped."""
    # shrink the cruise speed if the distance is too short to reach it
    v = min(v_max, np.sqrt(accel * distance))
    t_acc = v / accel
    d_acc = 0.5 * accel * t_acc ** 2
    t_cru = max(0.0, (distance - 2 * d_acc) / v)
    tt = np.clip(np.asarray(t, float) - t_start, 0.0, None)
    s = np.where(tt < t_acc, 0.5 * accel * tt ** 2, 0.0)
    m = (tt >= t_acc) & (tt < t_acc + t_cru)
    s = np.where(m, d_acc + v * (tt - t_acc), s)
    td = tt - t_acc - t_cru
    m = (td >= 0) & (td < t_acc)
    s = np.where(m, d_acc + v * t_cru + v * td - 0.5 * accel * td ** 2, s)
    s = np.where(td >= t_acc, distance, s)
    return s


def weave(s: np.ndarray, amp: float, omega: float, ramp_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Lateral offset (m) of the robot's path at arc length ``s`` (m) and its slope d(offset)/ds: a
    sine of amplitude ``amp`` (m) and spatial frequency ``omega`` (rad/m), faded in over the first
    ``ramp_m`` with a smoothstep, so that the heading (the slope's arctan) is smooth everywhere: at
    most ~10 deg/s of yaw rate (a linear fade-in would put a heading step in the path that no robot
    drives and no LiDAR scan across it can be de-skewed for: ``docs/design/synth.md``)."""
    x = np.clip(np.asarray(s, float) / ramp_m, 0.0, 1.0)
    ramp = x * x * (3.0 - 2.0 * x)
    dramp = 6.0 * x * (1.0 - x) / ramp_m
    sn, cs = np.sin(omega * s), np.cos(omega * s)
    return amp * sn * ramp, amp * (omega * cs * ramp + sn * dramp)


def robot_trajectory(start_xy, stop_xy, duration_s: float, t0_ns: int, rng: np.random.Generator,
                     rate_hz: float = 200.0) -> tuple[Trajectory, dict]:
    """True base_link trajectory over ``duration_s`` seconds from ``t0_ns``; returns it and its
    parameters (cruise speed, distance, ...)."""
    start, stop = np.asarray(start_xy, float), np.asarray(stop_xy, float)
    v_max = float(rng.uniform(0.3, 0.5))
    accel = float(rng.uniform(0.25, 0.4))
    t_start = float(rng.uniform(0.2, 0.8))
    total = float(np.linalg.norm(stop - start))
    # do not plan farther than can be driven in the time available
    usable = max(0.5, duration_s - t_start - 0.5)
    reach = v_max * usable - v_max ** 2 / accel if usable > 2 * v_max / accel else 0.25 * accel * usable ** 2
    distance = float(min(total, max(0.2, reach)))
    d = (stop - start) / max(total, 1e-9)
    n = int(np.ceil(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    s = speed_profile(t, distance, v_max, accel, t_start)
    # end the path at the stop point: start farther back if the robot cannot cover it all
    begin = stop - d * distance
    weave_amp = float(rng.uniform(0.0, 0.05))
    weave_f = float(rng.uniform(0.05, 0.15))
    lat, dlat_ds = weave(s, weave_amp, 2 * np.pi * weave_f / max(v_max, 1e-3))
    nrm = np.array([-d[1], d[0]])
    xy = begin + s[:, None] * d + lat[:, None] * nrm
    heading = np.arctan2(d[1], d[0])
    yaw = heading + np.arctan(dlat_ds)     # the path's tangent: the robot drives where it points
    yaw = yaw + np.deg2rad(float(rng.uniform(-3, 3)))  # mounting / steering offset
    poses = pose_xy_yaw(xy[:, 0], xy[:, 1], yaw)
    t_ns = t0_ns + np.round(t * 1e9).astype(np.int64)
    info = {"cruise_speed_mps": v_max, "accel_mps2": accel, "start_delay_s": t_start, "distance_m": distance,
            "start_xy": np.round(begin, 4).tolist(), "stop_xy": np.round(stop, 4).tolist()}
    return Trajectory(t_ns, poses), info


def odometry(truth: Trajectory, rng: np.random.Generator, rate_hz: float = 30.0,
             scale_error: float | None = None, yaw_bias_dps: float | None = None) -> tuple[Trajectory, dict]:
    """Drifting wheel-odometry poses ``T_odom_base`` at ``rate_hz`` (identity at the first sample)."""
    t0, t1 = int(truth.timestamp_ns[0]), int(truth.timestamp_ns[-1])
    step = int(round(1e9 / rate_hz))
    t_ns = np.arange(t0, t1 + 1, step, dtype=np.int64)
    P = truth.interpolate(t_ns)
    scale = 1.0 + (float(rng.uniform(-0.03, 0.03)) if scale_error is None else scale_error)
    bias = np.deg2rad(float(rng.uniform(-0.8, 0.8)) if yaw_bias_dps is None else yaw_bias_dps)
    dt = step / 1e9
    out = np.zeros_like(P)
    out[0] = np.eye(4)
    for k in range(1, len(P)):
        D = np.linalg.inv(P[k - 1]) @ P[k]
        dyaw = yaw_rad(D)
        moving = np.linalg.norm(D[:2, 3]) > 1e-5
        noise_t = rng.normal(0.0, 0.002 * np.sqrt(dt)) if moving else 0.0
        noise_y = rng.normal(0.0, np.deg2rad(0.2) * np.sqrt(dt)) if moving else 0.0
        dyaw_n = dyaw + (bias * dt if moving else 0.0) + noise_y
        D2 = np.eye(4)
        D2[:3, :3] = Rotation.from_euler("z", dyaw_n).as_matrix()
        D2[:2, 3] = D[:2, 3] * scale + noise_t
        out[k] = out[k - 1] @ D2
    return Trajectory(t_ns, out), {"rate_hz": rate_hz, "scale": scale, "yaw_bias_dps": float(np.rad2deg(bias))}


def _fillet_path(waypoints: np.ndarray, radius: float, step: float = 0.01) -> np.ndarray:
    """(N,2) points every ~``step`` m along the polyline ``waypoints`` (K,2) with each inner corner
    replaced by a circular arc of ``radius`` m (shrunk where a leg is too short for it), so the heading
    is continuous along the path."""
    P = np.asarray(waypoints, float)
    pieces = [P[:1]]
    cur = P[0]
    for k in range(1, len(P) - 1):
        a, b, c = P[k - 1], P[k], P[k + 1]
        u, v = b - a, c - b
        lu, lv = np.linalg.norm(u), np.linalg.norm(v)
        u, v = u / lu, v / lv
        turn = np.arctan2(u[0] * v[1] - u[1] * v[0], u @ v)   # signed turn angle (rad)
        if abs(turn) < 1e-6:
            continue
        # tangent length of the fillet, limited to under half of each leg
        tl = min(radius * np.tan(abs(turn) / 2), 0.49 * lu, 0.49 * lv)
        r = tl / np.tan(abs(turn) / 2)
        p_in, p_out = b - u * tl, b + v * tl
        n = np.array([-u[1], u[0]]) * np.sign(turn)        # towards the arc's centre
        centre = p_in + n * r
        seg = np.linalg.norm(p_in - cur)
        m = max(2, int(np.ceil(seg / step)) + 1)
        pieces.append(cur + (p_in - cur) * np.linspace(0, 1, m)[1:, None])
        a0 = np.arctan2(*(p_in - centre)[::-1])
        m = max(2, int(np.ceil(abs(turn) * r / step)) + 1)
        ang = a0 + np.sign(turn) * np.linspace(0, abs(turn), m)[1:]
        pieces.append(centre + r * np.column_stack([np.cos(ang), np.sin(ang)]))
        cur = p_out
    seg = np.linalg.norm(P[-1] - cur)
    m = max(2, int(np.ceil(seg / step)) + 1)
    pieces.append(cur + (P[-1] - cur) * np.linspace(0, 1, m)[1:, None])
    return np.concatenate(pieces)


@dataclass(frozen=True)
class DriveProfile:
    """How :func:`path_trajectory` drives a path: corners rounded to arcs of ``turn_radius`` m, a
    trapezoidal speed profile (cruise ``speed`` m/s, ``accel`` m/s²) that slows on the arcs so the yaw
    rate stays below ``max_yaw_rate`` rad/s; poses sampled at ``rate_hz``; at rest for ``t_start`` s
    before, ``t_end`` s after and ``pause_s`` s between legs."""

    speed: float = 0.6
    accel: float = 0.4
    turn_radius: float = 0.6
    max_yaw_rate: float = 0.8
    rate_hz: float = 200.0
    t_start: float = 0.3
    t_end: float = 0.3
    pause_s: float = 0.5


def _leg(waypoints: np.ndarray, drive: DriveProfile):
    """One leg from rest to rest along ``waypoints``: (t (N,) s from its start, x, y, tangent heading
    (N,) rad, length m) at the 1 cm path samples."""
    speed, accel, max_yaw_rate = drive.speed, drive.accel, drive.max_yaw_rate
    xy = _fillet_path(np.asarray(waypoints, float), drive.turn_radius)
    ds = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    xy = xy[np.r_[True, ds > 1e-9]]
    s_pts = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    head = np.unwrap(np.arctan2(*np.diff(xy, axis=0).T[::-1]))
    head = np.r_[head, head[-1]]
    # curvature -> speed limit along the path, then a forward/backward pass for the acceleration limit
    kappa = np.abs(np.gradient(head, s_pts, edge_order=1)) if len(s_pts) > 2 else np.zeros(len(s_pts))
    v = np.minimum(speed, max_yaw_rate / np.maximum(kappa, 1e-9))
    v[0] = v[-1] = 0.0
    dsg = np.diff(s_pts)
    for i in range(1, len(v)):
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * accel * dsg[i - 1]))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * accel * dsg[i]))
    t_pts = np.r_[0.0, np.cumsum(dsg / np.maximum(0.5 * (v[1:] + v[:-1]), 1e-3))]
    return t_pts, xy[:, 0], xy[:, 1], head, float(s_pts[-1])


def path_trajectory(waypoints, t0_ns: int, rng: np.random.Generator, drive: DriveProfile = DriveProfile(),
                    legs: list | None = None) -> tuple[Trajectory, dict]:
    """True base_link trajectory along the plan-view polyline ``waypoints`` (K,2) m, driven as
    ``drive`` says (:class:`DriveProfile`: arcs at the corners, speed profile, rests), the robot
    heading along the path (plus a fixed ±2° mounting offset drawn from ``rng``). ``legs``
    [(waypoints (K,2), reverse bool), ...] instead: driven one after the other, each from rest to rest
    with ``drive.pause_s`` between them, a ``reverse`` leg backwards (the heading stays that of the leg
    before: a robot backing out of a branch). Returns it and its parameters (length, duration)."""
    speed, turn_radius, max_yaw_rate, rate_hz = drive.speed, drive.turn_radius, drive.max_yaw_rate, drive.rate_hz
    t_start, t_end, pause_s = drive.t_start, drive.t_end, drive.pause_s
    legs = [(np.asarray(waypoints, float), False)] if legs is None else [(np.asarray(w, float), bool(r)) for w, r in legs]
    ts, xs, ys, hs, length, t_off = [], [], [], [], 0.0, t_start
    for k, (wp, rev) in enumerate(legs):
        t_pts, x, y, h, L = _leg(wp, drive)
        h = h + (np.pi if rev else 0.0)
        if hs:   # the heading continues from the leg before (no jump of 2 pi)
            h = h + 2 * np.pi * np.round((hs[-1][-1] - h[0]) / (2 * np.pi))
        ts.append(t_off + t_pts)
        xs.append(x)
        ys.append(y)
        hs.append(h)
        length += L
        t_off = float(ts[-1][-1]) + (pause_s if k < len(legs) - 1 else 0.0)
    t_pts, x_pts, y_pts, h_pts = (np.concatenate(a) for a in (ts, xs, ys, hs))
    duration = float(t_pts[-1] + t_end)
    n = int(np.ceil(duration * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    # piecewise-linear in time between the 1 cm samples (at rest before, between legs and after)
    order = np.argsort(t_pts, kind="stable")
    t_pts, x_pts, y_pts, h_pts = t_pts[order], x_pts[order], y_pts[order], h_pts[order]
    x, y = np.interp(t, t_pts, x_pts), np.interp(t, t_pts, y_pts)
    yaw = np.interp(t, t_pts, h_pts) + np.deg2rad(float(rng.uniform(-2, 2)))
    poses = pose_xy_yaw(x, y, yaw)
    t_ns = t0_ns + np.round(t * 1e9).astype(np.int64)
    info = {"kind": "waypoints", "legs": [{"waypoints": np.round(w, 4).tolist(), "reverse": r} for w, r in legs],
            "length_m": float(length), "duration_s": duration, "cruise_speed_mps": float(speed),
            "turn_radius_m": float(turn_radius), "max_yaw_rate_rps": float(max_yaw_rate)}
    return Trajectory(t_ns, poses), info
