"""The named steps :func:`~holodata.mapping.register.pipeline.register_scene` runs (module doc of
:mod:`holodata.mapping.register`): the stored report of a scene done before, the initial guess, the
static camera cloud (step 1), the failure message of the extrinsic's check (step 3), the human
candidates, picks and track (step 4), the closed surfaces (step 5) and the writes. Each gets what it
works on (a scene handle, arrays, the settings), never a dataset URL to reopen."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...conventions import transform_points
from ...dataset.layout import CALIB_T_WORLD_CAMERA, CAMERA_POINTS_WORLD, HUMAN_FACES, HUMAN_POINTS, HUMAN_VERTICES
from ...errors import InputError
from ...parallel import fork_call
from .camera import (
    CameraFrames,
    ForegroundTest,
    camera_seen_through,
    camera_swept,
    depth_noise_model,
    frame_candidates,
    static_depth,
)
from .config import RegisterConfig, Registration
from .humans import ColumnShape, body_columns, closed_surface, column_centroid, pick_human, silhouette_cut, static_residual
from .scene_inputs import camera_tf_guess, map_frame_problem
from .tracks import cut_prediction, radial_speed, side_back, track_jumps, track_prediction, track_smooth, velocity_shift

# the floor under a person: the FLOOR_PERCENTILE-th percentile of the map's heights within
# FLOOR_RADIUS_M (plan) of the track (low outliers aside), from more than FLOOR_MIN_POINTS points
FLOOR_RADIUS_M = 2.5
FLOOR_PERCENTILE = 2
FLOOR_MIN_POINTS = 50

def initial_guess(scene, url: str, T_init: np.ndarray | None) -> tuple[np.ndarray, str]:
    """(T_world_camera guess (4,4), its source "--init" or "tf"): ``T_init`` when given, else the
    camera's TF pose in the map's world frame. InputError (one line) without one, or when the TF
    world is not the frame the LiDAR map is in."""
    if T_init is not None:
        return T_init, "--init"
    world, tf = camera_tf_guess(scene)
    if tf is None:
        raise InputError(f"{url}: scene {scene.id!r}: no TF pose of the camera in a world frame (sensors.camera."
                         f"T_<world>_sensor); give --init x,y,z,roll,pitch,yaw")
    problem = map_frame_problem(scene, world)
    if problem:
        raise InputError(f"{url}: scene {scene.id!r}: the camera's TF pose is in {world!r} but {problem}; register "
                         f"cannot start from it: give --init x,y,z,roll,pitch,yaw in the map's frame")
    return np.asarray(tf, float), "tf"


@dataclass
class StaticCamera:
    """Step 1's result. Per pixel (H,W): ``med`` static depth (m, NaN: none), ``mad`` its spread (m),
    ``cnt`` background samples; ``rays`` (H,W,3) unit-depth rays; ``okm`` (H,W) pixels with a static
    depth; ``points`` (N,3) the static camera cloud (camera frame, m) of those pixels, ``sigma`` (N,) its
    depth noise (m), ``residual`` (N,) bool its points on no large plane (:func:`static_residual`);
    ``images``: {frame: depth image} made on the way (used again for the humans)."""

    med: np.ndarray
    mad: np.ndarray
    cnt: np.ndarray
    rays: np.ndarray
    okm: np.ndarray
    points: np.ndarray
    sigma: np.ndarray
    residual: np.ndarray
    images: dict


def static_camera(cam: CameraFrames, cfg: RegisterConfig, quiet: bool) -> StaticCamera | None:
    """Step 1: the static depth from an evenly spread subset (``median_frames``) of the frames with
    points, and the static camera cloud; None when every frame is empty. Every frame's depth image is
    made again in the humans step (a recording's images never sit in memory together)."""
    cam_frames = [int(k) for k in np.flatnonzero(cam.counts() > 0)]
    if len(cam_frames) > cfg.median_frames:
        cam_frames = [cam_frames[i] for i in np.linspace(0, len(cam_frames) - 1, cfg.median_frames).round().astype(int)]
    images: dict = {}
    static = static_depth(cam, cam_frames, quiet, images=images)
    if static is None:
        return None
    med, mad, cnt = static
    rays = cam.rays()
    okm = np.isfinite(med) & (cnt > 0)
    points = rays[okm] * med[okm][:, None]
    sigma = depth_noise_model(med[okm], mad[okm]) / np.sqrt(cnt[okm])
    return StaticCamera(med, mad, cnt, rays, okm, points, sigma, static_residual(points, cfg), images)


def attempt_problem(x: dict, cfg: RegisterConfig) -> str:
    """The check an attempt ``x`` (one of :class:`Registration`'s ``attempts``) failed, in a few words
    with the limit it missed: the overlap, the fitness, the RMSE, a fallback's distance from the guess,
    the pose's standard deviation along a measured direction, or its slide off the guess along a
    held one (:func:`~.extrinsic.check_held`)."""
    if "prior_shift_m" in x and (x["prior_shift_m"] > cfg.fallback_max_shift_m
                                 or x["prior_rot_deg"] > cfg.fallback_max_rot_deg):
        return (f"{x['prior_shift_m']:.1f} m / {x['prior_rot_deg']:.0f} deg from the guess (at most "
                f"{cfg.fallback_max_shift_m:g} m / {cfg.fallback_max_rot_deg:g} deg)")
    if x["overlap"] < cfg.min_overlap_points:
        return f"{x['overlap']} camera points on the map (at least {cfg.min_overlap_points})"
    if x["fitness"] < cfg.min_fitness:
        return f"fitness {x['fitness']:.2f} (at least {cfg.min_fitness:g})"
    if x["rmse"] > cfg.max_rmse_m:
        return f"rmse {x['rmse'] * 100:.1f} cm (at most {cfg.max_rmse_m * 100:g} cm)"
    std = x.get("pose_std_m", float("nan"))
    if not std <= cfg.max_pose_std_m:
        return f"pose std {std * 100:.1f} cm (at most {cfg.max_pose_std_m * 100:g} cm)"
    slide = max((abs(v) for v in x.get("held_slide_m") or []), default=0.0)
    if slide > cfg.max_pose_std_m:
        return (f"{slide * 100:.1f} cm off the guess along a direction the data does not constrain (at most "
                f"{cfg.max_pose_std_m * 100:g} cm)")
    return "failed its check"


ATTEMPT_NAMES = {"icp": "ICP", "fpfh+icp": "FPFH fallback"}


def registration_failure(where: str, reg: Registration, cfg: RegisterConfig, init_source: str) -> str:
    """The one-line message of a registration whose attempts all failed their check (``where``: the
    dataset and scene): what failed, each attempt's missed check (:func:`attempt_problem`), what the
    scene is left with and what the user can do. The numbers of every check are in the scene's
    ``register_failed`` attribute (and ``--json``), not in the line."""
    what = "; ".join(f"{ATTEMPT_NAMES.get(x['method'], x['method'])}"
                     f"{' from the ' + init_source + ' guess' if x['method'] == 'icp' else ''}: {attempt_problem(x, cfg)}"
                     for x in reg.attempts)
    return (f"{where}: the camera could not be registered to the LiDAR map ({what}); the scene is kept without a "
            f"person; give --init X,Y,Z,ROLL,PITCH,YAW nearer the camera's pose (details: --json)")


def clear_outputs(sw, cfg: RegisterConfig, calib: bool = False) -> None:
    """Remove a previous run's human arrays and camera copy (with ``calib`` also
    ``calib/T_world_camera``) from scene writer ``sw``; make ``camera/points_world`` when
    ``write_camera_world`` and not ``calib`` (filled by :func:`camera_world`)."""
    for name in (HUMAN_VERTICES, HUMAN_FACES, HUMAN_POINTS, CAMERA_POINTS_WORLD) + ((CALIB_T_WORLD_CAMERA,) if calib else ()):
        if name in sw.arrays():
            sw.remove(name)
    if cfg.write_camera_world and not calib:
        sw.ragged_array(CAMERA_POINTS_WORLD)


@dataclass
class Candidates:
    """Step 4's candidates: per frame (qw world points (N,3), rows (N,), columns (N,), depths (N,)) of
    the returns that may be the person; ``carved``: map points the camera sees through (M,) bool."""

    frames: list
    carved: np.ndarray


def human_candidates(cam: CameraFrames, static: StaticCamera, M: np.ndarray, T: np.ndarray, cfg: RegisterConfig,
                     processes: int, quiet: bool, label: str) -> Candidates:
    """Step 4, candidates: returns in front of the static depth (a moving person) or on no large plane
    of the static cloud and not explained by the map (a person standing still, in the temporal
    background), in every frame; the later half of the frames in a second process (numpy and scipy
    only: it may fork after open3d's OpenMP) when ``processes`` > 1."""
    from scipy.spatial import cKDTree

    sigma = np.where(np.isfinite(static.mad), static.mad, 0.0)
    # map points the camera sees through, or sees a walk along its line of sight sweep over (a person
    # the LiDAR map kept), explain nothing away
    carved = camera_seen_through(M, T, cam.K, cam.shape, static.images.values(),
                                 np.maximum(cfg.fg_min_m, cfg.fg_sigma * depth_noise_model(
                                     np.where(np.isfinite(static.med), static.med, 0.0), sigma)))
    carved |= camera_swept(M, T, cam.K, cam.shape, static.images.values(), static.med)
    mtree = cKDTree(M[~carved])
    still = np.zeros(static.med.shape, bool)
    if static.residual.any():
        sw_ = transform_points(T, static.points[static.residual])
        dmap_ = mtree.query(sw_, k=1, distance_upper_bound=np.nextafter(cfg.map_explain_m, np.inf), workers=-1)[0]
        rr = np.zeros(len(static.points), bool)
        rr[np.flatnonzero(static.residual)[dmap_ > cfg.map_explain_m]] = True
        still[static.okm] = rr
    front = static.med - np.maximum(cfg.fg_min_m, cfg.fg_sigma * sigma)    # a return nearer than this moved
    always = ~np.isfinite(static.med) | still
    n = cam.scene.n_frames
    half = n // 2 if processes > 1 else n
    test = ForegroundTest(T, static.rays, front, always, mtree)
    later = fork_call(frame_candidates, cam, range(half, n), test, cfg, static.images,
                      label=f"{label}: human candidates", enabled=half < n)
    cand = frame_candidates(cam, range(half), test, cfg, static.images, quiet, f"register {cam.scene.id}")
    cand += later()
    return Candidates(cand, carved)


def floor_below(M: np.ndarray, centre: np.ndarray | None) -> float | None:
    """The floor under the person (:data:`FLOOR_RADIUS_M`, :data:`FLOOR_PERCENTILE`) around the
    track's ``centre`` (3,), None without a centre or with :data:`FLOOR_MIN_POINTS` map points or fewer there."""
    if centre is None:
        return None
    near = np.linalg.norm(M[:, :2] - centre[:2], axis=1) < FLOOR_RADIUS_M
    return float(np.percentile(M[near, 2], FLOOR_PERCENTILE)) if near.sum() > FLOOR_MIN_POINTS else None


def body_only(qw: np.ndarray, hm: np.ndarray, eye: np.ndarray, floor_z: float | None, cfg: RegisterConfig) -> np.ndarray:
    """The pick ``hm`` (N,) bool of the world points ``qw`` (N,3) without stereo streaks along the rays
    (a body is at most ``max_depth_spread_m`` deep along the view from ``eye``) and floor returns at
    the feet (``floor_margin_m`` above ``floor_z``).

    The depth along the view is the plan (horizontal) distance from the eye, as in :func:`body_columns`:
    a standing body is a vertical column, and its depth is horizontal. The 3-D range also grows with
    the height below a camera mounted above the person (2.5 m away in plan under a camera 2.4 m up, the
    feet are 0.6 m farther than the torso), so a cut on it takes the legs away and lifts the solid
    (docs/design/register.md, "A camera above the person")."""
    if hm.any():
        rng_ = np.linalg.norm(qw[:, :2] - eye[:2], axis=1)
        mid = np.median(rng_[hm])
        hm &= np.abs(rng_ - mid) <= cfg.max_depth_spread_m
        if floor_z is not None:
            hm &= qw[:, 2] > floor_z + cfg.floor_margin_m
    return hm


def near_track(qw: np.ndarray, m0: np.ndarray, centre: np.ndarray, cfg: RegisterConfig) -> bool:
    """Whether the largest person-like cluster ``m0`` of ``qw`` lies within ``track_radius_m`` (plan)
    of the track's ``centre``: then it is also the largest near it."""
    return bool(m0.any() and np.linalg.norm(qw[m0, :2].mean(0) - centre[:2]) <= cfg.track_radius_m)


@dataclass
class Picks:
    """Step 4's picks: per frame the person's world points (N,3) float32 and (points, rows, columns,
    depths) of them; ``floor_z`` under the track (or None); ``repicked`` frames picked again."""

    points: list
    pixels: list
    floor_z: float | None
    repicked: int


def pick_track(cand: list, M: np.ndarray, eye: np.ndarray, f_px: float, t_cam: np.ndarray,
               cfg: RegisterConfig, sigma_a: float | None = None) -> Picks:
    """Step 4, the person of interest: person-like clusters near the track's median (people farther
    away, e.g. walking past in another corridor, are not it); a pick far from where its neighbours put
    the person (a wall fragment while the person is lost in far stereo noise, :func:`track_jumps`) is
    picked again near that prediction, or dropped. ``t_cam`` (T,) the candidates' stamps (ns).
    ``sigma_a`` (1/m): the camera's depth noise σ = a·z² (:func:`~.camera.noise_coefficient`); with it
    neighbouring pixels link along the view within their noise (:func:`pick_human`'s ``pixels``)."""
    def px(q):
        return None if sigma_a is None else (q[1], q[2], q[3], sigma_a * np.asarray(q[3], np.float64) ** 2)

    first = [pick_human(q[0], cfg, footprint=q[3] / f_px, pixels=px(q), eye=eye) for q in cand]
    cents = np.array([q[0][m].mean(0) for q, m in zip(cand, first) if m.any()])
    centre = np.median(cents, axis=0) if len(cents) else None
    floor_z = floor_below(M, centre)
    picks = [body_only(qw, m0 if centre is None or near_track(qw, m0, centre, cfg)
                       else pick_human(qw, cfg, centre, footprint=q[3] / f_px, pixels=px(q), eye=eye), eye, floor_z, cfg)
             for q, m0 in zip(cand, first) for qw in (q[0],)]
    cen0 = np.array([c[0][m].mean(0) if m.any() else np.full(3, np.nan) for c, m in zip(cand, picks)])
    jumped = track_jumps(cen0, t_cam, cfg.track_jump_m, cfg.walk_speed_mps)
    pred = track_prediction(np.where(jumped[:, None], np.nan, cen0), t_cam)
    jump_cfg = replace(cfg, track_radius_m=2 * cfg.track_jump_m)
    points, pixels = [], []
    for k, ((qw, vv, uu, dv), hm) in enumerate(zip(cand, picks)):
        if jumped[k]:
            hm = (body_only(qw, pick_human(qw, jump_cfg, pred[k], footprint=dv / f_px, pixels=px((qw, vv, uu, dv)),
                                            eye=eye),
                            eye, floor_z, cfg)
                  if np.isfinite(pred[k]).all() else np.zeros_like(hm))
        points.append(qw[hm].astype(np.float32))
        pixels.append((qw[hm], vv[hm], uu[hm], dv[hm]))
    return Picks(points, pixels, floor_z, int(jumped.sum()))


def body_columns_of(picks: Picks, eye: np.ndarray, f_px: float, cts: np.ndarray, cfg: RegisterConfig) -> list:
    """Step 5, the solid behind each frame's visible front (:func:`body_columns`): deeper behind a
    person walking along the view (the far leg) by ``walk_back_frac`` at ``walk_back_speed_mps``, and
    behind one walking across it (the far side, :func:`side_back`: ``breadth_m`` / ``thickness_m``)."""
    cen = np.array([p.mean(0) if len(p) else np.full(3, np.nan) for p in picks.points], float)
    walk = cfg.walk_back_frac * np.minimum(1.0, radial_speed(cen, cts, eye, cfg.max_speed_mps) / cfg.walk_back_speed_mps)
    side = side_back(cen, cts, eye, cfg.breadth_m / cfg.thickness_m, cfg.heading_speed_mps, cfg.max_speed_mps)
    return [body_columns(qh, vh, uh, dh, eye, f_px,
                         ColumnShape(cfg.min_thickness_m, cfg.thickness_m, cfg.surface_gap_px, cfg.floor_reach_m,
                                     float(walk[k]), float(side[k])), picks.floor_z)
            for k, (qh, vh, uh, dh) in enumerate(picks.pixels)]


def human_shift(points: list, cts: np.ndarray, ts: np.ndarray, cfg: RegisterConfig) -> np.ndarray:
    """(T,3) velocity compensation of each frame's person from the camera stamp ``cts`` to the frame
    stamp ``ts`` (ns) (:func:`velocity_shift`)."""
    cen = np.array([p.mean(0) if len(p) else np.full(3, np.nan) for p in points], float)
    return velocity_shift(cen, cts, ts, cfg.max_speed_mps)


def human_surfaces(points: list, columns: list, shift: np.ndarray, eye: np.ndarray, voxel: float) -> list:
    """:func:`closed_surface` per frame: (vertices (V,3) float32, faces (F,3) int32) of each frame's
    human points (N,3) moved by its velocity ``shift`` (3,) m, seen from ``eye`` (3,), with its
    :func:`body_columns` (span (N,2), pixel_m (N,), down_to (N,)); empty for a frame without points."""
    out = []
    for p, (span, px, down), d in zip(points, columns, shift):
        if len(p) == 0:
            out.append((np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)))
            continue
        down = down + d[2] if down is not None else None
        v, f = closed_surface(np.asarray(p, np.float64) + d, eye + d, span, voxel, pixel_m=px, down_to=down)
        out.append((v.astype(np.float32), f.astype(np.int32)))
    return out


