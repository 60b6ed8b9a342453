"""``holodata view``: one scene in Rerun (desktop viewer, web viewer, or an ``.rrd`` file).

Steps (:meth:`SceneView.run`): open a Rerun recording stream (saved to a file, served by a gRPC data
server bound to 127.0.0.1 only, or sent to a spawned desktop viewer); log what never changes once (the class
table as an annotation context, the static mesh, the camera's extrinsic); then frame by frame, on
the ``time`` timeline (``time/timestamp_ns``), read only that frame's arrays and log

====================================  ========================================================
``radar/range_azimuth``               heatmap slice at the row nearest 0° elevation (R, W), the top 60 dB
``radar/elevation_azimuth``           heatmap maximum over range beyond the rig (H, W), the top 60 dB
``gt/range/b1..b3``                   GT range images per bounce (depth images, metres)
``gt/label/b1..b3``                   GT labels per bounce (segmentation images, class table)
``world/gt/mirrored``                 GT returns where the radar sees them: beam origin + range ×
                                      first direction (the beam-origin model the GT was traced with)
``world/gt/unmirrored``               GT hit points (``gt/point``), coloured by label
``world/radar``, ``world/lidar``      poses (``pose/T_world_*``) as transforms; ``world/lidar/points``
                                      the LiDAR scan in its sensor frame under that transform
``world/camera/points``               the depth camera's cloud under ``calib/T_world_camera``
``world/human``                       the registered human surface (``human/vertices``, ``human/faces``)
``world/pred/points``                 with a run (``checkpoint`` or an evaluation ``report``): the
                                      run's predicted points (stage one + its stage two, as
                                      ``holodata evaluate`` scores them), coloured by predicted label
``world/person/true``, ``…/predicted`` the person's centre in the GT hit points and in the run's
                                      points (clusters of human points, as evaluate matches them)
====================================  ========================================================

Arrays a scene lacks are left out and listed in the returned ``notes``. Memory stays flat in the
scene's length (one frame at a time; ragged arrays read shard by shard by the dataset reader).
"""
from __future__ import annotations

from dataclasses import KW_ONLY, dataclass
from typing import Any

import numpy as np

from .dataset.heatmap import read_heatmap
from .dataset.layout import (
    CALIB_T_WORLD_CAMERA,
    CAMERA_POINTS,
    GT_LABEL,
    GT_POINT,
    GT_RANGE,
    HUMAN_FACES,
    HUMAN_VERTICES,
    LIDAR_POINTS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_LIDAR,
    POSE_T_WORLD_RADAR,
    RADAR_CYCLE_NS,
    RADAR_HEATMAP,
    TIME_TIMESTAMP_NS,
)
from .errors import DatasetError, InputError


def _db_image(a: np.ndarray, span_db: float = 60.0) -> np.ndarray:
    """Linear amplitudes → uint8 image of 20 log10(a) over the top ``span_db`` dB of the frame."""
    db = 20 * np.log10(np.maximum(np.asarray(a, np.float32), 1e-9))
    top = float(db.max())
    return np.round(255 * np.clip((db - (top - span_db)) / span_db, 0, 1)).astype(np.uint8)


def parse_frames(spec: str | None, n: int) -> range:
    """``"A:B"`` (either side optional) → frames A..B-1 of ``n``; one-line InputError when out of range."""
    if not spec:
        return range(n)
    try:
        a, _, b = spec.partition(":")
        lo = int(a) if a else 0
        hi = int(b) if b else (lo + 1 if not _ else n)
    except ValueError as err:
        raise InputError(f"--frames must look like A:B (e.g. 0:40), got {spec!r}") from err
    if not 0 <= lo < hi <= n:
        raise InputError(f"--frames {spec}: {'empty' if hi <= lo else 'out of range'} (the scene has frames 0..{n - 1})")
    return range(lo, hi)


DATA_PORT = 9876        # the gRPC data server's default port (Rerun's)
PAGE_PORT = 9090        # the SDK's web viewer page, served only with a non-loopback --bind
LOOPBACK = "127.0.0.1"


