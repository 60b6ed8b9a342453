"""``holodata ingest``."""
from __future__ import annotations

import click

from holodata.cli.options import dask_options, json_option, quiet_option


@click.command()
@click.argument("recordings", nargs=-1, required=True)
@click.option("--out", "out", help="Dataset to create or extend (local path or fsspec URL).")
@click.option("--list", "list_only", is_flag=True,
              help="Only print each recording's topics, types, counts, rates and the roles ingest would use.")
@click.option("--topics", "topics_file", type=click.Path(dir_okay=False),
              help="YAML file mapping roles to topics (see examples/topics.yaml).")
@click.option("--scene-id", "scene_ids", multiple=True,
              help="Scene id, once per RECORDING argument (default: its file or folder name). A holodata synth "
                   "output folder is its data pass <ID> and its mapping pass <ID>_map.")
@click.option("--msg-dir", type=click.Path(file_okay=False),
              help="Folder of .msg files for message types the recording does not define.")
@click.option("--meta", type=click.Path(dir_okay=False),
              help="Ouster sensor metadata .json for a .pcap (default: same name next to the pcap).")
@click.option("--tolerance", "tolerance_ms", type=float, default=None,
              help="Max time offset (ms) between a frame and the LiDAR scan / camera frame synced to it "
                   "(default per sensor: half its median period, at least 50 ms).")
@click.option("--codec", type=click.Choice(["zstd", "lz4"]), default=None,
              help="Compression of the new arrays (default: lz4 for bulk arrays, the dataset's zstd for small ones).")
@click.option("--beamform-grid", default=None, metavar="HxW",
              help="Raw radar samples (PanoRadar raw trajectories): beams of the heatmaps formed, elevation x "
                   "azimuth (default 64x512, elevation +45..-45 deg).")
@click.option("--beamform-fov", type=click.FloatRange(1.0, 360.0), default=None,
              help="Raw radar samples: azimuth field of view of one beam's synthetic aperture, degrees (default 90).")
@click.option("--beamform-focus", type=click.Choice(["far", "near"]), default=None,
              help="Raw radar samples: far = PanoRadar's far-field azimuth compensation (default); near = focus "
                   "on every range bin with the exact antenna distances (sharper below ~3 m).")
@click.option("--beamform-motion", "motion", type=click.Choice(["static", "moving"]), default=None,
              help="PanoRadar raw trajectories: the robot was at rest (static: circular padding, no motion term) or "
                   "moving (default: static when the trajectory's folder or its parent, the building folder as in "
                   "PanoRadar, names 'static'; --list says which rule decided).")
@click.option("--keep-iq", is_flag=True,
              help="Raw radar samples: also store them (radar/iq, ~21 MB per full-size rotation) so that "
                   "`holodata beamform` can re-image them with other parameters.")
