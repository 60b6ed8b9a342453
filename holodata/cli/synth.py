"""``holodata synth``: write a synthetic corner recording plus its hidden truth."""
from __future__ import annotations

import click

from holodata.cli.options import dask_options, json_option, quiet_option


def _shape(value: str, flag: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in value.lower().split("x"))
    except ValueError as err:
        raise click.BadParameter(f"must look like 64x1024, got {value!r}", param_hint=flag) from err
    if a < 1 or b < 1:
        raise click.BadParameter(f"must be positive, got {value!r}", param_hint=flag)
    return a, b


@click.command()
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder (recording + truth/).")
@click.option("--corner", type=click.Choice(["T", "L", "cross", "oblique"]), default="L", show_default=True,
              help="Corner shape.")
@click.option("--width", type=float, default=None,
              help="Approach-corridor width in metres (default: drawn from the seed, 1.3-4.7).")
@click.option("--frames", type=int, default=None,
              help="Radar rotations (2 Hz; default 20, with --corners 4); at the default sizes ~43 MB each (20: ~0.87 GB), "
                   "printed before writing.")
@click.option("--format", "fmt", type=click.Choice(["mcap", "rosbag2", "rosbag1"]), default="mcap", show_default=True,
              help="mcap: ROS 2 bag with MCAP storage; rosbag2: sqlite3 storage; rosbag1: ROS 1 .bag.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed: identical files).")
@click.option("--grid", default="64x512", show_default=True, help="Radar beam grid HxW (elevation x azimuth).")
@click.option("--range-bins", "range_bins", type=click.IntRange(min=8), default=256, show_default=True,
              help="Radar range bins (3.75 cm each).")
@click.option("--lidar", default="64x1024", show_default=True, help="LiDAR beams x columns.")
@click.option("--lidar-fov", "lidar_fov", type=click.FloatRange(5.0, 180.0), default=33.2, show_default=True,
              help="LiDAR vertical field of view in degrees (33.2 OS1-like, 90 OS0-like).")
@click.option("--camera", default="376x672", show_default=True, help="Depth camera rows x columns.")
@click.option("--no-human", is_flag=True, help="Record the corner without a human.")
@click.option("--visible-walkers", type=click.IntRange(min=0), default=0, show_default=True,
              help="People walking in the robot's corridor, visible to the LiDAR (truth/lidar_instances.npz).")
@click.option("--stereo-images", is_flag=True, help="Also record the rectified left/right mono8 pair (for OpenCV stereo).")
@click.option("--mapping-pass/--no-mapping-pass", "mapping_pass", default=True, show_default=True,
              help="Also record the mapping pass: the robot drives the empty corner through its legs first, "
              "LiDAR + odometry only, as its own recording OUT/mapping (for holodata slam --map-scene).")
@click.option("--mapping-scan-hz", type=click.FloatRange(0.1, 10.0), default=2.0, show_default=True,
              help="LiDAR scans per second kept in the mapping pass (throttled from the 10 Hz sensor).")
@click.option("--robot-stop-x", type=click.FloatRange(-3.0, 0.0), default=None,
              help="Where the data pass's robot stops, metres along the approach corridor (junction at 0; default: "
              "0.6-1.2 m short of it, drawn from the seed).")
@click.option("--radar-output", "radar_output", type=click.Choice(["heatmap", "iq"]), default="heatmap", show_default=True,
              help="heatmap: beamformed RadarHeatmap messages (the beamformer's point-spread function, fast); iq: every "
                   "rotation's raw FMCW samples (RadarRawRotation on /radar/raw), which ingest beamforms like a real rig's; with "
                   "--corners the corpus stores them beamformed as ingest does.")
@click.option("--radar-chirps", "radar_chirps", type=click.IntRange(min=16), default=None,
              help="Chirp positions per rotation (default 1024, PanoRadar's; ~500 or more keep a 90° synthetic aperture free "
                   "of grating lobes).")
@click.option("--count", type=click.IntRange(min=1), default=1, show_default=True,
              help="Recordings to write: >1 writes OUT/scene_000, OUT/scene_001, ... with seeds SEED, SEED+1, ...")
@click.option("--corners", type=int, default=None,
              help="Write a training dataset instead: OUT is a Zarr dataset of N procedurally varied corners x --frames "
                   "rotations (heatmaps + ground truth from the true mesh; no LiDAR, camera or mapping pass), seeded by --seed, "
                   "resumable.")
@click.option("--test", "n_test", type=int, default=0, show_default=True,
              help="With --corners: the last N corners form the test split (the rest train).")
@click.option("--processes", type=click.IntRange(min=0), default=0, show_default=True,
              help="With --corners: local worker processes (0 = one per CPU).")
@click.option("--heatmap-dtype", "heatmap_dtype", type=click.Choice(["float16", "float32", "uint8"]), default="float16",
              show_default=True,
              help="With --corners: how heatmaps are stored. float16/float32: linear amplitude; uint8: log10 amplitude "
                   "codes (0.39 dB steps, docs/format.md), a third of float16's size and read ~4x faster by the loader: "
                   "the storage for training at 64x512.")
@dask_options("one recording (with --count) or one corner (with --corners) per task",
              "OUT must be a folder the workers share.")
