"""Click options shared by several commands (one definition, the same wording everywhere)."""
from __future__ import annotations

import click


def dask_options(task: str, shared: str):
    """``--workers N`` / ``--scheduler ADDRESS`` for commands that can run ``task`` (e.g. "one task
    per shard") on a Dask cluster; ``shared`` says what the workers must be able to reach."""

    def decorate(fn):
        fn = click.option("--scheduler", metavar="ADDRESS",
                          help=f"Run {task} on an existing Dask cluster (tcp://host:8786 or a scheduler file); "
                               f"{shared}")(fn)
        return click.option("--workers", default=0, show_default=True, type=click.IntRange(0),
                            help=f"Run {task} on a local Dask cluster of N worker processes (0 = no Dask).")(fn)

    return decorate


def quiet_option(help: str = "No progress bar."):
    """``--quiet`` (parameter ``quiet``); ``help`` where a command's --quiet silences more."""
    return click.option("--quiet", is_flag=True, help=help)


def json_option(help: str = "Print a JSON summary on stdout."):
    """``--json`` (parameter ``as_json``); ``help`` where a command prints something else than a summary."""
    return click.option("--json", "as_json", is_flag=True, help=help)


def config_file_option(sections: str):
    """``--config FILE`` (parameter ``config_file``): the YAML/JSON file of stage settings whose
    ``sections`` (e.g. "section gt", "sections slam, mesh, ...") the command reads; flags given win."""
    return click.option("--config", "config_file", type=click.Path(exists=True, dir_okay=False), default=None,
                        help=f"YAML/JSON file of stage settings ({sections}; examples/holodata.yaml); flags given here win.")


def force_option(help: str = "Recompute a scene already done with the same inputs and settings."):
    """``--force`` (parameter ``force``); ``help`` where a command's --force does more."""
    return click.option("--force", is_flag=True, help=help)


class ConfigOption(click.Option):
    """An option that sets field ``field`` of a stage's config dataclass (``section`` of
    :data:`holodata.config_file.SECTIONS`). Its default is None, "not given": the ``--config`` file's
    value stands, else the dataclass's (only a flag given overrides them). ``--help`` shows the
    dataclass's default, read when the help is shown (``shown`` formats it; None shows nothing), so
    the number is written once, in the dataclass; the stage's module is imported only then."""

    def __init__(self, *decls, section: str, field: str, shown=str, **attrs):
        self.config_field = (section, field)
        self._shown = shown
        super().__init__(*decls, default=None, **attrs)

    @property
    def show_default(self):
        section, name = self.config_field
        try:
            from holodata.config_file import config_class

            value = getattr(config_class(section)(), name)
        except ImportError:     # a core install's --help: the stage's extra is not installed
            return None
        return self._shown(value)

    @show_default.setter
    def show_default(self, _value) -> None:   # click.Option's __init__ sets it: the dataclass says it instead
        pass

    def get_help_extra(self, ctx):   # (click >= 8.2) "[default: 0.15]", not the "(0.15)" of a text default
        extra = super().get_help_extra(ctx)
        d = extra.get("default")
        if isinstance(d, str) and d.startswith("(") and d.endswith(")"):
            extra["default"] = d[1:-1]
        return extra


def config_option(*decls, section: str, field: str, shown=str, **attrs):
    """``click.option(*decls, **attrs)`` as a :class:`ConfigOption` of ``section``'s ``field``."""
    return click.option(*decls, cls=ConfigOption, section=section, field=field, shown=shown, **attrs)
