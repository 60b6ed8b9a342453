"""Which optional dependencies each task needs, and the one line that says so.

``pip install holodata`` is the dataset core: the format, ``holodata validate``, ``holodata info`` and
the reader API (``holodata.open_dataset(...)[scene][array]``) need only :data:`CORE`. Every stage's
dependencies come with an extra named for the user's task (docs/install.md). :data:`EXTRAS` is the
single source: ``[project.optional-dependencies]`` in pyproject.toml lists the same requirements
(``all`` is their union; ``dev`` holds the test tools and is not a task), and
tests/project/test_light_install.py checks that the two agree.

The CLI checks a command's extras before it starts (:func:`check_command`: no half-done work, one line,
exit 1) and maps a missing module met later to its extra (:func:`missing_extra_line`). Library code
calls :func:`require`. Nothing here imports a third-party package: :func:`installed` only looks the
module up.
"""
from __future__ import annotations

import importlib.util

from .errors import HolodataError

# the packages of the core, as imported (the requirements are pyproject.toml's [project] dependencies;
# pyyaml comes with zarr anyway, through its config library donfig, and the stages read YAML with it)
CORE: tuple[str, ...] = ("numpy", "zarr", "numcodecs", "fsspec", "jsonschema", "click", "rich", "yaml")

# extra -> {requirement, exactly as pyproject.toml writes it: the top-level module it is imported as}
EXTRAS: dict[str, dict[str, str]] = {
    # read datasets on S3 (s3://bucket/dataset.zarr): validate, info, the reader, any stage's --out
    "s3": {"s3fs>=2024.1": "s3fs"},
    # --workers N / --scheduler ADDRESS of synth, ingest, beamform and raytrace-gt
    "dask": {"dask[distributed]>=2024.8": "distributed"},
    # holodata ingest / beamform: ROS 1, ROS 2 (sqlite3, MCAP), HDF5, image recordings; raw radar beamforming
    "ingest": {
        "rosbags>=0.10": "rosbags",
        "mcap>=1.2": "mcap",
        "blake3>=1.0": "blake3",            # the recording's digest (source.blake3)
        "h5py>=3.8": "h5py",
        "opencv-python-headless>=4.8": "cv2",
        "scipy>=1.11": "scipy",
        "numba>=0.60": "numba",
    },
    # holodata synth: synthetic recordings of corners with their hidden truth (ray-traced sensors)
    "synth": {
        "rosbags>=0.10": "rosbags",
        "scipy>=1.11": "scipy",
        "numba>=0.60": "numba",
        "open3d>=0.19": "open3d",
        "embreex>=4.3": "embreex",
        "trimesh>=5.2,<6": "trimesh",     # meshio reads PLY and STL with it; metadata["_ply_raw"] layout as of 5.x
    },
    # holodata slam / register: LiDAR SLAM, the scene mesh, camera extrinsic, human surfaces
    "mapping": {
        "open3d>=0.19": "open3d",
        "kiss-icp==1.3.0": "kiss_icp",
        "evo>=1.28": "evo",
        "scipy>=1.11": "scipy",
        "numba>=0.60": "numba",
        "embreex>=4.3": "embreex",
        "trimesh>=5.2,<6": "trimesh",
        "matplotlib>=3.8": "matplotlib",
        "rosbags>=0.10": "rosbags",        # the recording's TF, read back for a LiDAR-only scene
        "mcap>=1.2": "mcap",
    },
    # holodata raytrace-gt: multi-bounce ground truth per radar beam
    "gt": {
        "open3d>=0.19": "open3d",          # the default ray-casting backend
        "embreex>=4.3": "embreex",
        "numba>=0.60": "numba",
        "scipy>=1.11": "scipy",
        "trimesh>=5.2,<6": "trimesh",
    },
    # holodata train / evaluate, holodata.torch: the CPU wheel (scripts/setup.sh); pinned exactly
    "train": {
        "torch==2.13.0": "torch",
        "scipy>=1.11": "scipy",
        "numba>=0.60": "numba",
        "matplotlib>=3.8": "matplotlib",
    },
    # holodata view: a scene in Rerun (--checkpoint / --report need 'train' too)
    "view": {
        "rerun-sdk>=0.41,<0.42": "rerun",
        "scipy>=1.11": "scipy",
    },
    # holodata export --format hdf5
    "export": {"h5py>=3.8": "h5py"},
}
ALL = "all"     # pyproject.toml: every requirement of EXTRAS (scripts/setup.sh installs it)

# command -> the extras it cannot start without (checked before it runs)
COMMAND_EXTRAS: dict[str, tuple[str, ...]] = {
    "demo": ("synth", "ingest", "mapping", "gt", "train"),
    "synth": ("synth",),
    "ingest": ("ingest",),
    "beamform": ("ingest",),
    "slam": ("mapping",),
    "register": ("mapping",),
    "raytrace-gt": ("gt",),
    "train": ("train",),
    "evaluate": ("train",),
    "view": ("view",),
}
# (command, option) -> (the value that needs it, None for any value given; the extra)
OPTION_EXTRAS: dict[tuple[str, str], tuple[str | None, str]] = {
    ("view", "checkpoint"): (None, "train"),
    ("view", "report"): (None, "train"),
    ("export", "fmt"): ("hdf5", "export"),
}
# fsspec protocol of a dataset URL -> the extra that reads it
URL_EXTRAS: dict[str, str] = {"s3": "s3", "s3a": "s3"}
# options that start a Dask cluster (holodata.cli.options.dask_options: a command with --scheduler)
DASK_OPTIONS = ("workers", "scheduler")


