"""``holodata train``: stage one (the multi-return model) and stage two (the learned ray tracer
and volumetric refiner) on a dataset's train split."""
from __future__ import annotations

from pathlib import Path

import click

from holodata.cli.options import json_option, quiet_option


@click.command()
@click.argument("dataset")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False),
              help="Run directory (checkpoint.pt, stage2.pt, config.json, metrics.jsonl). An existing run resumes.")
@click.option("--epochs", type=click.IntRange(min=1), default=None,
              help="Total stage-one epochs (default 20, or the config file's); also bounds each stage-two phase "
                   "unless --stage2-epochs or --stage2-config says otherwise.")
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default=None, help="Training device (default cpu).")
@click.option("--config", "config_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML/JSON file of TrainConfig fields (flags win).")
@click.option("--batch-size", type=click.IntRange(min=1), default=None)
@click.option("--lr", type=float, default=None, help="AdamW learning rate.")
@click.option("--seed", type=int, default=None)
@click.option("--workers", "num_workers", type=click.IntRange(min=0), default=None, help="DataLoader worker processes.")
@click.option("--range-loss", "range_loss", type=click.Choice(["l1", "ce"]), default=None,
              help="Stage one's range term: l1 (L1 on the soft-argmax mean; default) or ce (cross-entropy over range bins "
                   "against two-hot sub-bin targets, predicted by the mode).")
@click.option("--stage", type=click.Choice(["1", "2", "all"]), default="all", show_default=True,
              help="1: stage one only; 2: stage two only (from --stage1 or RUN/checkpoint.pt); all: stage one, then stage two.")
@click.option("--stage1", "stage1", type=click.Path(), default=None,
              help="Stage-one checkpoint (file or run directory) for --stage 2; must match DATASET's grid and range bins.")
@click.option("--stage2-config", "stage2_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML/JSON file of Stage2Config fields (flags win).")
@click.option("--stage2-epochs", type=click.IntRange(min=0), default=None,
              help="Epochs of each stage-two phase (ray tracer, then refiner; default 20 each).")
@click.option("--init", "init", default=None,
              help="Fine-tune from this checkpoint (file, run directory, or 'pretrained': the weights holodata ships): "
                   "stage one, and stage two where the run has a stage2.pt; its stage-one settings are the defaults, "
                   "flags and --config win.")
