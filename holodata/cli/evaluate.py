"""``holodata evaluate``: model + baseline metrics, metrics.json and report.html."""
from __future__ import annotations

import click

from holodata.cli.options import json_option, quiet_option


@click.command()
@click.argument("dataset")
@click.option("--checkpoint", type=click.Path(), help="RUN directory or RUN/checkpoint.pt, or 'pretrained' (the weights "
              "holodata ships for the dataset's grid: 32x128 or 64x512; any other grid is refused); not with --oracle.")
@click.option("--oracle", is_flag=True,
              help="Score the ground truth itself (GT ranges, normals, labels) through the same stage-two un-mirroring: a "
                   "perfect prediction, which must score perfectly.")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False),
              help="Report directory (metrics.json, report.html, PNGs).")
@click.option("--split", default="test", show_default=True, help="Dataset split to evaluate.")
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True)
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Evaluate only the first N frames of the split.")
@click.option("--estimator", type=click.Choice(["auto", "mean", "median", "mode"]), default="auto", show_default=True,
              help="Point estimate of each beam's range-bin distribution (soft-argmax models; auto: the one the "
                   "checkpoint was trained for).")
@click.option("--motion-cue", is_flag=True,
              help="Find the person from the change between a corner's consecutive rotations (no training): the "
                   "model row's human centres are the moving person's instead of the per-beam human head's "
                   "clusters (holodata.evaluate.motion).")
@click.option("--screenshot", is_flag=True, help="Also save REPORT/report.png (headless Chromium).")
@quiet_option()
@json_option("Print metrics.json on stdout.")
def evaluate(dataset, checkpoint, oracle, out, split, device, max_frames, estimator, motion_cue, screenshot, quiet,
             as_json):
    """Evaluate a trained checkpoint and the strongest-peaks baseline on DATASET's split.

    \b
    \b
    Examples:
      holodata evaluate lab/ds.zarr --checkpoint lab/run --out lab/report
      holodata evaluate lab/ds.zarr --checkpoint pretrained --out lab/report-pretrained
    The ground truth through the same stage two (a check of origins, frames and metrics):
      holodata evaluate lab/ds.zarr --oracle --out lab/report-oracle
    """
    from holodata.evaluate import Evaluation
    from holodata.evaluate.motion import MotionCue

    if oracle == (checkpoint is not None):
        raise click.UsageError("give either --checkpoint RUN or --oracle")
    doc = Evaluation(dataset, checkpoint, out, split=split, device=device, max_frames=max_frames, quiet=quiet,
                     estimator=None if estimator == "auto" else estimator, oracle=oracle,
                     motion=MotionCue() if motion_cue else None).run()
    if screenshot:
        from pathlib import Path

        from holodata.evaluate.report import screenshot as shoot

        shoot(Path(out) / "report.html", Path(out) / "report.png")
    if as_json:
        import json

        click.echo(json.dumps(doc, indent=2))
        return
    from holodata.evaluate import format_tables

    click.echo(format_tables(doc))
    click.echo(f"report: {out}/report.html")


COMMANDS = [evaluate]
