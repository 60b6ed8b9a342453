"""The ``holodata`` click group.

Each command lives in its own module under ``holodata/cli/`` and is listed in ``COMMAND_MODULES``;
heavy imports happen inside command bodies so ``holodata --help`` stays fast.
Errors: :class:`holodata.errors.HolodataError` (and any other exception) becomes one line on
stderr and exit code 1; ``--debug`` shows the traceback instead. Usage errors exit 2. A command whose
extra is not installed (``pip install holodata`` is the dataset core) says which one in one line, exit 1:
checked before it starts (:data:`holodata.extras.COMMAND_EXTRAS`, s3:// arguments, --workers/--scheduler),
and a missing module of an extra met later is named by its extra (:func:`holodata.extras.missing_extra_line`).
"""
from __future__ import annotations

import contextlib
import functools
import importlib
import signal
import sys

import click

# module name under holodata.cli -> attribute holding the click command(s)
COMMAND_MODULES: list[str] = [
    "demo",
    "info",
    "ingest",
    "beamform",
    "raytrace",
    "slam",
    "synth",
    "train",
    "evaluate",
    "register",
    "export",
    "view",
    "split",
]


class HolodataGroup(click.Group):
    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        """``--debug`` anywhere (``holodata info X --debug`` too) is the group's flag."""
        if "--debug" in args:
            cut = args.index("--") if "--" in args else len(args)
            args = ["--debug"] + [a for a in args[:cut] if a != "--debug"] + args[cut:]
        return super().parse_args(ctx, args)

    def invoke(self, ctx: click.Context):
        try:
            return self._invoke(ctx)
        finally:
            close_filesystems()

    def _invoke(self, ctx: click.Context):
        try:
            result = super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except KeyboardInterrupt:
            click.echo("interrupted", err=True)
            sys.exit(130)
        except Exception as err:  # noqa: BLE001 - the CLI's single error boundary
            if ctx.obj and ctx.obj.get("debug"):
                raise
            from holodata.extras import missing_extra_line

            # a module of an extra that is not installed: which extra to install, not the module's traceback
            line = missing_extra_line(err, ctx.invoked_subcommand)
            click.echo(f"error: {line or one_line(err)}", err=True)
            sys.exit(1)
        # the command's work is done (and committed): a Ctrl-C during interpreter shutdown would
        # only turn exit 0 into "killed by SIGINT" over a finished result
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        return result


def close_filesystems() -> None:
    """Close the object-store HTTP sessions the command opened (s3fs's, in this process) before the
    interpreter shuts down, which would otherwise leave aiohttp to print "Unclosed client session" on
    stderr after the result (:func:`holodata.dataset.store.close_filesystems`)."""
    if "s3fs" not in sys.modules:     # no object store was used
        return
    from holodata.dataset.store import close_filesystems as close

    with contextlib.suppress(Exception):   # any failure: the command's result and exit code stand
        close()


def one_line(err: BaseException) -> str:
    from holodata.errors import HolodataError

    msg = " ".join(str(err).split()) or err.__class__.__name__
    if not isinstance(err, HolodataError):
        msg = f"{err.__class__.__name__}: {msg} (run with --debug for a traceback)"
    return msg


@click.group(cls=HolodataGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, help="Show full tracebacks on errors.")
@click.version_option(package_name="holodata")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """holodata: multi-bounce radar ground truth datasets.

    Synthesise or ingest recordings, build the scene mesh, ray-trace per-beam multi-bounce
    ground truth into sharded Zarr datasets, validate them, train and evaluate models.
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


def needs_extras(name: str, callback):
    """``callback`` (a command's body) that first checks the extras ``holodata <name>`` needs with its
    parsed options (:func:`holodata.extras.check_command`): a missing one is one line and exit 1 before
    any work, while ``--help`` and usage errors never get here."""

    @functools.wraps(callback)
    def run(*args, **kwargs):
        from holodata.extras import check_command

        check_command(name, kwargs)
        return callback(*args, **kwargs)

    run.holodata_checks_extras = True
    return run


for _name in COMMAND_MODULES:
    _mod = importlib.import_module(f"holodata.cli.{_name}")
    for _cmd in _mod.COMMANDS:
        if _cmd.callback is not None and not getattr(_cmd.callback, "holodata_checks_extras", False):
            _cmd.callback = needs_extras(_cmd.name, _cmd.callback)
        cli.add_command(_cmd)


def main() -> None:
    from holodata.parallel import keep_freed_memory

    keep_freed_memory()
    cli(obj={})


if __name__ == "__main__":
    main()