@dask_options("one recording per task", "recordings must be readable at the same paths on the workers.")
@quiet_option("No progress bar, no warnings.")
@json_option("Print the summary as JSON on stdout.")
def ingest(recordings, out, list_only, topics_file, scene_ids, msg_dir, meta, tolerance_ms, codec, beamform_grid,
           beamform_fov, beamform_focus, motion, keep_iq, workers, scheduler, quiet, as_json):
    """Read RECORDING(s) — ROS 1 .bag, rosbag2 folder (sqlite3/mcap), .mcap, .db3, Ouster
    .pcap (+ .json), .h5 (holodata layout), PanoRadar rf_npy/lidar_npy folder or raw trajectory
    (radar_data.npy + data_params.npz: beamformed here, parameters in the scene attrs) — and write one
    dataset scene per recording: radar heatmaps, LiDAR scans and camera clouds synced to the radar
    rotation cycles (LiDAR scans are the frames when there is no radar), timestamps, TF poses and
    extrinsics. Rerun the same command to resume. A recording cut short is ingested up to where it
    breaks and marked truncated.

    Exit 0 when every recording was ingested (warnings go to stderr), 1 when one could not be.

    \b
    Examples (the recordings of `holodata synth --help`):
      holodata ingest --list lab/c1
      holodata ingest lab/c1 lab/c2 --out lab/ds.zarr
      holodata ingest lab/raw --out lab/raw.zarr --beamform-grid 32x128 --beamform-focus near --keep-iq
    A lab's own bags, topics named in a file (examples/topics.yaml):
      holodata ingest corner_01.bag corner_01_map.bag --out data.zarr --scene-id c1 --scene-id c1_map --topics topics.yaml
    """
    import json
    import sys

    from holodata.dataset.info import plural
    from holodata.ingest import IngestOptions, format_listing, list_recording
    from holodata.ingest import ingest as run_ingest

    beamform = _beamform_params(beamform_grid, beamform_fov, beamform_focus)
    bf_kw = {"beamform": beamform} if beamform is not None else {}
    if motion is not None:
        bf_kw["motion"] = motion
    if list_only:
        infos, errors = [], []
        for r in recordings:
            try:
                infos.append(list_recording(r, msg_dir=msg_dir, meta=meta, topics=topics_file, **bf_kw))
            except Exception as err:  # noqa: BLE001 - one line per recording
                from holodata.cli.main import one_line

                errors.append(f"{r}: {one_line(err)}" if str(r) not in str(err) else one_line(err))
        if as_json:
            click.echo(json.dumps({"recordings": infos, "errors": errors}, indent=2))
        else:
            click.echo("\n\n".join(format_listing(i) for i in infos))
        for e in errors:
            click.echo(f"error: {e}", err=True)
        sys.exit(1 if errors else 0)
    if not out:
        raise click.UsageError("--out DATASET is required (or use --list)")
    from holodata.distributed import cluster

    with cluster(workers, scheduler) as client:
        opts = IngestOptions(topics=topics_file, msg_dir=msg_dir, tolerance_ms=tolerance_ms, meta=meta, codec=codec,
                             beamform=beamform, keep_iq=keep_iq, motion=motion)
        summary = run_ingest(list(recordings), out, opts, scene_ids=list(scene_ids) or None, quiet=quiet or as_json,
                             client=client)
    if as_json:
        click.echo(json.dumps(summary, indent=2, default=str))
    else:
        for sc in summary["scenes"]:
            if sc.get("skipped"):
                click.echo(f"{sc['scene']}: {sc['skipped']} ({plural(sc['frames'], 'frame')})")
                continue
            arrays = ", ".join(sc["arrays"])
            trunc = " (truncated recording: readable part)" if sc["truncated"] else ""
            click.echo(f"{sc['scene']}: {plural(sc['frames'], 'frame')} ({sc['frame_sensor']}) from {sc['recording']}{trunc}"
                       f" -> {arrays}")
        click.echo(f"dataset: {summary['dataset']}")
    if not quiet:
        for sc in summary["scenes"]:
            for w in sc.get("notes", []) + sc.get("warnings", []):
                click.echo(f"warning: {sc['scene']}: {w}", err=True)
    for f in summary["failed"]:
        click.echo(f"error: {f['error']}", err=True)
    sys.exit(0 if summary["ok"] else 1)


COMMANDS = [ingest]


def _beamform_params(grid: str | None, fov: float | None, focus: str | None = None):
    """BeamformParams from the --beamform-* flags (None when none was given: the reader's default)."""
    if grid is None and fov is None and focus is None:
        return None
    from holodata.conventions import Grid
    from holodata.radar import BeamformParams

    kw = {}
    if grid is not None:
        try:
            g = Grid.parse(grid)
        except ValueError as err:
            raise click.BadParameter(str(err), param_hint="--beamform-grid") from err
        kw["grid"] = g
    if fov is not None:
        kw["azimuth_fov_deg"] = fov
    if focus is not None:
        kw["focus"] = focus
    try:
        return BeamformParams(**kw)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--beamform-grid") from err
