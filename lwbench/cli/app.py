"""The ``lwbench`` application: the one error boundary, global options and plugin commands.

**One error boundary.** Every :class:`~lwbench.errors.LwbenchError` that leaves a command -- a
built-in one or a plugin's, raised while parsing, planning or running -- is printed as one line
(``error: ...``) and the process exits with status 2 (:class:`LwbenchGroup.main`); commands just
raise. click's usage errors (an unknown option, ``--frames 0``, a missing argument) get the same
one line, naming the command's ``--help``, instead of typer's five-line box. Anything else is a
bug and keeps its traceback.

**Plugin commands load lazily.** A plugin's ``lwbench_register_commands`` hook is called only when
the command line names a command lwbench does not have, or when help lists every command -- not
when ``lwbench run`` or ``lwbench list`` starts (plugins are then imported once, by the registry,
if the command needs them). A plugin whose hook raises is reported like any plugin that fails to
load, and the other commands keep working.
"""

from __future__ import annotations

import sys
from typing import Annotated

import typer
from typer.core import TyperGroup

from lwbench.errors import LwbenchError

from .output import err_console, print_error

__all__ = ["LwbenchGroup", "PLUGIN_PANEL", "app", "main", "registry"]

PLUGIN_PANEL = "Plugin commands"


class LwbenchGroup(TyperGroup):
    """The root command: the error boundary and the lazy plugin commands (see the module doc)."""

    _plugins_loaded = False

    def main(self, *args, standalone_mode: bool = True, **kwargs):
        try:
            # Not standalone: click's exceptions come here, where they become one line.
            rv = super().main(*args, standalone_mode=False, **kwargs)
        except LwbenchError as exc:
            print_error(str(exc))
            sys.exit(2)
        except typer.TyperException as exc:  # click's errors (typer vendors click: this is their base)
            if not standalone_mode:
                raise
            if type(exc).__name__ != "NoArgsIsHelpError":  # `lwbench` alone: typer has printed the help
                print_error(usage_line(exc))
            sys.exit(exc.exit_code)
        except typer.Abort:
            if not standalone_mode:
                raise
            err_console.print("Aborted.")
            sys.exit(1)
        if not standalone_mode:
            return rv
        # Not standalone, click returns typer.Exit's code instead of exiting with it.
        sys.exit(rv if isinstance(rv, int) else 0)

    def get_command(self, ctx, cmd_name: str):
        command = super().get_command(ctx, cmd_name)
        if command is None and not self._plugins_loaded:
            self.load_plugin_commands()
            command = super().get_command(ctx, cmd_name)
        if command is not None:
            _unset_help_is_false(command, ctx)
        return command

    def get_help_option(self, ctx):
        option = super().get_help_option(ctx)
        if option is not None and option.default is None:
            option.default = False
        return option

    def list_commands(self, ctx) -> list[str]:
        self.load_plugin_commands()
        return super().list_commands(ctx)

    def load_plugin_commands(self) -> None:
        """Every installed plugin's commands (hook ``lwbench_register_commands``), added once."""
        if self._plugins_loaded:
            return
        self._plugins_loaded = True
        from lwbench.registry import get_registry

        reg = get_registry()
        extra = typer.Typer(add_completion=False)
        for impl in reg.pm.hook.lwbench_register_commands.get_hookimpls():
            try:
                impl.function(cli=extra)
            except Exception as exc:  # noqa: BLE001 - one plugin's bug must not take the CLI down
                reg.record_failure(impl.plugin_name, "lwbench_register_commands", exc)
        if not (extra.registered_commands or extra.registered_groups):
            return
        group = typer.main.get_group(extra)
        for name, command in group.commands.items():
            if name in self.commands:
                reg.record_failure(name, "lwbench_register_commands",
                                   LwbenchError(f"a plugin command may not replace lwbench's own {name!r}"))
                continue
            if not isinstance(getattr(command, "rich_help_panel", None), str):  # None or typer's default marker
                command.rich_help_panel = PLUGIN_PANEL
            self.add_command(command, name)


def usage_line(exc: typer.TyperException) -> str:
    """One line for a click error: what is wrong and, for a usage error, where the help is."""
    message = " ".join(exc.format_message().split())
    ctx = getattr(exc, "ctx", None)
    if ctx is not None:
        return f"{ctx.command_path}: {message} (see {ctx.command_path} --help)"
    return message


def _unset_help_is_false(command, ctx) -> None:
    """``--help`` not given reads as ``False``, not ``None``: typer then skips building a pydantic
    validator for it (and importing pydantic, ~0.1 s of every command's start; measured with
    ``python -X importtime``)."""
    option = command.get_help_option(ctx)
    if option is not None and option.default is None:
        option.default = False


app = typer.Typer(
    cls=LwbenchGroup,
    add_completion=False,
    no_args_is_help=True,
    help="lwbench: benchmark LiDAR point-cloud reduction codecs on one leaderboard.",
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)

_state = {"strict": False}


def registry():
    """The installed plugins; a plugin that failed to load is a warning (``--strict``: an error)."""
    from lwbench.registry import get_registry

    reg = get_registry()
    if _state["strict"]:
        reg.raise_failures()
    elif reg.failures:
        names = ", ".join(f.plugin for f in reg.failures)
        err_console.print(
            f"[yellow]warning:[/] plugin(s) failed to load and were skipped: {names} "
            "(`lwbench list` shows why; --strict makes this fatal)", highlight=False,
        )
    return reg


def _version(value: bool) -> None:
    if value:
        from lwbench.version import __version__

        print(f"lwbench {__version__}")
        raise typer.Exit()


@app.callback()
def _global_options(
    strict: Annotated[bool, typer.Option("--strict", help="Fail if any plugin fails to load (for CI).")] = False,
    version: Annotated[bool, typer.Option(
        "--version", callback=_version, is_eager=True, help="Print the version and exit.")] = False,
) -> None:
    _state["strict"] = strict


def main() -> None:
    """The ``lwbench`` executable (console script ``lwbench = "lwbench.cli:main"``)."""
    app()