def is_loopback(host: str) -> bool:
    import ipaddress

    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def _stream(save, web: bool, port: int | None, scene_id: str, bind: str = LOOPBACK):
    """The recording stream: saved to ``save``, spawned in a desktop viewer, or (``web``) served by a
    gRPC data server bound to ``bind`` only (loopback by default: nobody else reaches the scene).

    The SDK's page server (``rr.serve_web_viewer``, rerun-sdk 0.41) binds every interface and takes
    no address, so it runs only when ``bind`` is not loopback, i.e. when the user asked for the network."""
    import rerun as rr

    rec = rr.RecordingStream("holodata", recording_id=f"holodata-{scene_id}")
    if save:
        rec.save(str(save))
    elif web:
        sink = rr.GrpcServerSink(bind_ip=bind, port=port or DATA_PORT)
        rec.set_sinks(sink)
        if not is_loopback(bind):
            rr.serve_web_viewer(web_port=PAGE_PORT, open_browser=False, connect_to=sink.uri)
    else:
        rec.spawn()
    return rec


def web_instructions(port: int | None, bind: str = LOOPBACK) -> list[str]:
    """How to look at a scene served by :func:`_stream` (``web``): lines for the terminal."""
    import urllib.parse

    import rerun as rr

    host = LOOPBACK if is_loopback(bind) else bind
    uri = f"rerun+http://{host}:{port or DATA_PORT}/proxy"
    if not is_loopback(bind):
        return [f"data server on {bind}:{port or DATA_PORT} (reachable from the network, no authentication)",
                f"web viewer page: http://{host}:{PAGE_PORT} (every interface)"]
    hosted = f"https://app.rerun.io/version/{rr.__version__}/?url={urllib.parse.quote(uri, safe='')}"
    return [f"data server on {uri} (this machine only)",
            f"open it with the desktop viewer: rerun {uri}",
            f"or in a browser on this machine: {hosted} (the page comes from rerun.io; the scene stays here)",
            f"from another machine: ssh -L {port or DATA_PORT}:127.0.0.1:{port or DATA_PORT} THIS_HOST first, "
            f"or holodata view --save SCENE.rrd and open that file with rerun"]


def run_of_report(report_dir) -> tuple[str | None, bool, str]:
    """(checkpoint, oracle, estimator) an evaluation report (``DIR/metrics.json``) was made with."""
    import json
    from pathlib import Path

    p = Path(report_dir) / "metrics.json"
    if not p.exists():
        raise InputError(f"{p}: no such file (--report takes the --out directory of holodata evaluate)")
    try:
        doc = json.loads(p.read_text())
        ck, est = doc["checkpoint"], doc["settings"].get("estimator", "mean")
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{p}: not a holodata metrics document ({err.__class__.__name__})") from err
    return (None, True, est) if ck == "oracle" else (ck, False, est)


class _Predictions:
    """A run's predicted points per frame, in the world frame (see :mod:`holodata.evaluate.predict`)."""

    def __init__(self, checkpoint, oracle: bool, estimator: str, ds, sc, device: str = "cpu"):
        from .conventions import reduced_grid
        from .evaluate.predict import Predictor
        from .scene_beams import SceneBeams

        self.run = Predictor.load(checkpoint, device=device, estimator=estimator, oracle=oracle)
        self.f = self.run.downsample
        self.grid = reduced_grid(ds.grid, self.f)
        self.beams, self.sc = SceneBeams(sc, ds.grid), sc

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame k → (points (N,3) float32 world frame, class ids (N,) uint8)."""
        from .evaluate.predict import label_of, oracle_points

        geo, f = self.beams.frame(k, self.f), self.f
        if self.run.model is None:
            rng = np.asarray(self.sc[GT_RANGE][k], np.float32)[:, ::f, ::f]
            p = oracle_points(rng, np.asarray(self.sc[GT_LABEL][k], np.uint8)[:, ::f, ::f], geo, self.grid)
        else:
            _rng, hum, cloud = self.run.ranges([read_heatmap(self.sc, k)])
            p = self.run.points(cloud[0], hum[0], geo, self.grid)
        P = np.asarray(p["point"], np.float64).reshape(-1, 3)
        ok = np.isfinite(P).all(-1)
        ids = label_of(np.asarray(p["los"], bool).reshape(-1), np.asarray(p["human"], bool).reshape(-1))
        return geo.to_world(P[ok]).astype(np.float32), ids[ok]


def _log_person(log, entity: str, points: np.ndarray, class_ids: np.ndarray, text: str) -> None:
    """The person's centre(s) as evaluate finds them (:func:`holodata.metrics.human_centroids`: clusters
    of human-labelled points, world frame) as a 0.25 m ball with a label; an empty entity when none."""
    import rerun as rr

    from .conventions import is_human
    from .metrics import human_centroids

    c = human_centroids(np.asarray(points, np.float64)[is_human(np.asarray(class_ids))]).astype(np.float32)
    log(entity, rr.Points3D(c, radii=0.25, labels=[text] * len(c)))


class _Log:
    """A recording stream (``rec``) that remembers the entity paths logged to it (``entities``)."""

    def __init__(self, rec):
        self.rec = rec
        self.entities: set[str] = set()

    def __call__(self, path, obj, static=False):
        self.rec.log(path, obj, static=static)
        self.entities.add(path)


def _missing_notes(has: set) -> list[str]:
    """One note per array (of those drawn) a scene whose arrays are ``has`` lacks."""
    notes = []
    for name, what in ((RADAR_HEATMAP, "radar panels"), (GT_RANGE, "GT panels and points"),
                       (POSE_T_WORLD_RADAR, "radar poses (GT points drawn in the radar frame)"),
                       (LIDAR_POINTS, "LiDAR scans"), (MESH_VERTICES, "the static mesh"),
                       (HUMAN_VERTICES, "the human surface")):
        if name not in has:
            notes.append(f"no {name}: {what} left out")
    return notes


def _log_statics(log: _Log, sc, has: set) -> None:
    """What never changes, logged once: the class table (annotation context), the world's axes
    (right-handed, z up), the static mesh and the camera's extrinsic."""
    import rerun as rr

    from .conventions import LABEL_NAMES

    classes = [rr.AnnotationInfo(id=k, label=v) for k, v in sorted(LABEL_NAMES.items())]
    log("/", rr.AnnotationContext(classes), static=True)
    log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if MESH_VERTICES in has and MESH_FACES in has:
        log("world/mesh", rr.Mesh3D(vertex_positions=np.asarray(sc[MESH_VERTICES][...], np.float32),
                                    triangle_indices=np.asarray(sc[MESH_FACES][...], np.int32)), static=True)
    if CALIB_T_WORLD_CAMERA in has:
        T = np.asarray(sc[CALIB_T_WORLD_CAMERA][...], np.float64)
        log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)


