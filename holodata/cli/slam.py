"""``holodata slam``: LiDAR poses, radar poses and the static mesh of a scene (docs/format.md §4)."""
from __future__ import annotations

import json

import click

from holodata.cli.options import config_file_option, config_option, force_option, json_option, quiet_option


@click.command("slam")
@click.argument("dataset")
@click.option("--scene", "scenes", multiple=True, help="Scene id (repeatable; default: every scene with LiDAR scans).")
@config_option("--voxel", section="slam", field="voxel", type=click.FloatRange(0.02, 2.0),
               help="kiss-icp voxel size in metres (indoor corridors: 0.1-0.2).")
@click.option("--max-range", type=click.FloatRange(min=0, min_open=True), default=None,
              help="LiDAR max range in metres (default: from the data).")
@click.option("--no-refine", is_flag=True, default=None, help="Bare kiss-icp poses (no open3d scan-to-map refinement).")
@click.option("--global-pass", is_flag=True, default=None,
              help="A second refinement pass of every scan against the whole static map (slower; mm-level gain on "
                   "synthetic corners).")
@config_option("--mesh-method", section="mesh", field="method", type=click.Choice(["poisson", "bpa"]),
               help="Surface reconstruction of the static scene.")
@config_option("--mesh-voxel", section="mesh", field="voxel", type=click.FloatRange(0.005, 0.5),
               help="Resolution of the merged (voxel-averaged) static cloud in metres.")
@click.option("--no-mesh", is_flag=True, default=None, help="Poses only.")
@click.option("--ply", type=click.Path(dir_okay=False), help="Also export the mesh as PLY (one scene only).")
@click.option("--tum", type=click.Path(dir_okay=False), help="Also export the LiDAR trajectory as TUM text (one scene only).")
@click.option("--truth", type=click.Path(file_okay=False), help="A holodata synth truth/ folder: print ATE/RPE and mesh "
              "Chamfer/F-scores against it, the mesh's coverage of the true surface within the radar's 3-bounce reach "
              "and the GT NLOS points per frame through the SLAM vs the true mesh (one scene only).")
@click.option("--report", type=click.Path(file_okay=False), help="With --truth: folder for accuracy.json and PNG plots.")
@click.option("--map-scene", "map_scene", default=None, metavar="MAPID",
              help="Localisation mode: a mapping pass of the same corner (its own LiDAR-only scene, e.g. ingested "
              "from a separate recording) is slammed first; the --scene scans are localised against its map and "
              "get its mesh. The map scene is marked role=mapping (no train/test split, no raytrace-gt). Default: the "
              "scene's own mapping pass <ID>_map when the dataset holds one (ingest of a synth output folder).")