@quiet_option()
@json_option()
def train(dataset, out, epochs, device, config_file, batch_size, lr, seed, num_workers, range_loss, stage, stage1,
          stage2_file, stage2_epochs, init, quiet, as_json):
    """Train stage one (the multi-return range-image UNet) and stage two (hybrid ray tracer +
    volumetric refiner, stored in RUN/stage2.pt) on DATASET's train split (`holodata split`).

    \b
    Examples:
      holodata train lab/ds.zarr --out lab/run --epochs 2
      holodata train lab/ds.zarr --out lab/finetuned --init pretrained --epochs 2
      holodata train lab/ds.zarr --out lab/run-s2 --stage 2 --stage1 lab/run --stage2-epochs 1
    On a GPU: add --device cuda. Data-parallel: torchrun --nproc-per-node 2 -m holodata.cli.main train
    DS --out RUN (same global batch and seed; rank 0 writes the checkpoints and trains stage two).
    """
    from holodata.dataset import open_dataset
    from holodata.dataset.splits import split_scenes
    from holodata.torch import ddp
    from holodata.torch.stage2_train import Stage2Config, train_stage2
    from holodata.torch.train import TrainConfig
    from holodata.torch.train import train as run_train

    def check_split() -> None:   # a missing or empty split, or leakage: one line before any training
        split_scenes(open_dataset(dataset), "train")

    summary = {}
    if stage in ("1", "all"):
        flags = {"epochs": epochs, "device": device, "batch_size": batch_size, "lr": lr, "seed": seed,
                 "num_workers": num_workers, "range_loss": range_loss}
        base = {}
        from pathlib import Path

        from holodata.torch.checkpoint import CHECKPOINT, load_checkpoint

        if (Path(out) / CHECKPOINT).exists():
            # the run resumes from it: loaded here first, as tensors and plain data only (a file that
            # pickles other objects is refused before training reads it)
            load_checkpoint(Path(out) / CHECKPOINT)
        if init is not None:
            from holodata.torch.pretrained import resolve

            init = resolve(init, open_dataset(dataset).grid)
            base = dict(load_checkpoint(init).get("train_config") or {})
        if config_file:
            cfg = TrainConfig.from_file(config_file, **flags)
            base.update({k: v for k, v in cfg.to_dict().items() if v != getattr(TrainConfig(), k)})
        base.update({k: v for k, v in flags.items() if v is not None})
        cfg = TrainConfig.from_dict(base)
        check_split()
        res = run_train(dataset, out, cfg, quiet=quiet, init=init)
        summary = {"run": str(res.out_dir), "checkpoint": str(res.checkpoint), "epochs": res.epochs,
                   "resumed_from": res.resumed_from, "final_loss": res.final_loss}
    ctx = ddp.from_env()
    ddp.close(ctx)
    if not ctx.main:
        return  # stage two and the summary: rank 0 alone
    if summary and not as_json:
        click.echo(_done_line("stage one", res.epochs, res.resumed_from, res.final_loss, res.checkpoint))
    if stage in ("2", "all"):
        s2_init = _stage2_init(init, dataset)
        # fine-tuning: the init run's stage-two settings are the defaults (its shapes must match);
        # the --stage2-config file and the flags win
        s2 = dict(_stage2_settings(s2_init)) if s2_init is not None else {}
        s2.update(_read_mapping(stage2_file) if stage2_file else {})
        told = stage2_epochs is not None or bool({"epochs_rt", "epochs_refine"} & set(s2))
        for k, v in {"device": device, "seed": seed, "epochs_rt": stage2_epochs, "epochs_refine": stage2_epochs}.items():
            if v is not None:
                s2[k] = v
        s2cfg = Stage2Config.from_dict(s2, source=str(stage2_file or "stage-two options"))
        if stage == "2":
            check_split()
        if epochs is not None and not told:   # --epochs bounds each stage-two phase too
            s2cfg.epochs_rt, s2cfg.epochs_refine = min(s2cfg.epochs_rt, epochs), min(s2cfg.epochs_refine, epochs)
        r2 = train_stage2(dataset, out, s2cfg, stage1=stage1 if stage == "2" else None, quiet=quiet,
                          init=s2_init)
        last = r2["history"][-1] if r2["history"] else {}
        summary.setdefault("run", str(out))
        summary["stage2"] = {"checkpoint": str(r2["checkpoint"]), "epochs": r2["epochs"],
                             "resumed_from": r2["resumed_from"], "final_loss": last.get("loss")}
        if not as_json:
            click.echo(_done_line("stage two", r2["epochs"], r2["resumed_from"], last.get("loss"), r2["checkpoint"]))
    if as_json:
        import json

        click.echo(json.dumps(summary, indent=2))


def _stage2_init(init, dataset):
    """What stage two fine-tunes from for ``--init``: the named run's stage-two checkpoint when it has one
    (``pretrained`` has), else None (a stage-one checkpoint file alone: stage two trains from scratch)."""
    if init is None:
        return None
    from pathlib import Path

    from holodata.dataset import open_dataset
    from holodata.torch.pretrained import resolve
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT

    run = Path(resolve(init, open_dataset(dataset).grid))
    return run if run.is_dir() and (run / STAGE2_CHECKPOINT).is_file() else None


def _stage2_settings(run) -> dict:
    """The Stage2Config fields a stage-two run was trained with (its stage2.pt), less the device and
    the epoch counts, which belong to the fine-tune."""
    from holodata.safe_io import load_torch
    from holodata.torch.stage2_infer import STAGE2_CHECKPOINT

    cfg = dict(load_torch(run / STAGE2_CHECKPOINT, "stage-two checkpoint").get("stage2_config") or {})
    return {k: v for k, v in cfg.items() if k not in ("device", "epochs_rt", "epochs_refine")}


def _done_line(stage: str, epochs: int, resumed_from: int, loss, checkpoint) -> str:
    """What a stage did: trained (how many epochs this run), or nothing when its checkpoint already had them."""
    from holodata.dataset.info import plural

    fl = "n/a" if loss is None else f"{loss:.4g}"
    if resumed_from >= epochs:
        return f"{stage}: nothing to train ({checkpoint} already has {plural(epochs, 'epoch')}; final loss {fl})"
    start = f" (epochs {resumed_from + 1}-{epochs}: resumed after epoch {resumed_from})" if resumed_from else ""
    return f"{stage}: trained {plural(epochs - resumed_from, 'epoch')}{start}; final loss {fl}; checkpoint {checkpoint}"


def _read_mapping(path) -> dict:
    import yaml

    from holodata.errors import InputError

    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise InputError(f"{path}: cannot read stage-two config ({' '.join(str(err).split())})") from err
    if not isinstance(data, dict):
        raise InputError(f"{path}: stage-two config must be a mapping of field: value")
    return data


COMMANDS = [train]
