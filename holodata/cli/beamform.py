"""``holodata beamform``: re-image stored raw radar samples (``ingest --keep-iq``) into radar/heatmap."""
from __future__ import annotations

import json
from dataclasses import dataclass

import click

from holodata.cli.options import dask_options, json_option, quiet_option


@click.command("beamform")
@click.argument("dataset")
@click.option("--scene", "scenes", multiple=True, help="Scene id (repeatable; default: every scene with radar/iq).")
@click.option("--fov", "fov", type=click.FloatRange(1.0, 360.0), default=None,
              help="Azimuth field of view of one beam's synthetic aperture, degrees (default: as ingested).")
@click.option("--n-syn", type=click.IntRange(min=1), default=None, help="Chirps per beam (odd; default: from --fov).")
@click.option("--window", type=click.Choice(["hann", "hamming", "blackman", "rect"]), default=None,
              help="Window over the chirps and the samples (default: as ingested).")
@click.option("--static-removal", type=click.Choice(["trajectory", "rotation", "none"]), default=None,
              help="Static reflection removed before imaging (default: as ingested).")
@click.option("--focus", type=click.Choice(["far", "near"]), default=None,
              help="far: PanoRadar's far-field azimuth compensation; near: focus on every range bin with the exact "
                   "antenna distances (default: as ingested).")
@click.option("--motion", type=click.Choice(["recorded", "slam", "none"]), default="recorded", show_default=True,
              help="Platform motion per rotation: what ingest imaged with, from slam's pose/T_world_radar, or at rest.")
@click.option("--device", default="cpu", show_default=True, help="cpu (numpy/numba) or a torch device such as cuda.")
@dask_options("one task per shard", "the dataset must be reachable from the workers (shared folder or s3://).")
@quiet_option()
@json_option()
def beamform(dataset, scenes, fov, n_syn, window, static_removal, focus, motion, device, workers, scheduler, quiet, as_json):
    """Re-image the raw radar samples a scene was ingested with (`holodata ingest --keep-iq`) into
    radar/heatmap, on the dataset's grid, with other imaging parameters or the motion slam measured.
    Every parameter goes into the scene attrs (source.beamform). Rerun to resume.

    \b
    \b
    Examples (lab/raw.zarr: `holodata ingest --help`):
      holodata beamform lab/raw.zarr --fov 60 --window hamming
      holodata beamform lab/raw.zarr --focus near
    """
    from holodata.dataset import open_dataset
    from holodata.dataset.layout import RADAR_IQ
    from holodata.distributed import cluster
    from holodata.errors import DatasetError

    ds = open_dataset(dataset)
    todo = list(scenes) or [s for s in ds.scenes if RADAR_IQ in ds.scene(s)]
    if not todo:
        raise DatasetError(f"{ds.url}: no scene holds radar/iq (ingest raw recordings with --keep-iq)")
    out = []
    with cluster(workers, scheduler) as client:
        for sid in todo:
            out.append(_one(dataset, ds, sid, _Imaging(fov, n_syn, window, static_removal, focus), motion, device,
                            client, quiet or as_json))
            if not as_json:
                r = out[-1]
                click.echo(f"{sid}: {r['skipped']}" if r.get("skipped") else
                           f"{sid}: {r['frames']} rotation(s) imaged (n_syn {r['n_syn']}, motion {r['motion']}) "
                           f"in {r['seconds']} s")
    if as_json:
        click.echo(json.dumps({"dataset": dataset, "scenes": out}, indent=2))


@dataclass
class _Imaging:
    """The imaging flags given (None: as ingested): ``fov`` (degrees), ``n_syn``, ``window`` (chirps and
    samples), ``static_removal``, ``focus``."""

    fov: float | None = None
    n_syn: int | None = None
    window: str | None = None
    static_removal: str | None = None
    focus: str | None = None

    def params(self, src: dict):
        """The BeamformParams of a scene ingested with ``src`` (its source.beamform.params) and these flags."""
        from holodata.radar import BeamformParams

        kw = BeamformParams.from_attrs(src).to_attrs()
        if self.fov is not None:
            kw.update(azimuth_fov_deg=self.fov, n_syn=None)
        if self.n_syn is not None:
            kw["n_syn"] = self.n_syn
        if self.window is not None:
            kw.update(chirp_window=self.window, sample_window=self.window)
        if self.static_removal is not None:
            kw["static_removal"] = self.static_removal
        if self.focus is not None:
            kw["focus"] = self.focus
        try:
            return BeamformParams.from_attrs(kw)
        except ValueError as err:
            raise click.BadParameter(str(err)) from err


def _one(dataset, ds, sid, imaging: _Imaging, motion, device, client, quiet) -> dict:
    """Imaging parameters of scene ``sid``: as ingested, with the flags given; then beamform it."""
    from holodata.errors import DatasetError
    from holodata.reimage import beamform_scene

    if sid not in ds.scenes:
        raise DatasetError(f"{ds.url}: no scene {sid!r} (have {', '.join(ds.scenes)})")
    src = ((ds.scene(sid).attrs.get("source") or {}).get("beamform") or {}).get("params") or {}
    params = imaging.params(src)
    return beamform_scene(dataset, sid, params, motion=motion, device=device, quiet=quiet, client=client)


COMMANDS = [beamform]
