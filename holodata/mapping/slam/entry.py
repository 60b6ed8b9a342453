"""The entry points of ``holodata slam``: :func:`slam_scene` (one scene: SLAM proper,
:func:`~.pipeline.run_slam`, or with a map scene the localisation mode, :func:`~.localise.localise_scene`)
and :func:`slam_dataset` (the scenes of a dataset, each data pass localised in its own mapping pass
when the dataset holds one)."""
from __future__ import annotations

from ...dataset.layout import LIDAR_POINTS
from ...errors import InputError
from .config import SlamConfig, SlamOutputs, SlamResult
from .localise import check_map_scene, localise_scene
from .pipeline import run_slam


def slam_scene(dataset_url, scene_id: str | None = None, *, config: SlamConfig = SlamConfig(), mesh_config=None,
               quiet: bool = False, outputs: SlamOutputs = SlamOutputs(), map_scene: str | None = None) -> SlamResult:
    """Run SLAM on one scene of the dataset at ``dataset_url`` (``scene_id`` None: its only scene).

    Writes ``pose/T_world_lidar``, ``pose/T_world_radar`` (with a radar extrinsic), ``mesh/*`` and
    the scene attribute ``slam`` when ``outputs.write``; exports the LiDAR trajectory as TUM
    (``outputs.tum``) and the mesh as PLY (``outputs.ply``). A scene already done with the same
    inputs and settings is not recomputed for writing (``outputs.force`` recomputes) — the poses are
    still returned (:class:`SlamOutputs`).

    ``map_scene``: localisation mode (:func:`localise_scene`): the scene's scans are localised
    against the map that slam builds from that scene (a mapping pass of the same corner), whose mesh
    and map the scene then gets."""
    if map_scene is not None:
        return localise_scene(dataset_url, scene_id, map_scene, config=config, mesh_config=mesh_config, quiet=quiet,
                              outputs=outputs)
    return run_slam(dataset_url, scene_id, config=config, mesh_config=mesh_config, quiet=quiet, outputs=outputs)


def slam_dataset(dataset_url, scene_ids=None, single_exports: bool = False, map_scene: str | None = None,
                 **kwargs) -> list[SlamResult]:
    """:func:`slam_scene` for each of ``scene_ids`` (default: every scene with lidar/points), with
    ``kwargs`` its keyword arguments. ``single_exports``: ``tum``/``ply`` exports (``outputs``) are
    allowed only when one scene is processed.
    ``map_scene``: localise each scene against that mapping pass (:func:`localise_scene`; needs
    ``scene_ids``); without it a scene localised against a mapping pass before is localised against
    that one again (its ``slam.map_scene``)."""
    from ...dataset import open_dataset

    ds = open_dataset(dataset_url)
    if map_scene is not None:
        if not scene_ids:
            raise InputError(f"{dataset_url}: a map scene needs the scenes to localise (give --scene)")
        for sid in scene_ids:
            if sid not in ds.scenes:
                raise InputError(f"{dataset_url}: no scene {sid!r} (have: {', '.join(ds.scenes) or 'none'})")
            check_map_scene(ds, sid, map_scene)
        if single_exports and len(scene_ids) > 1 and _exports(kwargs):
            raise InputError(f"{dataset_url}: {len(scene_ids)} scenes; --ply/--tum need one (give --scene)")
        return [localise_scene(dataset_url, sid, map_scene, **kwargs) for sid in scene_ids]
    if scene_ids:
        for sid in scene_ids:
            if sid not in ds.scenes:
                raise InputError(f"{dataset_url}: no scene {sid!r} (have: {', '.join(ds.scenes) or 'none'})")
        ids = list(scene_ids)
    else:
        ids = [s for s in ds.scenes if LIDAR_POINTS in ds.scene(s)]
    if not ids:
        raise InputError(f"{dataset_url}: no scene has lidar/points (nothing for slam)")
    if single_exports and len(ids) > 1 and _exports(kwargs):
        raise InputError(f"{dataset_url}: {len(ids)} scenes; --ply/--tum need one (give --scene)")
    # a scene localised against a mapping pass before stays localised against it; a data pass whose own
    # mapping pass is in the dataset (<id>_map, role mapping: ingest of a synth folder) is localised in it
    cfg = kwargs.get("config") or SlamConfig()
    prev = {sid: (ds.scene(sid).attrs.get("slam") or {}).get("map_scene")
            or (own_mapping_pass(ds, sid) if cfg.refine and cfg.mesh else None) for sid in ids}
    prev = {sid: m if m in ds.scenes else None for sid, m in prev.items()}
    if not scene_ids:   # a mapping pass is slammed as the map of the scenes localised in it, not on its own
        ids = [s for s in ids if s not in set(prev.values())]
    return [slam_scene(dataset_url, sid, map_scene=prev[sid], **kwargs) for sid in ids]


def _exports(kwargs: dict) -> bool:
    """Whether :func:`slam_dataset`'s keyword arguments ask for a TUM or PLY export."""
    outputs = kwargs.get("outputs")
    return bool(outputs is not None and (outputs.tum or outputs.ply))


def own_mapping_pass(ds, scene_id: str) -> str | None:
    """``<scene_id>_map`` when reader dataset ``ds`` holds it as a mapping pass (scene role, see
    :mod:`holodata.dataset.splits`) and ``scene_id`` is a data pass; else None."""
    from ...dataset.splits import DATA, MAPPING, scene_role

    m = f"{scene_id}_map"
    if m in ds.scenes and scene_role(ds.scene(m).attrs) == MAPPING and scene_role(ds.scene(scene_id).attrs) == DATA:
        return m
    return None
