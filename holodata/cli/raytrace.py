"""``holodata raytrace-gt``: multi-bounce ground truth per radar beam (docs/format.md §4)."""
from __future__ import annotations

import json

import click

from holodata.cli.options import config_file_option, config_option, dask_options, force_option, json_option, quiet_option


@click.command("raytrace-gt")
@click.argument("dataset", required=False)
@click.option("--scene", "scenes", multiple=True, help="Scene id to trace (dataset form; repeatable; default: all with a mesh).")
@click.option("--mesh", type=click.Path(),
              help="Standalone: scene mesh without human (.ply/.obj/.stl; a PLY face property 'label' gives semantic "
                   "classes), or a directory with one mesh per class (floor.ply, wall.ply, ...).")
@click.option("--poses", type=click.Path(dir_okay=False),
              help="Standalone: radar trajectory T_world_radar as TUM text; one frame per line.")
@click.option("--human", type=click.Path(dir_okay=False), help="Standalone: one human mesh (world frame) for all frames.")
@click.option("--human-dir", type=click.Path(file_okay=False),
              help="Standalone: one human mesh per frame index, named 000000.ply, 000001.ply, ... (k = 0-based TUM row; "
                   ".obj/.stl also accepted).")
@click.option("--out", help="Standalone: output dataset (local path or fsspec URL).")
@click.option("--scene-id", default="scene", show_default=True, help="Standalone: scene id in the output.")
@config_option("--grid", section="gt", field="grid", shown=lambda g: f"{g.H}x{g.W}", help="Standalone: beam grid HxW.")
@config_option("--elevation-fov", section="gt", field="grid", shown=lambda g: f"{g.elev_min_deg:g},{g.elev_max_deg:g}",
               help="Standalone: elevation range in degrees (min,max).")
@config_option("--max-bounces", section="gt", field="max_bounces", type=click.IntRange(1, 16))
@config_option("--max-range", section="gt", field="max_range", type=click.FloatRange(min=0, min_open=True),
               help="Metres of accumulated travel distance.")
@config_option("--backend", section="gt", field="backend", type=click.Choice(["open3d", "embreex"]))
@click.option("--rotation-radius", default=None, type=click.FloatRange(min=0),
              help="Beam origin on the rotation circle of this radius (m) per column; 0 = rotation centre. Default: the model "
                   "the recording states (docs/format.md §2: the rotation centre).")
@click.option("--column-time/--no-column-time", default=None,
              help="Each column at its own time within the rotation (pose SLERP between trajectory samples; rotation cycles "
                   "from radar/cycle_ns). Default: the recording's model (on).")
@click.option("--rotation-hz", default=None, type=click.FloatRange(min=0, min_open=True),
              help="Rotation rate (Hz) for column times of frames without a stored rotation cycle. Dataset form: the "
                   "frame stamp is the middle of the rotation (default 2). Standalone: each TUM row's columns span "
                   "1/Hz from its stamp (default: to the next row's stamp); a rotation longer than the rows' spacing "
                   "is an error.")
@config_option("--codec", section="gt", field="codec", type=click.Choice(["lz4", "zstd"]),
               help="Blosc codec (with shuffle) of the gt arrays: lz4 encodes ~2x faster, zstd files are ~25% smaller.")
@click.option("--shard-frames", default=None, type=click.IntRange(1),
              help="Frames per shard of the gt arrays (default: the dataset's; 32 for a new one).")
@config_option("--threads", section="gt", field="nthreads", type=click.IntRange(0),
               help="Ray-casting threads per process (0 = cores / processes).")
@click.option("--processes", default=0, show_default=True, type=click.IntRange(0),
              help="Local tracing processes (0 = one per core, max 4, for >= 1000 frames; 1 = in-process).")
@dask_options("one task per shard",
              "the dataset and inputs must be reachable from the workers (shared folder or s3://; credentials from the "
              "workers' environment).")
@config_file_option("section gt")
@force_option(help="Dataset form: trace every scene again. Without it, a scene whose GT was traced from other inputs "
                   "(a person registered since, a new mesh or poses, other settings) is traced again, others resume.")
