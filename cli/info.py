"""``holodata info`` and ``holodata validate``."""
from __future__ import annotations

import click


@click.command()
@click.argument("dataset")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout.")
def info(dataset: str, as_json: bool) -> None:
    """Summarise DATASET: scenes, frames, arrays, sizes, compression, splits.

    Example: holodata info demo/dataset.zarr
    """
    from holodata.dataset import dataset_info, format_info

    summary = dataset_info(dataset)
    if as_json:
        import json

        click.echo(json.dumps(summary, indent=2))
    else:
        click.echo(format_info(summary))


COMMANDS = [info]