@click.option("--force", is_flag=True, help="Replace a recording already in OUT (an interrupted run needs no --force).")
@quiet_option()
@json_option()
def synth(out, corner, width, frames, fmt, seed, grid, range_bins, lidar, lidar_fov, camera, no_human, visible_walkers,
          stereo_images, mapping_pass, mapping_scan_hz, robot_stop_x, radar_output, radar_chirps, corners, n_test, processes,
          heatmap_dtype, count, workers, scheduler, force, quiet, as_json) -> None:
    """Synthesise a corner recording (rotating radar, Ouster-like LiDAR, stereo depth camera, a
    walking human on the hidden side) as a real ROS recording, plus truth/ (mesh, trajectories,
    human meshes, scene description).

    \b
    Examples (README "Your own recording" ingests lab/c1 and lab/c2: a data and a mapping pass each):
      holodata synth --out lab/c1 --corner L --frames 6 --grid 32x128 --seed 1
      holodata synth --out lab/c2 --corner T --frames 6 --grid 32x128 --seed 2
    Raw radar samples instead of heatmaps (ingest beamforms them):
      holodata synth --out lab/raw --corner T --frames 2 --grid 32x128 --radar-output iq --no-mapping-pass
    A training dataset of 16 varied corners x 2 rotations, the last 4 for testing:
      holodata synth --corners 16 --frames 2 --grid 32x128 --test 4 --out lab/corpus.zarr
    """
    from holodata.conventions import Grid, RangeBins
    from holodata.synth import SynthSpec

    try:
        g = Grid.parse(grid)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--grid") from err
    if corners is not None:
        if count > 1:
            raise click.UsageError("give either --corners (a training dataset) or --count (recordings), not both")
        from holodata.synth.corpus import CorpusConfig

        cfg = CorpusConfig(corners=corners, frames=4 if frames is None else frames, grid=g,
                           range_bins=RangeBins(n=range_bins), seed=seed, n_test=n_test, heatmap_dtype=heatmap_dtype,
                           radar_output=radar_output, radar_chirps=radar_chirps,
                           **({"hidden_person": 0.0} if no_human else {}))
        _corpus(out, cfg, processes, workers, scheduler, quiet, as_json)
        return
    spec = SynthSpec(corner=corner, width=width, frames=20 if frames is None else frames, format=fmt, seed=seed,
                     human=not no_human, grid=g, range_bins=RangeBins(n=range_bins), lidar_shape=_shape(lidar, "--lidar"),
                     camera_shape=_shape(camera, "--camera"), stereo_images=stereo_images, visible_walkers=visible_walkers,
                     lidar_vertical_fov_deg=lidar_fov, mapping_pass=mapping_pass, mapping_scan_hz=mapping_scan_hz,
                     robot_stop_x=robot_stop_x, radar_output=radar_output, radar_chirps=radar_chirps)
    if count > 1 or workers or scheduler:
        _recordings(out, count, spec, workers, scheduler, quiet, as_json)
    else:
        _recording(out, spec, force, quiet, as_json)


def _recording(out, spec, force: bool, quiet: bool, as_json: bool) -> None:
    """One recording of ``spec`` into ``out`` (its expected size printed first)."""
    from holodata.synth import estimate_bytes, synthesize

    need = estimate_bytes(spec)
    if not (quiet or as_json):
        click.echo(f"writing ~{need / 1e6:.0f} MB (data pass; the mapping pass adds LiDAR scans)", err=True)
    res = synthesize(out, spec, quiet=quiet, force=force)
    if as_json:
        import json

        click.echo(json.dumps(res.summary(), indent=2, default=str))
        return
    size = sum(f.stat().st_size for f in res.recording.rglob("*") if f.is_file()) if res.recording.is_dir() \
        else res.recording.stat().st_size
    click.echo(f"recording: {res.recording} ({res.format}, {sum(res.counts.values())} messages, "
               f"{res.n_frames} radar {'frame' if res.n_frames == 1 else 'frames'}, {size / 1e6:.0f} MB)")
    click.echo(f"truth:     {res.truth_dir} (corner {res.corner}, width {res.width_m:.2f} m, "
               f"human {'yes' if res.human else 'no'})")
    if res.mapping_recording is not None:
        click.echo(f"mapping:   {res.mapping_recording} (the empty corner, LiDAR + odometry; `holodata ingest "
                   f"{res.out_dir}` ingests both passes, and slam localises the data pass in this one)")


def _recordings(out, count: int, spec, workers, scheduler, quiet: bool, as_json: bool) -> None:
    """``count`` recordings of ``spec`` (consecutive seeds) under ``out``, here or on a Dask cluster."""
    import json

    from holodata.distributed import cluster
    from holodata.synth.batch import synth_scenes

    with cluster(workers, scheduler) as client:
        res = synth_scenes(out, count, spec, client=client, quiet=quiet or as_json)
    if as_json:
        click.echo(json.dumps(res, indent=2, default=str))
    else:
        for r in res:
            click.echo(f"recording: {r['recording']} ({r['format']}, {r['n_frames']} radar frames, "
                       f"corner {r['corner']}, width {r['width_m']:.2f} m, seed {r['seed']})")


def _corpus(out, cfg, processes: int, workers, scheduler, quiet: bool, as_json: bool) -> None:
    """The training dataset ``cfg`` (a :class:`~holodata.synth.corpus.CorpusConfig`) into ``out``."""
    from holodata.distributed import cluster
    from holodata.synth.corpus import synth_corpus

    cfg.check()
    with cluster(workers, scheduler) as client:
        res = synth_corpus(out, cfg, processes=processes, client=client, quiet=quiet or as_json)
    if as_json:
        import json

        click.echo(json.dumps(res, indent=2, default=str))
        return
    click.echo(f"dataset: {res['dataset']} ({cfg.corners} corners x {cfg.frames} frames on {cfg.grid.H}x{cfg.grid.W} beams, "
               f"seed {cfg.seed}; {res['written']} written, {cfg.corners - res['written']} already there; "
               f"{res['seconds']:.0f} s)")
    for line in res["span"]:
        click.echo("  " + line)


COMMANDS = [synth]