@quiet_option()
@json_option()
def raytrace_gt(dataset, scenes, mesh, poses, human, human_dir, out, scene_id, grid, elevation_fov, max_bounces,
                max_range, backend, rotation_radius, column_time, rotation_hz, codec, shard_frames, threads, processes, workers,
                scheduler, config_file, force, quiet, as_json):
    """Ray-trace multi-bounce ground truth (gt/range, gt/normal, gt/point, gt/label, gt/semantic,
    gt/human_center) for every frame, shard by shard (an interrupted run resumes).

    \b
    On a dataset (reads mesh/*, pose/T_world_radar, time/timestamp_ns and a registered human):
      holodata raytrace-gt lab/ds.zarr
      holodata raytrace-gt lab/ds.zarr --scene c1 --force
    Standalone (a mesh and a TUM trajectory; --human-dir holds one mesh per frame):
      holodata raytrace-gt --mesh lab/c1.ply --poses lab/c1/truth/trajectory_radar.tum --out lab/gt.zarr --grid 32x128
    On a Dask cluster, writing to S3 (AWS_* variables in the workers' environment):
      holodata raytrace-gt s3://lab-bucket/data.zarr --scheduler tcp://head:8786
    """
    from dataclasses import replace

    from holodata.config_file import build
    from holodata.conventions import Grid
    from holodata.dataset.info import plural
    from holodata.groundtruth import OriginModel, RaytraceStandalone, raytrace_dataset

    standalone = mesh is not None
    if standalone:
        if dataset is not None or scenes:
            raise click.UsageError("give either DATASET [--scene] or --mesh/--poses/--out, not both")
        if poses is None or out is None:
            raise click.UsageError("standalone form needs --mesh, --poses and --out")
        if force:
            raise click.UsageError("--force belongs to the dataset form")
    else:
        if dataset is None:
            raise click.UsageError("give DATASET, or --mesh/--poses/--out for the standalone form")
        if any(x is not None for x in (poses, human, human_dir, out)):
            raise click.UsageError("--poses/--human/--human-dir/--out belong to the standalone form (with --mesh)")
    if human is not None and human_dir is not None:
        raise click.UsageError("give either --human or --human-dir, not both")
    # GTConfig's defaults, then the --config file's section gt, then the flags given (None: not given)
    cfg = build("gt", config_file, dict(max_bounces=max_bounces, max_range=max_range, backend=backend,
                                        shard_frames=shard_frames, nthreads=threads, codec=codec))
    if (grid, elevation_fov) != (None, None):   # the one given replaces its half of the file's (or default) grid
        g = cfg.grid
        try:
            cfg = replace(cfg, grid=Grid.parse(grid or f"{g.H}x{g.W}",
                                               elevation_fov or f"{g.elev_min_deg!r},{g.elev_max_deg!r}"))
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--grid/--elevation-fov") from err
    if (rotation_radius, column_time, rotation_hz) != (None, None, None):
        # the origin flags given replace the recording's model: the file's origin, else the defaults of
        # docs/format.md §2, with the given fields changed
        d = cfg.origin or OriginModel()
        cfg = replace(cfg, origin=OriginModel(d.rotation_radius if rotation_radius is None else rotation_radius,
                                              d.column_time if column_time is None else column_time,
                                              d.rotation_hz if rotation_hz is None else rotation_hz))
    from holodata.distributed import cluster

    with cluster(workers, scheduler) as client:
        if standalone:
            summary = RaytraceStandalone(mesh, poses, out, human=human, human_dir=human_dir, scene_id=scene_id,
                                         cfg=cfg, quiet=quiet, processes=processes, client=client,
                                         rotation_hz=rotation_hz).run()
        else:
            summary = raytrace_dataset(dataset, list(scenes) or None, cfg=cfg, quiet=quiet, processes=processes,
                                       client=client, force=force)
    if as_json:
        click.echo(json.dumps(summary))
    elif not quiet:
        for s in summary["scenes"]:
            if s.get("retraced"):
                why = "--force" if s["retraced"] == ["--force"] else f"its inputs changed ({', '.join(s['retraced'])})"
                click.echo(f"{summary['out']}: scene {s['scene']}: traced again: {why}")
            click.echo(f"{summary['out']}: scene {s['scene']}: {plural(s['frames'], 'frame')}, "
                       f"{plural(s['shards_written'], 'shard')} written, {s['shards_skipped']} already done "
                       f"({s['seconds']} s; beams from the {s['origin_model']}"
                       + (f": {s['column_times']})" if s.get("column_times") else ")"))


COMMANDS = [raytrace_gt]
