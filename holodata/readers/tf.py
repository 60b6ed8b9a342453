"""TF: static extrinsics (``/tf_static``) and a buffer of dynamic transforms (``/tf``).

Edges are stored as ``T_parent_child`` (4x4 float64, maps child-frame points into the parent
frame). :meth:`TransformBuffer.lookup` walks the tree between two frames, composing static edges
and dynamic edges interpolated at the query time (linear translation, SLERP rotation); a dynamic
edge queried more than ``max_gap_ns`` outside its recorded span gives None rather than an
extrapolated guess. Fed from ``tf2_msgs/TFMessage`` (ROS 2, ROS 1) and ``tf/tfMessage`` (ROS 1).
"""
from __future__ import annotations

from collections import defaultdict, deque

import numpy as np

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")


def quat_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """3x3 rotation of a quaternion (x, y, z, w), normalised first; zero -> identity."""
    n = x * x + y * y + z * z + w * w
    if n == 0.0:
        return np.eye(3)
    s = 2.0 / n
    return np.array([[1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
                     [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
                     [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)]])


def transform_matrix(tf) -> np.ndarray:
    """geometry_msgs/Transform -> 4x4 float64."""
    q = tf.rotation
    t = tf.translation
    T = np.eye(4)
    T[:3, :3] = quat_matrix(float(q.x), float(q.y), float(q.z), float(q.w))
    T[:3, 3] = (t.x, t.y, t.z)
    return T


def _strip(frame: str) -> str:
    return str(frame).lstrip("/")


def _stamp(h) -> int:
    st = h.stamp
    nsec = getattr(st, "nanosec", None)
    if nsec is None:
        nsec = getattr(st, "nsec", 0)
    return int(st.sec) * 1_000_000_000 + int(nsec)


class TransformBuffer:
    def __init__(self, max_gap_ns: int = 200_000_000):
        self.static: dict[tuple[str, str], np.ndarray] = {}
        self._dyn: dict[tuple[str, str], list[tuple[int, np.ndarray]]] = defaultdict(list)
        self._traj: dict = {}
        self.max_gap_ns = int(max_gap_ns)

    # -- filling ------------------------------------------------------------------------------------
    def add(self, parent: str, child: str, T: np.ndarray, t_ns: int | None = None, static: bool = False) -> None:
        key = (_strip(parent), _strip(child))
        if static:
            self.static[key] = np.asarray(T, np.float64)
        else:
            self._dyn[key].append((int(t_ns), np.asarray(T, np.float64)))
            self._traj.pop(key, None)

    def add_message(self, msg, static: bool = False) -> int:
        """Add every TransformStamped of a TFMessage; returns how many. A transform holding a NaN/inf
        translation or rotation (damaged bytes) is left out (not counted): it would make every pose
        composed through it NaN, which validate rejects."""
        n = 0
        for ts in msg.transforms:
            T = transform_matrix(ts.transform)
            if np.isfinite(T).all():
                self.add(ts.header.frame_id, ts.child_frame_id, T, _stamp(ts.header), static)
                n += 1
        return n

    # -- queries ------------------------------------------------------------------------------------
    @property
    def frames(self) -> set[str]:
        return {f for k in list(self.static) + list(self._dyn) for f in k}

    @property
    def dynamic_edges(self) -> list[tuple[str, str]]:
        return sorted(k for k in self._dyn if k not in self.static)

    def _trajectory(self, key):
        from ..trajectory import Trajectory

        tr = self._traj.get(key)
        if tr is None:
            items = sorted(self._dyn[key], key=lambda x: x[0])
            ts = np.array([t for t, _ in items], np.int64)
            keep = np.r_[ts[1:] != ts[:-1], True]   # equal stamps: the later message wins
            tr = Trajectory(ts[keep], np.stack([T for (_, T), k in zip(items, keep) if k]))
            self._traj[key] = tr
        return tr

    def _edge(self, key, t_ns, static_only: bool):
        if key in self.static:
            return self.static[key]
        if static_only or key not in self._dyn:
            return None
        tr = self._trajectory(key)
        if t_ns is None:
            return None
        if t_ns < tr.timestamp_ns[0] - self.max_gap_ns or t_ns > tr.timestamp_ns[-1] + self.max_gap_ns:
            return None
        return tr.interpolate(np.array([t_ns]))[0]

    def _path(self, a: str, b: str, static_only: bool):
        """Frames from a to b with the edge direction: list of (key, forward)."""
        adj: dict[str, list] = defaultdict(list)
        keys = list(self.static) + ([] if static_only else [k for k in self._dyn if k not in self.static])
        for p, c in keys:
            adj[p].append((c, (p, c), True))
            adj[c].append((p, (p, c), False))
        prev = {a: None}
        q = deque([a])
        while q:
            f = q.popleft()
            if f == b:
                break
            for g, key, fwd in adj[f]:
                if g not in prev:
                    prev[g] = (f, key, fwd)
                    q.append(g)
        if b not in prev:
            return None
        path = []
        f = b
        while prev[f] is not None:
            g, key, fwd = prev[f]
            path.append((key, fwd))
            f = g
        return path[::-1]

    def lookup(self, target: str, source: str, t_ns: int | None = None, static_only: bool = False) -> np.ndarray | None:
        """``T_target_source`` at ``t_ns`` (4x4), or None if the frames are not connected (or a
        dynamic edge has no data near ``t_ns``)."""
        target, source = _strip(target), _strip(source)
        if target == source:
            return np.eye(4)
        path = self._path(target, source, static_only)
        if path is None:
            return None
        T = np.eye(4)
        for key, fwd in path:
            E = self._edge(key, t_ns, static_only)
            if E is None:
                return None
            # walking target -> source: along parent->child multiply by T_parent_child
            T = T @ (E if fwd else np.linalg.inv(E))
        return T

    def lookup_many(self, target: str, source: str, t_ns) -> tuple[np.ndarray, np.ndarray] | None:
        """``T_target_source`` at each time of ``t_ns`` (N,): (N, 4, 4) poses and an (N,) bool mask
        of the times every dynamic edge covers (within ``max_gap_ns``); None if not connected."""
        target, source = _strip(target), _strip(source)
        t = np.asarray(t_ns, np.int64).reshape(-1)
        out = np.broadcast_to(np.eye(4), (len(t), 4, 4)).copy()
        ok = np.ones(len(t), bool)
        if target == source:
            return out, ok
        path = self._path(target, source, False)
        if path is None:
            return None
        for key, fwd in path:
            if key in self.static:
                E = np.broadcast_to(self.static[key], (len(t), 4, 4))
            else:
                tr = self._trajectory(key)
                ok &= (t >= tr.timestamp_ns[0] - self.max_gap_ns) & (t <= tr.timestamp_ns[-1] + self.max_gap_ns)
                E = tr.interpolate(t)
            out = out @ (E if fwd else np.linalg.inv(E))
        return out, ok

    def root(self, frame: str) -> str:
        """The top of ``frame``'s tree (following child -> parent edges)."""
        parent = {c: p for p, c in list(self.static) + list(self._dyn)}
        f = _strip(frame)
        seen = set()
        while f in parent and f not in seen:
            seen.add(f)
            f = parent[f]
        return f

    def time_span(self, key) -> tuple[int, int]:
        tr = self._trajectory(key)
        return int(tr.timestamp_ns[0]), int(tr.timestamp_ns[-1])


def find_frame(frames, candidates) -> str | None:
    """The first of ``candidates`` present in ``frames``."""
    fs = set(frames)
    return next((c for c in candidates if c in fs), None)


WORLD_FRAMES = ("map", "world", "odom")
BASE_FRAMES = ("base_link", "base_footprint", "base")