def all_surfaces(points: list, columns: list, shift: np.ndarray, eye: np.ndarray, cfg: RegisterConfig,
                 processes: int, label: str) -> list:
    """Step 5: :func:`human_surfaces` of every frame, every other one in a second process when
    ``processes`` > 1."""
    odd = fork_call(human_surfaces, points[1::2], columns[1::2], shift[1::2], eye, cfg.surface_voxel,
                    label=f"{label}: human surfaces", enabled=processes > 1)
    even = human_surfaces(points[0::2], columns[0::2], shift[0::2], eye, cfg.surface_voxel)
    surfaces: list = [None] * len(points)
    surfaces[0::2], surfaces[1::2] = even, odd()
    return surfaces


def write_outputs(sw, surfaces: list, points: list, T: np.ndarray) -> None:
    """The human arrays (ragged per frame, world frame) and ``calib/T_world_camera`` into scene writer
    ``sw``."""
    data = {HUMAN_VERTICES: [s[0] for s in surfaces], HUMAN_FACES: [s[1] for s in surfaces], HUMAN_POINTS: points}
    for name, per_frame in data.items():
        r = sw.ragged_array(name)
        for s in range(r.n_shards):
            sl = r.frames(s)
            r.write_shard(s, per_frame[sl])
    sw.write_array(CALIB_T_WORLD_CAMERA, T,
                   attrs={"frame": "camera points frame (optical for depth images)", "source": "holodata register"})


