"""``holodata demo``: the whole pipeline end to end on synthetic corners."""
from __future__ import annotations

import click

from holodata.cli.options import json_option, quiet_option


@click.command()
@click.option("--out", "out", type=click.Path(file_okay=False), default="holodata-demo", show_default=True,
              help="Output folder (recordings/, dataset.zarr, run/, report/); rerunning resumes.")
@click.option("--quick", is_flag=True, help="Small grids and few frames, raw radar samples, both stages fine-tuned from the "
              "shipped weights: about 3 minutes on 2 idle cores.")
@click.option("--from-scratch", "from_scratch", is_flag=True,
              help="With --quick: train both stages from scratch (15 + 3 + 2 epochs, about 5 minutes) instead of "
                   "fine-tuning the weights holodata ships (the full demo always trains from scratch: they are for "
                   "--quick's grid).")
@click.option("--keep-recordings", "keep_recordings", is_flag=True,
              help="Keep the MCAP recordings under OUT/recordings once ingested (quick demo: ~2 GB); by default "
                   "they are removed (their truth/ stays) and a rerun takes them from the dataset.")
@click.option("--mapping", type=click.Choice(["slam", "truth"]), default="slam", show_default=True,
              help="Poses, mesh and humans from holodata slam + register, or from the synthetic truth (oracle).")
@click.option("--radar-output", "radar_output", type=click.Choice(["heatmap", "iq"]), default=None,
              help="iq: synth records raw radar samples and ingest beamforms them, as a real rig's data goes (the "
                   "default with --quick); heatmap: synth records the direct heatmaps (the default for the full demo, "
                   "whose 320 full-size rotations of raw samples would take about an hour to synthesise).")
@click.option("--beamform-focus", "focus", type=click.Choice(["near", "far"]), default=None,
              help="With --radar-output iq: ingest's beamformer focuses every range bin with the exact antenna "
                   "distances (near, the default) or uses PanoRadar's far-field compensation (far).")
@quiet_option("No progress bars.")
@json_option()
def demo(out, quick, from_scratch, keep_recordings, mapping, radar_output, focus, quiet, as_json) -> None:
    """Synthesise train and test corners as MCAP recordings, ingest them, map them, ray-trace the
    multi-bounce ground truth, validate the dataset, train both stages of the bundled model and
    evaluate every Table-2 row against the strongest-peaks baseline. Prints where the report is.

    \b
    Examples:
      holodata demo --quick
      holodata demo --quick --from-scratch --out holodata-demo-scratch
      holodata demo --quick --radar-output heatmap --out holodata-demo-heatmaps
    """
    import dataclasses

    from holodata.demo import combined_metrics, default_radar_output, demo_config, run_demo
    from holodata.evaluate import format_tables

    log = None if as_json else (lambda line: click.echo(line, err=True))
    cfg = dataclasses.replace(demo_config(quick, from_scratch=from_scratch),
                              radar_output=radar_output or default_radar_output(quick))
    if focus is not None:
        cfg = dataclasses.replace(cfg, beamform_focus=focus)
    res = run_demo(out, quick=quick, mapping=mapping, quiet=quiet, log=log, config=cfg, keep_recordings=keep_recordings)
    if as_json:
        import json

        click.echo(json.dumps({"out": str(res.out_dir), "dataset": str(res.dataset), "report": str(res.report),
                               "mapping": res.mapping, "timings": res.timings,
                               "metrics": res.metrics, "pretrained": res.pretrained}, indent=2, default=str))
        return
    click.echo(format_tables(combined_metrics(res.metrics, res.pretrained)))
    trained = "fine-tuned from the shipped weights" if cfg.init else "trained from scratch"
    click.echo(f"model*: the demo's model ({trained} on the train corners)"
               + ("; pretrained, pretr_*: the shipped weights as they are (holodata evaluate DATASET --checkpoint "
                  "pretrained); baseline, oracle_stage1: as in report.html" if res.pretrained is not None else ""))
    click.echo(f"dataset: {res.dataset}  (holodata info {res.dataset})")
    click.echo(f"report:  {res.report}")


COMMANDS = [demo]
