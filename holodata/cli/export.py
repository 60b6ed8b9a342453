"""``holodata export``: a dataset's scenes in other tools' layouts (PanoRadar npy folders, HDF5)."""
from __future__ import annotations

import json

import click

from holodata.cli.options import json_option, quiet_option


@click.command("export")
@click.argument("dataset")
@click.option("--format", "fmt", type=click.Choice(["panoradar", "hdf5"]), required=True,
              help="panoradar: per scene rf_npy/ lidar_npy/ (+ gt_npy/ label_npy/) as PanoRadar's processed data; "
                   "hdf5: per scene an .h5 in the layout holodata's HDF5 reader reads, every array included.")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--scene", "scenes", multiple=True, help="Scene id (repeatable; default: every scene, or --split's).")
@click.option("--split", default=None, help="Only the scenes of this split (train, test, ...).")
@click.option("--force", is_flag=True,
              help="Replace a scene's folder or file in --out that holodata did not write (never a symlink).")
@quiet_option()
@json_option()
def export(dataset, fmt, out, scenes, split, force, quiet, as_json):
    """Write scenes of DATASET for other tools: PanoRadar's processed trajectory folders (which
    holodata's own npy reader ingests back) or HDF5 files (holodata's HDF5 reader layout). Each scene
    is written under a temp name and moved in place when complete; it replaces only what an earlier
    export wrote (.holodata-manifest.json in --out), else refuses unless --force.

    \b
    Example:
      holodata export lab/ds.zarr --format panoradar --out lab/panoradar --split test
      holodata export lab/ds.zarr --format hdf5 --out lab/h5
    """
    from holodata.export import export_dataset

    r = export_dataset(dataset, fmt, out, scene_ids=list(scenes) or None, split=split, quiet=quiet or as_json,
                      force=force)
    if as_json:
        click.echo(json.dumps(r, indent=2))
        return
    for s in r["scenes"]:
        click.echo(f"{s['scene']}: {s['frames']} frame(s) -> {s['out']}")
    for s in r["skipped"]:
        click.echo(f"{s['scene']}: skipped, {s['why']}")


COMMANDS = [export]