def frame_cuts(picks: Picks, static_depth: np.ndarray, cfg: RegisterConfig, sigma_a: float | None = None) -> np.ndarray:
    """(T,) share of each frame's silhouette rows cut by a nearer static surface or the image's side
    (:func:`silhouette_cut`, ``cut_reach_px``): nearer than a silhouette end's depth by more than the
    foreground test's margin there, max(``fg_min_m``, ``fg_sigma`` σ), σ = ``sigma_a`` z² the
    camera's depth noise (:func:`~.camera.noise_coefficient`; ``fg_min_m`` alone without it): a far
    person on a noisy camera is not cut by noise in front of them."""
    def margin(d):
        return cfg.fg_min_m if sigma_a is None else np.maximum(cfg.fg_min_m, cfg.fg_sigma * sigma_a * np.asarray(d) ** 2)

    return np.array([silhouette_cut(vv, uu, dv, static_depth, cfg.cut_reach_px, margin(dv))
                     for (_, vv, uu, dv) in picks.pixels], float)


def track_smoothing(points: list, columns: list, shift: np.ndarray, eye: np.ndarray, ts: np.ndarray,
                    cfg: RegisterConfig, cuts: np.ndarray | None = None) -> np.ndarray:
    """(T,3) the shifts that move each frame's solid (its :func:`column_centroid` moved by its
    velocity ``shift`` (T,3)) onto the smoothed track (:func:`track_smooth`, its window from the
    track's noise and speed, frame stamps ``ts`` (T,) ns, weights the frame's returns); zero where a
    frame has no person or ``track_smooth`` is off. A frame whose silhouette is cut on ``cut_share``
    of its rows or more (``cuts`` (T,), :func:`frame_cuts`: the person partly hidden) takes no part in
    the fit and is placed on the line through the whole frames around it (:func:`cut_prediction`)
    where there are enough, its visible part's centre being no estimate of the person's."""
    if not cfg.track_smooth:
        return np.zeros((len(points), 3))
    cen = np.array([column_centroid(p, eye, span, px, down) if len(p) else np.full(3, np.nan)
                    for p, (span, px, down) in zip(points, columns)], float) + shift
    n = np.array([len(p) for p in points], float)
    cut = np.zeros(len(points), bool) if cuts is None else np.asarray(cuts) >= cfg.cut_share
    target = track_smooth(cen, np.where(cut, 0.0, n), ts)
    pred = cut_prediction(cen, ts, cut, cfg.cut_window_s)
    target = np.where(np.isfinite(pred), pred, target)
    out = target - cen
    return np.where(np.isfinite(out), out, 0.0)
