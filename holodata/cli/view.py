"""``holodata view``: a scene in Rerun (desktop or web viewer, or an .rrd file)."""
from __future__ import annotations

import json

import click

from holodata.cli.options import json_option


@click.command("view")
@click.argument("dataset")
@click.option("--scene", default=None, help="Scene id (default: the first scene with a radar).")
@click.option("--frames", default=None, metavar="A:B", callback=lambda c, p, v: _frames_spec(v),
              help="Frames A..B-1 (default: all).")
@click.option("--save", type=click.Path(dir_okay=False), default=None, callback=lambda c, p, v: _file_name(v),
              help="Write an .rrd file (open it later with `rerun FILE.rrd`; needs no display). It replaces only an "
                   ".rrd holodata wrote there.")
@click.option("--force", is_flag=True, help="Replace a --save file holodata did not write (never a symlink).")
@click.option("--web", is_flag=True,
              help="Serve the scene to a viewer over gRPC, on 127.0.0.1 only (it prints how to open it: the desktop "
                   "viewer, a browser, or an SSH tunnel from another machine).")
@click.option("--port", type=click.IntRange(1024, 65535), default=None, help="The data server's port (default 9876).")
@click.option("--bind", default="127.0.0.1", show_default=True,
              help="Address of the data server. Anything but loopback opens the scene to the network without "
                   "authentication (and serves Rerun's web viewer page on every interface, port 9090).")
@click.option("--checkpoint", type=click.Path(exists=True), default=None,
              help="A trained run (RUN or RUN/checkpoint.pt): draw its predicted points per frame.")
@click.option("--report", type=click.Path(exists=True, file_okay=False), default=None,
              help="An evaluation's --out directory: draw the predicted points of the run it scored.")
@click.option("--device", default="cpu", show_default=True, help="Torch device for --checkpoint/--report.")
@json_option()
def view(dataset, scene, frames, save, force, web, port, bind, checkpoint, report, device, as_json):
    """Look at a scene in Rerun: per frame (timeline `time`) the radar heatmap (range-azimuth slice
    at 0° elevation, maximum over range), GT range and label images per bounce, the GT returns
    mirrored (where the radar sees them) and un-mirrored (hit points) coloured by label, the LiDAR
    scan, the camera cloud, the human surface and the sensor poses; the static mesh once. With
    --checkpoint or --report, the run's predicted points too (world/pred/points).

    \b
    Examples:
      holodata view lab/ds.zarr --scene c2 --save lab/c2.rrd
      holodata view lab/ds.zarr --scene c2 --report lab/report --save lab/c2-pred.rrd
      holodata view lab/ds.zarr --scene c2 --web
    """
    import os

    from holodata.errors import InputError
    from holodata.view import SceneView, web_instructions

    if save and web:
        raise click.UsageError("--save or --web, not both")
    if checkpoint and report:
        raise click.UsageError("--checkpoint or --report, not both")
    if not save and not web and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise InputError("no display for the desktop viewer: use --save OUT.rrd or --web")
    try:
        import rerun  # noqa: F401
    except ImportError as err:
        raise InputError("holodata view needs the Rerun SDK: pip install -e '.[view]' (scripts/setup.sh installs it)") from err
    r = SceneView(dataset, scene, frames, save=save, web=web, port=port, checkpoint=checkpoint, report=report,
                  device=device, bind=bind, force=force).run()
    stream = r.pop("stream", None)   # noqa: F841 - held: the web viewer's data server lives as long as it
    if as_json:
        click.echo(json.dumps(r, indent=2))
    else:
        where = save or ("the data server" if web else "the viewer")
        click.echo(f"{r['scene']}: {r['frames']} frame(s), {len(r['entities'])} entities -> {where}")
        for n in r["notes"]:
            click.echo(f"note: {n}")
        if web:
            for line in web_instructions(port, bind):
                click.echo(line)
    if web:
        click.echo("serving; Ctrl-C to stop")
        import time

        while True:
            time.sleep(3600)


def _frames_spec(v):
    """``A:B`` with integers on either side (usage error, exit 2, otherwise)."""
    import re

    if v is not None and not re.fullmatch(r"\s*\d*\s*(:\s*\d*\s*)?", v):
        raise click.BadParameter(f"{v!r}: give A:B (frames A..B-1, e.g. 0:40), A: or :B", param_hint="--frames")
    return v


def _file_name(v):
    """A file name for --save, not a folder."""
    import os

    if v is not None and (v.endswith(("/", os.sep)) or os.path.isdir(v)):
        raise click.BadParameter(f"{v!r} is a folder: give a file name, e.g. {os.path.join(v, 'scene.rrd')}",
                                 param_hint="--save")
    return v


COMMANDS = [view]