class MissingExtraError(HolodataError, ImportError):
    """An optional dependency of the task is not installed; the message names the extra to install."""


def all_requirements() -> list[str]:
    """The ``all`` extra: every requirement of :data:`EXTRAS`, once, in table order."""
    return list(dict.fromkeys(r for reqs in EXTRAS.values() for r in reqs))


def installed(module: str) -> bool:
    """Whether the top-level ``module`` can be imported (looked up, not imported)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):     # a broken install, a module set to None in sys.modules
        return False


def missing(extra: str) -> list[str]:
    """The modules of ``extra`` that are not installed."""
    return [m for m in dict.fromkeys(EXTRAS[extra].values()) if not installed(m)]


def install_line(what: str, extras: list[str], modules: list[str]) -> str:
    """``<what> needs the 'x' extra (m is not installed): pip install 'holodata[x]'``."""
    quoted = [f"'{e}'" for e in extras]
    names = quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " and " + quoted[-1]
    mods = ", ".join(modules[:3]) + (f" and {len(modules) - 3} more" if len(modules) > 3 else "")
    verb = "is" if len(modules) == 1 else "are"
    return (f"{what} needs the {names} extra{'s' if len(extras) > 1 else ''} ({mods} {verb} not installed): "
            f"pip install 'holodata[{','.join(extras)}]'")


def require(extra: str | tuple[str, ...] | list[str], what: str) -> None:
    """Raise :class:`MissingExtraError` naming the extra(s) when a module of ``extra`` is missing;
    ``what`` is who needs it ("holodata slam", "holodata.torch")."""
    extras = [extra] if isinstance(extra, str) else list(extra)
    gone = {e: missing(e) for e in extras}
    lacking = [e for e in extras if gone[e]]
    if lacking:
        modules = list(dict.fromkeys(m for e in lacking for m in gone[e]))
        raise MissingExtraError(install_line(what, lacking, modules))


def _url_extras(value) -> list[str]:
    values = value if isinstance(value, (list, tuple)) else [value]
    out = []
    for v in values:
        s = str(v)
        proto = s.split("://", 1)[0].lower() if "://" in s else ""
        if proto in URL_EXTRAS:
            out.append(URL_EXTRAS[proto])
    return out


def command_extras(command: str, params: dict) -> list[str]:
    """The extras ``holodata <command>`` needs with these parsed parameters: its own
    (:data:`COMMAND_EXTRAS`), its options' (:data:`OPTION_EXTRAS`), ``s3`` for an s3:// argument,
    ``dask`` for --workers N / --scheduler."""
    extras = list(COMMAND_EXTRAS.get(command, ()))
    for (cmd, option), (value, extra) in OPTION_EXTRAS.items():
        if cmd == command and params.get(option) and (value is None or params[option] == value):
            extras.append(extra)
    for v in params.values():
        extras += _url_extras(v)
    if "scheduler" in params and any(params.get(o) for o in DASK_OPTIONS):   # dask_options' pair, not
        extras.append("dask")                                                  # train's DataLoader --workers
    return list(dict.fromkeys(extras))


def check_command(command: str, params: dict) -> None:
    """Before ``holodata <command>`` runs: :class:`MissingExtraError` when an extra it needs is missing."""
    require(command_extras(command, params), f"holodata {command}")


def extra_of(module: str, prefer: tuple[str, ...] | list[str] = ()) -> str | None:
    """The extra that installs the top-level ``module``: one of ``prefer`` that has it, else the
    smallest extra that has it; None for a module no extra installs."""
    top = module.split(".")[0]
    have = [e for e, reqs in EXTRAS.items() if top in reqs.values()]
    for e in prefer:
        if e in have:
            return e
    return min(have, key=lambda e: len(EXTRAS[e]), default=None)


def missing_module(err: BaseException) -> str | None:
    """The top-level module of the first ``ModuleNotFoundError`` in ``err``'s chain (its cause,
    context, ...) that an extra installs, or None."""
    seen = set()
    e: BaseException | None = err
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, ModuleNotFoundError) and e.name:
            top = e.name.split(".")[0]
            if extra_of(top) is not None and not installed(top):   # not: a submodule an old version lacks
                return top
        e = e.__cause__ or e.__context__
    return None


def missing_extra_line(err: BaseException, command: str | None) -> str | None:
    """The one line for an error caused by a module an extra installs (None otherwise), e.g.
    ``holodata slam needs the 'mapping' extra (open3d is not installed): pip install 'holodata[mapping]'``."""
    if isinstance(err, MissingExtraError):
        return str(err)
    module = missing_module(err)
    extra = extra_of(module, COMMAND_EXTRAS.get(command or "", ())) if module else None
    if module is None or extra is None:
        return None
    return install_line(f"holodata {command}" if command else "holodata", [extra], [module])


__all__ = ["CORE", "EXTRAS", "ALL", "COMMAND_EXTRAS", "OPTION_EXTRAS", "URL_EXTRAS", "MissingExtraError", "all_requirements",
           "installed", "missing", "require", "check_command", "command_extras", "extra_of", "missing_extra_line"]