@config_file_option("sections slam, mesh, ...")
@force_option()
@quiet_option()
@json_option()
def slam(dataset, scenes, voxel, max_range, no_refine, global_pass, mesh_method, mesh_voxel, no_mesh, ply, tum, truth,
         report, map_scene, config_file, force, quiet, as_json):
    """Estimate the LiDAR pose of every scan (kiss-icp, refined by scan-to-map point-to-plane ICP),
    the radar poses through the extrinsic, and a mesh of the static scene (moving points removed);
    writes pose/T_world_lidar, pose/T_world_radar, mesh/vertices, mesh/faces into the scene.

    \b
    Examples (each data pass of lab/ds.zarr is localised in its mapping pass <ID>_map):
      holodata slam lab/ds.zarr
      holodata slam lab/ds.zarr --scene c1 --map-scene c1_map --ply lab/c1.ply
      holodata slam lab/ds.zarr --scene c1 --truth lab/c1/truth --report lab/slam-report
    """
    from holodata.config_file import build
    from holodata.mapping.slam import SlamOutputs, slam_dataset

    if (ply or tum or truth) and len(scenes) > 1:
        raise click.UsageError("--ply/--tum/--truth need a single --scene")
    if report and not truth:
        raise click.UsageError("--report needs --truth")
    if map_scene is not None and not scenes:
        raise click.UsageError("--map-scene needs --scene (the scenes to localise against it)")
    # the dataclasses' defaults, then the --config file's sections slam and mesh, then the flags given (None:
    # not given; --no-refine / --global-pass / --no-mesh given are True)
    cfg = build("slam", config_file, dict(voxel=voxel, max_range=max_range, refine=False if no_refine else None,
                                          global_pass=global_pass, mesh=False if no_mesh else None))
    mcfg = build("mesh", config_file, dict(method=mesh_method, voxel=mesh_voxel))
    if map_scene is not None and (not cfg.refine or not cfg.mesh):
        raise click.UsageError("--map-scene localises by scan-to-map ICP against the map scene's mesh map: "
                               "no --no-refine / --no-mesh")
    results = slam_dataset(dataset, list(scenes) or None, config=cfg, mesh_config=mcfg, quiet=quiet,
                           outputs=SlamOutputs(force=force, tum=tum, ply=ply), single_exports=True, map_scene=map_scene)
    out = {"dataset": dataset, "scenes": [r.summary for r in results]}
    if truth:
        import holodata
        from holodata.evaluate.slam_accuracy import evaluate_slam
        from holodata.mapping.slam import MAPPING_ROLE

        r = results[0]
        role = holodata.open_dataset(dataset).scene(r.scene).attrs.get("role")
        out["accuracy"] = evaluate_slam(r.trajectory(), r.mesh, truth, out_dir=report,
                                        extra_trajectories={"kiss-icp": r.kiss_trajectory()},
                                        pass_="mapping" if role == MAPPING_ROLE else "data")
    if as_json:
        click.echo(json.dumps(out, default=str))
        return
    for s in out["scenes"]:
        m = s.get("mesh") or {}
        if s.get("skipped"):
            click.echo(f"{dataset}: scene {s['scene']}: {s['skipped']}", err=quiet)
            continue
        where = f" in mapping pass {s['map_scene']}'s map" if s.get("map_scene") else ""
        click.echo(f"{dataset}: scene {s['scene']}: {s['scans']} scans, {s['frames']} frames posed{where}, "
                   f"mesh {m.get('faces', 0)} faces ({s['timings'].get('total_s')} s)", err=quiet)
        if s.get("tf_agreement"):
            g = s["tf_agreement"]
            click.echo(f"  poses vs TF's over {g['scans']} scans: up to {g['position_max_m'] * 100:.1f} cm and "
                       f"{g['yaw_max_deg']:.2f} deg apart ({g['position_last_m'] * 100:.1f} cm at the last; "
                       f"TF odometry drifts, and so does slam far from its anchor)", err=quiet)
    if truth:
        a = out["accuracy"]
        t = a["trajectory"]
        line = f"ATE {t['ate_rmse_m'] * 100:.2f} cm, RPE {t['rpe_frame_rmse_m'] * 100:.2f} cm/frame"
        if "mesh" in a:
            m = a["mesh"]
            line += (f", mesh Chamfer {m['chamfer_m'] * 100:.2f} cm, F@2/5/10cm {m['f_2cm']:.3f}/{m['f_5cm']:.3f}/"
                     f"{m['f_10cm']:.3f}")
        click.echo(line)
        if "coverage" in a:
            c = a["coverage"]
            by = "/".join(f"{v:.3f}" for _, v in sorted(c["coverage_bounce"].items()))
            click.echo(f"mesh coverage of the true surface within radar reach (tau {c['tau_m'] * 100:.0f} cm, "
                       f"{c['grid'][0]}x{c['grid'][1]} beams, {c['max_bounces']} bounces): {c['coverage']:.3f} "
                       f"(bounce 1/2/3 {by}; NLOS points {c.get('coverage_nlos', float('nan')):.3f}); GT NLOS points per "
                       f"frame: {c['nlos_per_frame_est']:.0f} through the "
                       f"SLAM mesh, {c['nlos_per_frame_true']:.0f} through the true mesh "
                       f"(ratio {c['nlos_ratio']:.2f})")


COMMANDS = [slam]