@dataclass
class _Series:
    """A scene's per-frame series, read once: ``t`` (T,) int64 ns frame times (``time/timestamp_ns``,
    else 0.5 s apart); ``poses``/``lposes`` (T,4,4) radar/LiDAR poses in the world frame, or None;
    ``cycles`` (T,2) int64 ns each frame's rotation, or None; ``origin``: the beam-origin model the
    GT was traced with; ``traj``: the radar trajectory for per-column poses (None without poses or
    with times that do not increase); ``el0``: the grid row nearest 0° elevation; ``beyond_rig``:
    the first range bin beyond the rotation circle's diameter."""

    t: np.ndarray
    poses: np.ndarray | None
    lposes: np.ndarray | None
    cycles: np.ndarray | None
    origin: Any
    traj: Any
    el0: int
    beyond_rig: int

    @classmethod
    def read(cls, sc, has: set, g, rb) -> _Series:
        """The series of scene ``sc`` (arrays ``has``) on grid ``g`` and range bins ``rb``."""
        from .beams import OriginModel, scene_origin_model
        from .conventions import RADAR_ROTATION_RADIUS_M
        from .trajectory import Trajectory

        t = np.asarray(sc[TIME_TIMESTAMP_NS][...], np.int64) if TIME_TIMESTAMP_NS in has else \
            (np.arange(sc.n_frames) * 500_000_000).astype(np.int64)
        poses = np.asarray(sc[POSE_T_WORLD_RADAR][...], np.float64) if POSE_T_WORLD_RADAR in has else None
        lposes = np.asarray(sc[POSE_T_WORLD_LIDAR][...], np.float64) if POSE_T_WORLD_LIDAR in has else None
        cycles = np.asarray(sc[RADAR_CYCLE_NS][...], np.int64) if RADAR_CYCLE_NS in has else None
        gt_attrs = (sc.attrs.get("gt") or {}).get("origin_model")
        origin = OriginModel.from_attrs(gt_attrs) if gt_attrs else scene_origin_model(sc.attrs)[0]
        traj = Trajectory(t, poses) if poses is not None and len(t) > 1 and np.all(np.diff(t) > 0) else None
        el0 = int(np.argmin(np.abs(g.elevations())))
        # bins inside the rotation circle's diameter hold the rig's own TX->RX leakage: left out of the max
        beyond_rig = int(np.searchsorted(rb.centres(), 2 * RADAR_ROTATION_RADIUS_M))
        return cls(t, poses, lposes, cycles, origin, traj, el0, beyond_rig)


