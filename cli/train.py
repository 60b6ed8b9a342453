"""``holodata train``: the multi-return model on a dataset's train split."""
from __future__ import annotations

import click


@click.command()
@click.argument("dataset")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Run directory (checkpoint.pt, config.json, metrics.jsonl). An existing run resumes.")
@click.option("--epochs", type=click.IntRange(min=1), default=None, help="Total epochs (default 20, or the config file's).")
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default=None, help="Training device (default cpu).")
@click.option("--config", "config_file", type=click.Path(exists=True, dir_okay=False), default=None, help="YAML/JSON file of TrainConfig fields (flags win).")
@click.option("--batch-size", type=click.IntRange(min=1), default=None)
@click.option("--lr", type=float, default=None, help="AdamW learning rate.")
@click.option("--seed", type=int, default=None)
@click.option("--workers", "num_workers", type=click.IntRange(min=0), default=None, help="DataLoader worker processes.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
def train(dataset, out, epochs, device, config_file, batch_size, lr, seed, num_workers, quiet, as_json):
    """Train the multi-return range-image UNet on DATASET's train split (split by scene).

    Example: holodata train demo/dataset.zarr --out runs/unet --epochs 30 --device cuda
    """
    from holodata.torch.train import TrainConfig, train as run_train

    flags = {"epochs": epochs, "device": device, "batch_size": batch_size, "lr": lr, "seed": seed,
             "num_workers": num_workers}
    if config_file:
        cfg = TrainConfig.from_file(config_file, **flags)
    else:
        cfg = TrainConfig.from_dict({k: v for k, v in flags.items() if v is not None})
    res = run_train(dataset, out, cfg, quiet=quiet)
    summary = {"run": str(res.out_dir), "checkpoint": str(res.checkpoint), "epochs": res.epochs,
               "resumed_from": res.resumed_from, "final_loss": res.final_loss}
    if as_json:
        import json

        click.echo(json.dumps(summary, indent=2))
    else:
        start = f" (resumed after epoch {res.resumed_from})" if res.resumed_from else ""
        click.echo(f"trained {res.epochs} epochs{start}; final loss {res.final_loss:.4g}; checkpoint {res.checkpoint}")


COMMANDS = [train]
