"""``holodata register``: camera extrinsic in the SLAM map + per-frame human points and closed human
surfaces (human/vertices + human/faces, read by ``holodata raytrace-gt``); also the LiDAR-grid human
segmentation (lidar/instance)."""
from __future__ import annotations

import json

import click


def _init(value: str | None):
    if value is None:
        return None
    try:
        vals = [float(v) for v in value.split(",")]
    except ValueError as err:
        raise click.BadParameter(f"must be x,y,z,roll,pitch,yaw (m, degrees), got {value!r}", param_hint="--init") from err
    if len(vals) != 6:
        raise click.BadParameter(f"must be 6 numbers x,y,z,roll,pitch,yaw (m, degrees), got {len(vals)}", param_hint="--init")
    return vals


@click.command("register")
@click.argument("dataset")
@click.option("--scene", "scene", default=None, help="Scene id (default: the only scene).")
@click.option("--init", "init", default=None, metavar="X,Y,Z,ROLL,PITCH,YAW",
              help="Initial guess of T_world_camera (camera points frame, metres and degrees, extrinsic xyz Euler); "
                   "default: the camera's TF pose in the map.")
@click.option("--no-segment", is_flag=True, help="Skip the LiDAR-grid human segmentation (lidar/instance).")
@click.option("--camera-world/--no-camera-world", default=False, show_default=True,
              help="Also write camera/points_world: the whole camera cloud in the map frame, as large as camera/points "
                   "(holodata.mapping.register.camera_points_world gives it from calib/T_world_camera without the copy).")
@click.option("--truth", type=click.Path(file_okay=False, exists=True),
              help="A holodata synth truth/ folder: print extrinsic, human centroid and segmentation errors against it.")
@click.option("--report", type=click.Path(file_okay=False), help="With --truth: folder for register_accuracy.json and a PNG.")
@click.option("--processes", type=click.IntRange(min=0), default=0, show_default=True,
              help="Processes (0: two on a machine with two or more CPUs; 1: all in this process).")
@click.option("--guess-std", "guess_std", type=click.FloatRange(min=0.0), default=5.0, show_default=True, metavar="CM",
              help="How good the guess (TF pose or --init) is along directions the camera's view does not constrain: "
                   "the result there is the guess, with this uncertainty; accepted only if <= 2 cm.")
@click.option("--config", "config_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML/JSON file of stage settings (sections register, segment, ...; examples/holodata.yaml); flags "
                   "given here win.")
@click.option("--force", is_flag=True, help="Recompute a scene already done with the same inputs and settings.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def register(ctx, dataset, scene, init, no_segment, camera_world, truth, report, processes, guess_std, config_file, force,
             quiet, as_json) -> None:
    """Register the depth camera to the LiDAR map (needs pose/T_world_lidar from `holodata slam`):
    point-to-plane ICP of the camera's static cloud onto the map from the TF guess or --init,
    FPFH+RANSAC fallback accepted only if it passes the fitness/RMSE check; then the human in every
    frame (points + a closed surface, world frame) and the LiDAR-grid human instance masks.

    \b
    Example:
      holodata register data.zarr --scene corner_03
      holodata register data.zarr --init 0.7,-8.1,1.2,-95,0,-9.5 --json
      holodata register data.zarr --truth synth_T/truth --report register_report/
    """
    from holodata.config_file import build, explicit_flags, read
    from holodata.mapping.register import register_scene

    if report and not truth:
        raise click.UsageError("--report needs --truth")
    flags = {"segment_lidar": "no_segment", "write_camera_world": "camera_world", "processes": "processes",
             "guess_std_m": "guess_std"}
    cfg = build("register", config_file, dict(segment_lidar=not no_segment, write_camera_world=camera_world,
                                              processes=processes, guess_std_m=guess_std / 100.0),
                explicit_flags(ctx, flags))
    seg = build("segment", config_file) if config_file and "segment" in read(config_file) else None
    seg = None if seg is None or seg == type(seg)() else seg     # the defaults: the same fingerprint as without a file
    res = register_scene(dataset, scene, init=_init(init), cfg=cfg, quiet=quiet, force=force, segment_cfg=seg)
    if truth:
        from holodata.mapping.human_eval import evaluate_register

        res["accuracy"] = evaluate_register(dataset, res["scene"], truth, report)
    if as_json:
        click.echo(json.dumps(res, indent=2, default=str))
        return
    if res.get("skipped"):
        click.echo(f"{dataset}: scene {res['scene']}: {res['skipped']}", err=quiet)
    e = res["extrinsic"]
    chosen = next((a for a in e.get("attempts") or [] if a.get("method") == e["method"]), {})
    held = chosen.get("held_directions") or []
    click.echo(f"scene {res['scene']}: extrinsic by {e['method']} (init {res['init']}): fitness {e['fitness']:.2f}, "
               f"rmse {e['rmse_m'] * 100:.1f} cm over {e['overlap_points']} overlap points"
               + (f", pose std {chosen['pose_std_m'] * 100:.1f} cm" if "pose_std_m" in chosen else "")
               + (f"; held at the guess (+-{cfg.guess_std_m * 100:.1f} cm, not measured): {', '.join(held)}"
                  if held else ""))
    click.echo(f"human in {res['frames_with_human']}/{res['frames']} frames -> human/vertices, human/faces, human/points"
               f"{', camera/points_world' if camera_world else ''}; {res['seconds']:.1f} s")
    if truth:
        a = res["accuracy"]
        e, ea, c = a["extrinsic"], a["extrinsic_aligned"], a["human_centroid"]
        line = (f"extrinsic {e['trans_cm']:.2f} cm {e['rot_deg']:.2f} deg (trajectory-aligned {ea['trans_cm']:.2f} cm "
                f"{ea['rot_deg']:.2f} deg); human centroid mean/median/max {c['mean_cm']:.1f}/{c['median_cm']:.1f}/"
                f"{c['max_cm']:.1f} cm in {c['frames']} frames ({c['missing']} without a human)")
        if "segmentation" in a:
            line += f"; LiDAR segmentation AP50 {a['segmentation']['ap']:.3f}"
        click.echo(line)


COMMANDS = [register]