class _FrameDrawer:
    """Logs the frames of scene ``sc`` (arrays ``has``, grid ``g``, series ``s``) to ``log``, one
    frame's arrays read at a time, on the ``time`` timeline."""

    def __init__(self, log: _Log, sc, has: set, g, s: _Series):
        self.log, self.sc, self.has, self.g, self.s = log, sc, has, g, s

    def frame(self, f: int, pred: _Predictions | None) -> None:
        """Frame ``f``: the radar panels, the sensors, the GT, and ``pred``'s points when given."""
        self.log.rec.set_time("time", timestamp=np.datetime64(int(self.s.t[f]), "ns"))
        if RADAR_HEATMAP in self.has:
            self._radar(f)
        P = self._sensors(f)
        if GT_RANGE in self.has:
            self._gt(f, P)
        if pred is not None:
            import rerun as rr

            pts, ids = pred.frame(f)
            self.log("world/pred/points", rr.Points3D(pts, class_ids=ids, radii=0.02))
            _log_person(self.log, "world/person/predicted", pts, ids, "predicted person")

    def _radar(self, f: int) -> None:
        """The heatmap's range-azimuth slice at 0° elevation and its maximum over range beyond the rig."""
        import rerun as rr

        hm = read_heatmap(self.sc, f)
        self.log("radar/range_azimuth", rr.Image(_db_image(hm[:, self.s.el0, :])))
        self.log("radar/elevation_azimuth", rr.Image(_db_image(hm[self.s.beyond_rig:].max(axis=0))))

    def _sensors(self, f: int) -> np.ndarray:
        """The radar and LiDAR poses, the LiDAR scan, the camera cloud and the human surface; returns
        the radar pose (4,4) (identity without poses)."""
        import rerun as rr

        sc, has, log, s = self.sc, self.has, self.log, self.s
        P = s.poses[f] if s.poses is not None else np.eye(4)
        if s.poses is not None:
            log("world/radar", rr.Transform3D(translation=P[:3, 3], mat3x3=P[:3, :3]))
        if s.lposes is not None:
            L = s.lposes[f]
            log("world/lidar", rr.Transform3D(translation=L[:3, 3], mat3x3=L[:3, :3]))
            if LIDAR_POINTS in has:
                log("world/lidar/points", rr.Points3D(np.asarray(sc[LIDAR_POINTS][f], np.float32), radii=0.01))
        if CAMERA_POINTS in has and CALIB_T_WORLD_CAMERA in has:
            log("world/camera/points", rr.Points3D(np.asarray(sc[CAMERA_POINTS][f], np.float32), radii=0.01))
        if HUMAN_VERTICES in has and HUMAN_FACES in has:
            v, fc = np.asarray(sc[HUMAN_VERTICES][f], np.float32), np.asarray(sc[HUMAN_FACES][f], np.int32)
            if len(v) and len(fc):
                log("world/human", rr.Mesh3D(vertex_positions=v, triangle_indices=fc))
        return P

    def _gt(self, f: int, P: np.ndarray) -> None:
        """GT range and label images per bounce, the GT returns mirrored (beam origin + range × first
        direction, from radar pose ``P``) and un-mirrored (``gt/point``), and the true person."""
        import rerun as rr

        from .beams import beam_rays, column_poses

        sc, has, log, s, g = self.sc, self.has, self.log, self.s, self.g
        R = np.asarray(sc[GT_RANGE][f], np.float32)                  # (B, H, W)
        lab = np.asarray(sc[GT_LABEL][f], np.uint8) if GT_LABEL in has else None
        cp = column_poses(s.traj, f, g, s.origin, s.cycles[f] if s.cycles is not None else None) \
            if s.traj is not None else None
        o, d = beam_rays(g, P, s.origin, cp)
        for b in range(R.shape[0]):
            log(f"gt/range/b{b + 1}", rr.DepthImage(np.nan_to_num(R[b], nan=0.0), meter=1.0))
            if lab is not None:
                log(f"gt/label/b{b + 1}", rr.SegmentationImage(lab[b]))
        ok = np.isfinite(R).reshape(R.shape[0], -1)
        ids = lab.reshape(lab.shape[0], -1)[ok] if lab is not None else None
        mirrored = (o[None] + d[None] * np.nan_to_num(R.reshape(R.shape[0], -1, 1)))[ok]
        log("world/gt/mirrored", rr.Points3D(mirrored.astype(np.float32), class_ids=ids, radii=0.02))
        if GT_POINT in has:
            pts = np.asarray(sc[GT_POINT][f], np.float32).reshape(R.shape[0], -1, 3)[ok]
            log("world/gt/unmirrored", rr.Points3D(pts, class_ids=ids, radii=0.02))
            if ids is not None:
                _log_person(log, "world/person/true", pts, ids, "true person")


