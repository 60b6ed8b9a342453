"""``holodata synth``: :func:`synthesize` one corner recording (the data pass, and the mapping pass
when asked) into an output folder, written under a temporary folder and moved into place at the end;
:func:`estimate_bytes`, the data pass's expected size (checked against the free disk space first)."""
from __future__ import annotations

import shutil
from pathlib import Path

from ..conventions import Grid, RangeBins
from ..errors import InputError
from ..ownership import OutputDir
from . import truth as truthio
from .result import SynthResult
from .topics import RADAR_OUTPUTS

PARTIAL_NAME = "synth"  # OUT/.synth.<uuid>.partial: where synthesize writes until everything is in place


def estimate_bytes(frames: int, grid: Grid | None = None, range_bins: RangeBins | None = None,
                   lidar_shape: tuple[int, int] = (64, 1024), camera_shape: tuple[int, int] = (376, 672),
                   radar_encoding: str = "float16", stereo_images: bool = False, radar_output: str = "heatmap",
                   radar_chirps: int | None = None) -> int:
    """Expected size (bytes) of the data-pass recording: one heatmap per radar rotation (H·W·bins
    values, 2 bytes for float16 else 4); over the recording's span (0.3 s + 0.5 s per rotation)
    LiDAR scans at 10 Hz (beams·columns points of 48 bytes), camera frames at 5 Hz (a float32 depth
    image, an xyz float32 cloud, and with ``stereo_images`` two mono8 images) and odometry + TF at
    30 Hz (~0.8 kB). The mapping pass (LiDAR scans at 2 Hz while it drives the legs) comes on top.
    With ``radar_output="iq"`` a rotation is its chirps (plus the n_syn/2 on either side) × 8
    antennas × 256 samples of complex64 instead of the heatmap. (How close it comes:
    ``docs/design/synth.md``.)"""
    from .camera import CameraConfig
    from .lidar import OUSTER_DTYPE, LidarConfig
    from .scenario import ODOM_HZ, RADAR_START_S

    g, rb = grid or Grid(), range_bins or RangeBins()
    radar = g.H * g.W * rb.n * (2 if radar_encoding == "float16" else 4)
    if radar_output == "iq":
        from .radar import RadarConfig

        rc = RadarConfig(grid=g, range_bins=rb, **({"chirps_per_rotation": radar_chirps} if radar_chirps else {}))
        chirp, n_syn = rc.imaging()
        radar = (rc.chirps_per_rotation + 2 * (n_syn // 2)) * chirp.n_virtual * chirp.n_samples * 8
    span_s = RADAR_START_S + 0.5 * frames
    lidar = lidar_shape[0] * lidar_shape[1] * OUSTER_DTYPE.itemsize * LidarConfig.rate_hz
    px = camera_shape[0] * camera_shape[1]
    camera = px * (4 + 12 + (2 if stereo_images else 0)) * CameraConfig.rate_hz
    return int(frames * radar + span_s * (lidar + camera + 800 * ODOM_HZ))


def synthesize(out_dir, corner: str = "L", width: float | None = None, frames: int = 20, format: str = "mcap",
               seed: int = 0, human: bool = True, grid: Grid | None = None, range_bins: RangeBins | None = None,
               lidar_shape: tuple[int, int] = (64, 1024), camera_shape: tuple[int, int] = (376, 672),
               radar_encoding: str = "float16", stereo_images: bool = False, quiet: bool = False,
               visible_walkers: int = 0, lidar_vertical_fov_deg: float = 33.2, mapping_pass: bool = False,
               mapping_scan_hz: float | None = None, robot_stop_x: float | None = None,
               force: bool = False, radar_output: str = "heatmap", radar_chirps: int | None = None) -> SynthResult:
    """Synthesise one corner recording into ``out_dir`` (created; must not hold a previous recording).

    ``corner`` T|L|cross|oblique; ``width`` approach-corridor width m (None: drawn from ``seed``);
    ``frames`` radar rotations (2 Hz); ``format`` mcap|rosbag2|rosbag1; ``grid``/``range_bins`` the
    radar heatmap axes (docs/format.md §2); ``lidar_shape`` (beams, columns); ``camera_shape`` (rows, cols);
    ``stereo_images`` adds the rectified left/right mono8 pair (``STEREO_TOPICS``) for OpenCV stereo.
    ``visible_walkers`` N adds N people walking in the approach corridor, seen by every sensor, with
    per-scan LiDAR truth instance masks in ``truth/lidar_instances.npz`` (0: none, outputs unchanged).
    ``lidar_vertical_fov_deg``: 33.2 OS1-like (default), 90 OS0-like (sees floor and ceiling nearby).
    ``mapping_pass``: also record the mapping pass (module docstring): the robot drives the empty
    corner through every leg before the data pass, LiDAR + odometry only, LiDAR throttled to
    ``mapping_scan_hz`` (default ``scenario.MAPPING_SCAN_HZ``); the data pass is unchanged.
    ``robot_stop_x``: where the data pass's robot stops (m along the approach corridor, the junction
    at 0; None: 0.6-1.2 m short of it, drawn from the seed), moved back if the person could not hide.
    ``radar_output``: "heatmap" (``/radar/heatmap``, the radar model with the beamformer's point-spread
    function) or "iq" (``/radar/raw``: every rotation's raw FMCW samples from the same paths, which
    ingest beamforms like a real rig's; :meth:`holodata.synth.radar.RadarModel.iq`);
    ``radar_chirps``: chirp positions per rotation (default 1024; at least ~500 keep a 90°
    synthetic aperture free of grating lobes at 77 GHz).
    Same arguments → byte-identical files. ``force``: replace a recording already in ``out_dir``.
    """
    from .recording import FORMATS, recording_path
    from .scenario import MAPPING_SCAN_HZ, build_mapping_pass, build_scenario, write_mapping_recording, write_recording

    if format not in FORMATS:
        raise InputError(f"unknown recording format {format!r} (choose from {', '.join(FORMATS)})")
    if frames < 1:
        raise InputError(f"frames must be >= 1, got {frames}")
    if visible_walkers < 0:
        raise InputError(f"visible_walkers must be >= 0, got {visible_walkers}")
    if radar_output not in RADAR_OUTPUTS:
        raise InputError(f"unknown radar output {radar_output!r} (choose from {', '.join(RADAR_OUTPUTS)})")
    if radar_chirps is not None and radar_chirps < 16:
        raise InputError(f"radar_chirps must be >= 16, got {radar_chirps}")
    out_dir = Path(out_dir)
    rec = recording_path(out_dir, format)
    if robot_stop_x is not None and not -3.0 <= robot_stop_x <= 0.0:
        raise InputError(f"robot_stop_x must be within -3..0 m (the junction starts at 0), got {robot_stop_x}")
    if mapping_scan_hz is not None and not 0.1 <= mapping_scan_hz <= 10.0:
        raise InputError(f"mapping_scan_hz must be within 0.1-10 Hz, got {mapping_scan_hz}")
    # OUT may hold the user's own files: synth replaces only what a synth run wrote there (its
    # manifest, holodata.ownership), the recording only with force; everything is written under a
    # temp folder and moved into OUT at the end, the recording last: an interrupted run leaves no
    # recording that looks complete, and a rerun starts over (same arguments, same files)
    od = OutputDir(out_dir, "holodata synth")
    if (rec.exists() or rec.is_symlink()) and not force:
        raise InputError(f"{out_dir}: already holds a recording ({rec.name}); choose an empty --out, or --force "
                         f"to replace it")
    mp_name = recording_path(out_dir, format, "mapping").name
    names = ["truth", rec.name] + ([mp_name] if mapping_pass else [])
    for name in names:
        od.check_free(name, force=force and name == rec.name)
    if not mapping_pass and od.owns(mp_name):   # an earlier run's mapping pass of another data pass
        od.remove(mp_name)
    need = estimate_bytes(frames, grid, range_bins, lidar_shape, camera_shape, radar_encoding, stereo_images,
                          radar_output, radar_chirps)
    probe = next((q for q in (out_dir, *out_dir.parents) if q.exists()), Path("."))
    free = shutil.disk_usage(probe).free
    if free < need * 1.1:
        raise InputError(f"{out_dir}: the recording needs ~{need / 1e9:.2f} GB and {probe} has {free / 1e9:.2f} GB free "
                         f"(fewer --frames or smaller --grid/--lidar/--camera)")
    tmp = od.temp(PARTIAL_NAME, folder=True)
    sc = build_scenario(corner=corner, width=width, frames=frames, seed=seed, human=human,
                        grid=grid or Grid(), range_bins=range_bins or RangeBins(), lidar_shape=lidar_shape,
                        camera_shape=camera_shape, radar_encoding=radar_encoding, stereo_images=stereo_images,
                        visible_walkers=visible_walkers, lidar_vertical_fov_deg=lidar_vertical_fov_deg,
                        robot_stop_x=robot_stop_x, radar_chirps=radar_chirps)
    if radar_output != "heatmap":
        import dataclasses

        sc = dataclasses.replace(sc, radar_output=radar_output)
    res = write_recording(sc, tmp, format, quiet=quiet)
    if mapping_pass:
        import json

        mp = build_mapping_pass(sc, scan_hz=mapping_scan_hz or MAPPING_SCAN_HZ)
        entry = write_mapping_recording(sc, mp, tmp, format, quiet=quiet)
        scene = json.loads(res.scene_json.read_text())
        scene["mapping_pass"] = entry
        truthio.write_json(res.scene_json, scene)
        res.mapping_recording = tmp / entry["recording"]
        res.trajectory_lidar_mapping = res.truth_dir / "mapping_trajectory_lidar.tum"
    rec_tmp = recording_path(tmp, format)
    for child in sorted(tmp.iterdir(), key=lambda c: c == rec_tmp):  # the recording last
        od.install(child, child.name, force=force and child.name == rec.name)
    tmp.rmdir()
    for k, v in vars(res).items():  # paths into OUT, not the partial folder
        if isinstance(v, Path) and (v == tmp or tmp in v.parents):
            setattr(res, k, out_dir / v.relative_to(tmp))
    res.out_dir = out_dir
    return res
