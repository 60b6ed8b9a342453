"""``holodata register``: camera extrinsic in the SLAM map + per-frame human points and closed human
surfaces (human/vertices + human/faces, read by ``holodata raytrace-gt``); also the LiDAR-grid human
segmentation (lidar/instance)."""
from __future__ import annotations

import json

import click

from holodata.cli.options import config_file_option, config_option, force_option, json_option, quiet_option


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
@click.option("--scene", "scenes", multiple=True,
              help="Scene id (repeatable; default: every scene with a camera, i.e. not a LiDAR-only mapping pass).")
@click.option("--init", "init", default=None, metavar="X,Y,Z,ROLL,PITCH,YAW",
              help="Initial guess of T_world_camera (camera points frame, metres and degrees, extrinsic xyz Euler); "
                   "default: the camera's TF pose in the map.")
@click.option("--no-segment", is_flag=True, default=None, help="Skip the LiDAR-grid human segmentation (lidar/instance).")
@config_option("--camera-world/--no-camera-world", section="register", field="write_camera_world",
               shown=lambda v: "camera-world" if v else "no-camera-world",
               help="Also write camera/points_world: the whole camera cloud in the map frame, as large as camera/points "
                    "(holodata.mapping.register.camera_points_world gives it from calib/T_world_camera without the copy).")
@click.option("--truth", type=click.Path(file_okay=False, exists=True),
              help="A holodata synth truth/ folder: print extrinsic, human centroid and segmentation errors against it.")
@click.option("--report", type=click.Path(file_okay=False), help="With --truth: folder for register_accuracy.json and a PNG.")
@config_option("--processes", section="register", field="processes", type=click.IntRange(min=0),
               help="Processes (0: two on a machine with two or more CPUs; 1: all in this process).")
@config_option("--guess-std", "guess_std", section="register", field="guess_std_m", shown=lambda m: f"{m * 100:g}",
               type=click.FloatRange(min=0.0), metavar="CM",
               help="How good the guess (TF pose or --init) is along directions the camera's view does not constrain: "
                    "the result there is the guess, reported and accepted with this uncertainty (the measured "
                    "directions must be within 2 cm).")
@config_file_option("sections register, segment, ...")
@force_option()
@quiet_option()
@json_option()
@click.pass_context
def register(ctx, dataset, scenes, init, no_segment, camera_world, truth, report, processes, guess_std, config_file, force,
             quiet, as_json) -> None:
    """Register the depth camera to the LiDAR map (needs pose/T_world_lidar from `holodata slam`):
    point-to-plane ICP of the camera's static cloud onto the map from the TF guess or --init,
    FPFH+RANSAC fallback accepted only if it passes the fitness/RMSE check; then the human in every
    frame (points + a closed surface, world frame) and the LiDAR-grid human instance masks.

    A camera that cannot be registered costs its scene the person, not the scene: the scene keeps
    its mesh and poses (raytrace-gt traces it without a person), its attribute register_failed holds
    the numbers (--json prints them), and the command exits 1 with one line per such scene. --json
    prints one scene's summary, or {"dataset", "scenes": [...]} for several.

    \b
    Examples (every scene of lab/ds.zarr with a camera, i.e. each data pass, not its mapping pass):
      holodata register lab/ds.zarr
      holodata register lab/ds.zarr --scene c1 --truth lab/c1/truth --report lab/register-report
      holodata register lab/ds.zarr --scene c2 --json
    """
    from holodata import open_dataset
    from holodata.config_file import build, read
    from holodata.mapping.register import RegistrationError, camera_scenes, register_scene

    if report and not truth:
        raise click.UsageError("--report needs --truth")
    init = _init(init)
    # RegisterConfig's defaults, then the --config file's section register, then the flags given (None: not
    # given; --no-segment given is True)
    cfg = build("register", config_file, dict(segment_lidar=False if no_segment else None,
                                              write_camera_world=camera_world, processes=processes,
                                              guess_std_m=None if guess_std is None else guess_std / 100.0))
    seg = build("segment", config_file) if config_file and "segment" in read(config_file) else None
    seg = None if seg is None or seg == type(seg)() else seg     # the defaults: the same fingerprint as without a file
    ids = list(dict.fromkeys(scenes))
    if not ids:
        ds = open_dataset(dataset)
        ids = camera_scenes(ds)
        if not ids:     # (register_scene says so in one line)
            ids = [None]
        elif len(ids) < len(ds.scenes):
            rest = [s for s in ds.scenes if s not in ids]
            click.echo(f"{dataset}: registering the scene(s) with a camera: {', '.join(ids)} ({', '.join(rest)}: no "
                       f"camera)", err=True)
    if (truth or init is not None) and len(ids) > 1:
        raise click.UsageError(f"--truth/--init belong to one scene: give --scene (scenes with a camera: {', '.join(ids)})")
    results, failed = [], []
    for sid in ids:
        try:
            res = register_scene(dataset, sid, init=init, cfg=cfg, quiet=quiet, force=force, segment_cfg=seg)
        except RegistrationError as err:
            if len(ids) == 1 and not as_json:
                raise                       # one line on stderr, exit 1
            failed.append(str(err))
            results.append(err.report or {"scene": sid, "registered": False})
            continue
        if truth:
            from holodata.evaluate.register_accuracy import evaluate_register

            res["accuracy"] = evaluate_register(dataset, res["scene"], truth, report)
        results.append(res)
        if not as_json:
            _echo(dataset, res, cfg, truth, quiet)
    if as_json:
        click.echo(json.dumps(results[0] if len(results) == 1 else {"dataset": dataset, "scenes": results},
                              indent=2, default=str))
    for line in failed:
        click.echo(f"error: {' '.join(line.split())}", err=True)
    if failed:
        ctx.exit(1)


def _echo(dataset: str, res: dict, cfg, truth, quiet: bool) -> None:
    """The lines of one registered scene ``res`` (register_scene's summary)."""
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
               f"{', camera/points_world' if cfg.write_camera_world else ''}; {res['seconds']:.1f} s")
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
