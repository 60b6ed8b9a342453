"""``holodata info`` and ``holodata validate``."""
from __future__ import annotations

import click

from holodata.cli.options import json_option, quiet_option


@click.command()
@click.argument("dataset")
@json_option("Print the summary as JSON on stdout.")
def info(dataset: str, as_json: bool) -> None:
    """Summarise DATASET: scenes, frames, arrays, sizes, compression, splits.

    \b
    Examples:
      holodata info lab/ds.zarr
      holodata info holodata-demo/dataset.zarr
    """
    from holodata.dataset import dataset_info, format_info

    summary = dataset_info(dataset)
    if as_json:
        import json

        click.echo(json.dumps(summary, indent=2))
    else:
        click.echo(format_info(summary))


@click.command()
@click.argument("dataset")
@json_option("Print the report as JSON on stdout.")
@quiet_option()
def validate(dataset: str, as_json: bool, quiet: bool) -> None:
    """Check DATASET (local path or fsspec URL): attributes against the JSON Schemas, arrays and
    shapes implied by the grid, every shard's checksum and decoding, and the value rules (ranges,
    bounce order, labels, unit normals, timestamps, rigid poses, ragged offsets, splits).

    Prints one line per problem (scene, array, frame); exit 0 when clean, 1 otherwise.

    \b
    Examples:
      holodata validate lab/ds.zarr
      holodata validate holodata-demo/dataset.zarr --json
    """
    import sys

    from holodata.dataset.validate import format_report, validate_dataset

    report = validate_dataset(dataset, quiet=quiet or as_json)
    if as_json:
        import json

        click.echo(json.dumps(report, indent=2))
    else:
        click.echo(format_report(report))
    sys.exit(0 if report["ok"] else 1)


COMMANDS = [info, validate]