@dataclass
class SceneView:
    """``holodata view``: :meth:`run` logs scene ``scene_id`` (default: the first with a radar) of
    dataset ``url`` to Rerun and returns {scene, frames, entities, notes, grid, range_bins} (and,
    with ``web``, ``stream``: the recording stream whose gRPC server the web viewer reads from — it
    stops when the stream is dropped).

    ``frames``: "A:B" (:func:`parse_frames`; None: every frame). Where the recording goes: ``save``,
    an .rrd file (replacing only one holodata wrote, unless ``force``); ``web``, a gRPC data server
    on ``bind``:``port`` (:func:`_stream`); else a spawned desktop viewer. ``checkpoint`` (a run) or
    ``report`` (an evaluation's ``--out`` directory, whose run is used) adds the run's predicted
    points per frame, the model run on torch device ``device``."""

    url: str
    scene_id: str | None = None
    frames: str | None = None
    _: KW_ONLY
    save: Any = None
    web: bool = False
    port: int | None = None
    checkpoint: Any = None
    report: Any = None
    device: str = "cpu"
    bind: str = LOOPBACK
    force: bool = False

    def run(self) -> dict:
        """Open the scene, the run and the stream; log the statics, then frame by frame."""
        import rerun  # noqa: F401 - the SDK first: without it nothing is opened

        ds, scene_id = self._open()
        sc = ds.scene(scene_id)
        fr = parse_frames(self.frames, sc.n_frames)
        has = set(sc.arrays())
        notes = _missing_notes(has)
        pred = self._predictions(ds, sc, has, notes)
        saved, save = self._save_to()
        log = _Log(_stream(save, self.web, self.port, scene_id, self.bind))
        _log_statics(log, sc, has)
        g, rb = ds.grid, ds.range_bins
        drawer = _FrameDrawer(log, sc, has, g, _Series.read(sc, has, g, rb))
        for f in fr:
            drawer.frame(f, pred)
        log.rec.flush()
        if saved is not None:
            log.rec.disconnect()
            saved[0].install(save, saved[1], self.force)
        out = {"scene": scene_id, "frames": len(fr), "entities": sorted(log.entities), "notes": notes,
               "grid": f"{g.H}x{g.W}", "range_bins": rb.n}
        if self.web:
            out["stream"] = log.rec   # its gRPC server lives as long as the stream: the caller keeps it while serving
        return out

    def _open(self) -> tuple:
        """(the dataset, the scene id): ``scene_id``, or the first scene with a radar."""
        from .dataset import open_dataset

        ds = open_dataset(self.url)
        scene_id = self.scene_id
        if scene_id is None:
            scene_id = next((s for s in ds.scenes if RADAR_HEATMAP in ds.scene(s)), ds.scenes[0] if ds.scenes else None)
        if scene_id not in ds.scenes:
            raise DatasetError(f"{ds.url}: no scene {scene_id!r} (have {', '.join(ds.scenes) or 'none'})")
        return ds, scene_id

    def _predictions(self, ds, sc, has: set, notes: list) -> _Predictions | None:
        """The run's predicted points (None without ``checkpoint``/``report``, or when the scene
        lacks what the run needs: said in ``notes``)."""
        if self.checkpoint is None and self.report is None:
            return None
        ck, oracle, est = run_of_report(self.report) if self.report is not None else (self.checkpoint, False, "mean")
        need = [n for n in ((GT_RANGE, GT_LABEL) if oracle else (RADAR_HEATMAP,)) if n not in has]
        if need:
            notes.append(f"no {need[0]}: the run's predicted points left out")
            return None
        return _Predictions(ck, oracle, est, ds, sc, self.device)

    def _save_to(self) -> tuple:
        """(what installs the saved file, or None; the path the stream writes): with ``save``, the
        .rrd is written under a temp name and moved in place when complete; it replaces only an .rrd
        holodata wrote (or, with ``force``, any file but a symlink)."""
        if not self.save:
            return None, self.save
        from pathlib import Path

        from .ownership import OutputDir

        od, name = OutputDir(Path(self.save).parent, "holodata view"), Path(self.save).name
        od.check_free(name, self.force)
        return (od, name), od.temp(name)
