"""``holodata synth``: :func:`synthesize` one corner recording (:class:`SynthSpec`: the data pass, and
the mapping pass when asked) into an output folder, written under a temporary folder and moved into
place at the end; :func:`estimate_bytes`, the data pass's expected size (checked against the free
disk space first)."""
from __future__ import annotations

import shutil
from pathlib import Path

from ..conventions import Grid, RangeBins
from ..errors import InputError
from ..ownership import OutputDir
from . import truth as truthio
from .result import SynthResult
from .spec import SceneSpec, SynthSpec

PARTIAL_NAME = "synth"  # OUT/.synth.<uuid>.partial: where synthesize writes until everything is in place


def estimate_bytes(spec: SceneSpec) -> int:
    """Expected size (bytes) of the data-pass recording of ``spec``: one heatmap per radar rotation
    (H·W·bins values, 2 bytes for float16 else 4); over the recording's span (0.3 s + 0.5 s per
    rotation) LiDAR scans at 10 Hz (beams·columns points of 48 bytes), camera frames at 5 Hz (a float32
    depth image, an xyz float32 cloud, and with ``stereo_images`` two mono8 images) and odometry + TF at
    30 Hz (~0.8 kB). The mapping pass (LiDAR scans at 2 Hz while it drives the legs) comes on top.
    With ``radar_output="iq"`` a rotation is its chirps (plus the n_syn/2 on either side) × 8
    antennas × 256 samples of complex64 instead of the heatmap. (How close it comes:
    ``docs/design/synth.md``.)"""
    from .camera import CameraConfig
    from .lidar import OUSTER_DTYPE, LidarConfig
    from .scenario import ODOM_HZ, RADAR_START_S

    g, rb = spec.grid or Grid(), spec.range_bins or RangeBins()
    radar = g.H * g.W * rb.n * (2 if spec.radar_encoding == "float16" else 4)
    if spec.radar_output == "iq":
        from .radar import RadarConfig

        rc = RadarConfig(grid=g, range_bins=rb,
                         **({"chirps_per_rotation": spec.radar_chirps} if spec.radar_chirps else {}))
        chirp, n_syn = rc.imaging()
        radar = (rc.chirps_per_rotation + 2 * (n_syn // 2)) * chirp.n_virtual * chirp.n_samples * 8
    span_s = RADAR_START_S + 0.5 * spec.frames
    lidar = spec.lidar_shape[0] * spec.lidar_shape[1] * OUSTER_DTYPE.itemsize * LidarConfig.rate_hz
    px = spec.camera_shape[0] * spec.camera_shape[1]
    camera = px * (4 + 12 + (2 if spec.stereo_images else 0)) * CameraConfig.rate_hz
    return int(spec.frames * radar + span_s * (lidar + camera + 800 * ODOM_HZ))


def synthesize(out_dir, spec: SynthSpec = SynthSpec(), *, force: bool = False, quiet: bool = False) -> SynthResult:
    """Synthesise the corner recording ``spec`` into ``out_dir`` (created; must not hold a previous
    recording unless ``force``: replace it). Same spec → byte-identical files.

    OUT may hold the user's own files: synth replaces only what a synth run wrote there (its manifest,
    :mod:`holodata.ownership`), the recording only with ``force``; everything is written under a temp
    folder and moved into OUT at the end, the recording last: an interrupted run leaves no recording
    that looks complete, and a rerun starts over (same spec, same files)."""
    spec.check()
    out_dir = Path(out_dir)
    od = _claim_output(out_dir, spec, force)
    tmp = od.temp(PARTIAL_NAME, folder=True)
    res = _write_passes(spec, tmp, quiet)
    return _install(od, res, tmp, out_dir, spec.format, force)


def _claim_output(out_dir: Path, spec: SynthSpec, force: bool) -> OutputDir:
    """``out_dir`` as an :class:`OutputDir` once the names synth writes are free there (an earlier
    run's mapping pass of another data pass removed) and its disk has room for the recording."""
    from .recording import recording_path

    rec = recording_path(out_dir, spec.format)
    od = OutputDir(out_dir, "holodata synth")
    if (rec.exists() or rec.is_symlink()) and not force:
        raise InputError(f"{out_dir}: already holds a recording ({rec.name}); choose an empty --out, or --force "
                         f"to replace it")
    mp_name = recording_path(out_dir, spec.format, "mapping").name
    names = ["truth", rec.name] + ([mp_name] if spec.mapping_pass else [])
    for name in names:
        od.check_free(name, force=force and name == rec.name)
    if not spec.mapping_pass and od.owns(mp_name):   # an earlier run's mapping pass of another data pass
        od.remove(mp_name)
    _check_disk(out_dir, spec)
    return od


def _check_disk(out_dir: Path, spec: SynthSpec) -> None:
    """Refuse a recording (:func:`estimate_bytes`, 10 % margin) larger than the free space where ``out_dir`` goes."""
    need = estimate_bytes(spec)
    probe = next((q for q in (out_dir, *out_dir.parents) if q.exists()), Path("."))
    free = shutil.disk_usage(probe).free
    if free < need * 1.1:
        raise InputError(f"{out_dir}: the recording needs ~{need / 1e9:.2f} GB and {probe} has {free / 1e9:.2f} GB free "
                         f"(fewer --frames or smaller --grid/--lidar/--camera)")


def _write_passes(spec: SynthSpec, tmp: Path, quiet: bool) -> SynthResult:
    """The data pass (and with ``spec.mapping_pass`` the mapping pass, recorded in ``truth/scene.json``)
    written into the partial folder ``tmp``."""
    import json

    from .scenario import MAPPING_SCAN_HZ, build_mapping_pass, build_scenario, write_mapping_recording, write_recording

    sc = build_scenario(spec)
    res = write_recording(sc, tmp, spec.format, quiet=quiet)
    if spec.mapping_pass:
        mp = build_mapping_pass(sc, scan_hz=spec.mapping_scan_hz or MAPPING_SCAN_HZ)
        entry = write_mapping_recording(sc, mp, tmp, spec.format, quiet=quiet)
        scene = json.loads(res.scene_json.read_text())
        scene["mapping_pass"] = entry
        truthio.write_json(res.scene_json, scene)
        res.mapping_recording = tmp / entry["recording"]
        res.trajectory_lidar_mapping = res.truth_dir / "mapping_trajectory_lidar.tum"
    return res


def _install(od: OutputDir, res: SynthResult, tmp: Path, out_dir: Path, fmt: str, force: bool) -> SynthResult:
    """Move everything from ``tmp`` into ``out_dir``, the recording last, and point ``res``'s paths there."""
    from .recording import recording_path

    rec_name = recording_path(out_dir, fmt).name
    rec_tmp = recording_path(tmp, fmt)
    for child in sorted(tmp.iterdir(), key=lambda c: c == rec_tmp):  # the recording last
        od.install(child, child.name, force=force and child.name == rec_name)
    tmp.rmdir()
    for k, v in vars(res).items():  # paths into OUT, not the partial folder
        if isinstance(v, Path) and (v == tmp or tmp in v.parents):
            setattr(res, k, out_dir / v.relative_to(tmp))
    res.out_dir = out_dir
    return res
