"""The hidden person found by motion between consecutive rotations of a corner.

Radar works that find people behind corners mostly use their motion: what changes between frames
while walls stay (clutter removal across frames; ../shared/FIELD-NOTES.md, "Finding people behind
corners"). Here the cue is read on stage one's own returns, so it needs no training:

1. **change**: per bounce-2/3 return, how much its heatmap bin (±1 bin) changed from the
   neighbouring rotation of the same corner, dB (:func:`change_at_returns`), counted only where the
   bin stands ``min_snr_db`` over its beam's median (a return, not noise whose log swings freely);
2. **persistence**: each un-mirrored return's distance to the neighbouring rotation's un-mirrored
   cloud, both in the world frame (:func:`persistence`): the robot's own motion is compensated here,
   walls land on themselves, a walking person has moved;
3. **the person**: the returns that changed by ``min_change_db`` and moved by ``min_persist_m``
   are clustered (single linkage, :data:`holodata.metrics.HUMAN_CLUSTER_M`, at least
   :data:`~holodata.metrics.HUMAN_MIN_POINTS` points); the cluster with the largest summed
   change × persistence (capped at ``persist_cap_m``) is the person when that score reaches
   ``min_score`` (:func:`moving_person`).

A person who stands still gives neither cue, nor does a second person (one per frame): with
``MotionCue.alone`` (the default) they are not found at all; without it the model's human head is
left to find them. The heatmap's change is not compensated for the robot's motion between
rotations (a few cm at a corner); persistence is. Plain numpy; :class:`MotionScorer` is evaluate's
glue (reads the neighbouring rotation, runs stage one on it, caches the last frames).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from holodata.geometry.unmirror import unmirror
from holodata.metrics import HUMAN_CLUSTER_M, HUMAN_MATCH_M, HUMAN_MIN_POINTS, strongest_clusters


@dataclass(frozen=True)
class MotionCue:
    """Settings of :func:`moving_person` (module docstring), chosen on a development corpus (seed 500,
    benchmarks/results/hidden-person.md): ``min_change_db`` dB, ``min_snr_db`` dB, ``min_persist_m`` m,
    ``persist_cap_m`` m, ``cluster_m`` m, ``min_points``, ``min_score`` (dB·m summed over a cluster);
    ``gated``: read stage one's returns after the confidence gate its stage two was calibrated with
    (True) or all of them (False, the default: on the development corpus the gate dropped most of a
    hidden person's weak returns, halving what any labelling of the cloud can find); ``alone``: the
    cue's centres are the model row's human centres (True, the default: on the development corpus the
    per-beam human head's clusters were 0.9 % precise, so any centre of theirs beside the cue's
    mostly adds a false one) or join the head's (False)."""

    min_change_db: float = 25.0
    min_snr_db: float = 15.0
    min_persist_m: float = 0.05
    persist_cap_m: float = 0.5
    cluster_m: float = HUMAN_CLUSTER_M
    min_points: int = HUMAN_MIN_POINTS
    min_score: float = 70.0
    gated: bool = False
    alone: bool = True

    def to_dict(self) -> dict:
        return asdict(self)


def heatmap_db(heatmap: np.ndarray) -> np.ndarray:
    """20·log10 of a linear-amplitude heatmap, dB (amplitudes under 1e-12 count as 1e-12)."""
    return 20 * np.log10(np.maximum(heatmap, 1e-12))


def change_at_returns(db: np.ndarray, db_other: np.ndarray, ranges: np.ndarray, dr: float,
                      min_snr_db: float) -> np.ndarray:
    """(B,H,W) dB: per return of ``ranges`` (B,H,W) m (NaN = none) the largest |change| between the
    heatmaps ``db`` and ``db_other`` (R,H,W) dB (20·log10 amplitude, same grid) over its range bin
    (bin width ``dr`` m) and the bins either side; 0 where there is no return or where ``db`` at the
    bin is under ``min_snr_db`` over its beam's median."""
    R, H, W = db.shape
    change = np.abs(db - db_other)
    change = np.maximum(change, np.maximum(np.roll(change, 1, 0), np.roll(change, -1, 0)))
    snr = db - np.median(db, axis=0, keepdims=True)
    ok = np.isfinite(ranges)
    k = np.clip(np.floor(np.where(ok, ranges, 0) / dr).astype(np.int64), 0, R - 1)
    e, a = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    c = change[k, e[None], a[None]]
    return np.where(ok & (snr[k, e[None], a[None]] >= min_snr_db), c, 0.0)


def persistence(points_world: np.ndarray, other_world: np.ndarray, cap: float) -> np.ndarray:
    """(N,) m: each of ``points_world`` (N,3)'s distance to the nearest of ``other_world`` (M,3),
    capped at ``cap`` (``cap`` when ``other_world`` is empty)."""
    from scipy.spatial import cKDTree

    if not len(points_world):
        return np.zeros(0)
    if not len(other_world):
        return np.full(len(points_world), float(cap))
    d = cKDTree(other_world).query(points_world, distance_upper_bound=cap)[0]
    return np.minimum(d, cap)


def moving_person(points: np.ndarray, change: np.ndarray, persist: np.ndarray, cue: MotionCue = MotionCue()
                  ) -> np.ndarray:
    """(0 or 1, 3): the centre of the moving person among bounce-2/3 returns ``points`` (N,3) with
    their ``change`` (N,) dB and ``persist`` (N,) m (module docstring, step 3), or none."""
    sel = (change >= cue.min_change_db) & (persist >= cue.min_persist_m) & np.isfinite(points).all(-1)
    w = change[sel] * np.minimum(persist[sel], cue.persist_cap_m)
    return strongest_clusters(points[sel], w, 1, cue.min_score, cue.cluster_m, cue.min_points)


def merge_centres(centres: np.ndarray, extra: np.ndarray, min_dist: float = HUMAN_MATCH_M) -> np.ndarray:
    """``centres`` (K,3) with each of ``extra`` (L,3) that lies ``min_dist`` m or more from all of them."""
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    for c in np.asarray(extra, np.float64).reshape(-1, 3):
        if not len(centres) or np.linalg.norm(centres - c, axis=1).min() >= min_dist:
            centres = np.vstack([centres, c])
    return centres


class MotionScorer:
    """Evaluate's motion cue: :meth:`centres` of frame ``i`` of an opened evaluation (``s``:
    ``holodata.evaluate.pipeline._Opened``), given its baseline-transform heatmap and stage one's
    cloud ranges. The neighbouring rotation (the previous one of the corner, the next for its first)
    is read and run through stage one unless it was just scored; the last ``keep`` frames are cached.
    :meth:`centres` takes stage one's (range images, human probability, cloud ranges) of the frame."""

    def __init__(self, cue: MotionCue, s, beams: dict, keep: int = 3):
        self.cue, self.s, self.beams, self.keep = cue, s, beams, keep
        self.pos = {key: j for j, key in enumerate(s.index)}
        self.cache: dict = {}

    def _frame(self, sid: str, k: int, hm=None, cloud=None) -> tuple:
        """(heatmap dB (R,H,W), cloud ranges (3,H,W), un-mirrored points (3,H,W,3) radar frame, world (3,H,W,3))."""
        key = (sid, k)
        if key not in self.cache:
            from holodata.torch.data import apply_transform

            s = self.s
            if hm is None:
                heat, g_rng, g_lab = s.data.read(self.pos[key])
                hm = apply_transform(heat, g_rng, g_lab, s.base_tf)[0]
                cloud = self._returns(s.run.ranges([heat]), 0)
            geo = self.beams[sid].frame(k, s.run.downsample)
            P = unmirror(cloud, geo.directions, grid=s.grid, origins=geo.origins)["point"]
            self.cache[key] = (heatmap_db(hm), cloud, P, geo.to_world(P))
            while len(self.cache) > self.keep:
                self.cache.pop(next(iter(self.cache)))
        return self.cache[key]

    def _returns(self, pred, j: int | None = None) -> np.ndarray:
        """The returns the cue reads from stage one's output ``pred`` (its batch item ``j``, or the
        frame's own triple when None): the gated cloud ranges or the range images (``cue.gated``)."""
        a = pred[2] if self.cue.gated else pred[0]
        return a if j is None else a[j]

    def centres(self, i: int, hm: np.ndarray, pred: tuple) -> np.ndarray:
        """(0 or 1, 3) radar-frame centre of the moving person in frame ``i`` (none when its corner has
        no other rotation in the split); ``pred``: stage one's (ranges, human probability, cloud ranges)."""
        cloud = self._returns(pred)
        sid, k = self.s.index[i]
        other = next((o for o in ((sid, k - 1), (sid, k + 1)) if o in self.pos), None)
        if other is None:
            return np.zeros((0, 3))
        db, cloud, P, Pw = self._frame(sid, k, hm, cloud)
        db_o, _, _, Pw_o = self._frame(*other)
        change = change_at_returns(db, db_o, cloud, self.s.rb.dr, self.cue.min_snr_db)
        b = np.zeros(cloud.shape, bool)
        b[1:] = True                                              # bounces 2 and 3
        ok = b & np.isfinite(P).all(-1)
        ok_o = np.isfinite(Pw_o).all(-1)
        persist = persistence(Pw[ok], Pw_o[ok_o], self.cue.persist_cap_m)
        return moving_person(P[ok], change[ok], persist, self.cue)


__all__ = ["MotionCue", "MotionScorer", "change_at_returns", "heatmap_db", "merge_centres", "moving_person", "persistence"]
