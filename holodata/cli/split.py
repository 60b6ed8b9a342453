"""``holodata split``: set a dataset's train/test splits."""
from __future__ import annotations

import json

import click

from holodata.cli.options import json_option


@click.command("split")
@click.argument("dataset")
@click.option("--test", "test", multiple=True, required=True, metavar="SCENE",
              help="A data pass held out for evaluation (repeatable).")
@click.option("--train", "train", multiple=True, metavar="SCENE",
              help="A data pass to train on (repeatable; default: every data pass not in --test).")
@json_option("Print the splits as JSON on stdout.")
def split(dataset, test, train, as_json):
    """Set the train and test splits of DATASET. Splits hold data passes (radar recordings) only:
    mapping passes (LiDAR-only scenes, e.g. <ID>_map) are left out. train and evaluate use exactly
    these splits; a dataset without them is refused rather than split by a guess.

    \b
    Examples:
      holodata split lab/ds.zarr --test c2
      holodata split lab/ds.zarr --test c2 --train c1
    """
    from holodata.dataset.splits import set_splits

    r = set_splits(dataset, list(test), list(train) or None)
    if as_json:
        click.echo(json.dumps(r))
    else:
        for name in ("train", "test"):
            click.echo(f"{name}: {', '.join(r[name])}")


COMMANDS = [split]
