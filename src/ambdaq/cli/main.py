"""The ``ambdaq`` command group, its registry of commands and its error handling.

Commands are found through :data:`COMMANDS` and imported only when they run, so ``ambdaq --help``
and ``ambdaq --version`` load no numerical library: the listing takes each command's summary from
its docstring by reading the module's source, not by importing it.

Exit codes: 0 success, 1 runtime failure (device, I/O), 2 bad usage or bad input.  Errors are one
line on stderr; ``--debug`` (or ``AMBDAQ_DEBUG=1``) shows the traceback instead.
"""

from __future__ import annotations

import ast
import difflib
import os
import sys
from pathlib import Path

import click

from ..loading import load_object
from .. import __version__, python_can_import
from ..errors import AmbdaqError, AmbdaqWarning

# a process the command line runs never uses python-can's MF4 logger: python-can comes without the
# asammdf it imports for it (1.5 s of a served rig's start here); a notebook that imports ambdaq
# keeps python-can whole
python_can_import.install()


COMMANDS = {
    # name: "module:attribute" in ambdaq.cli; a new command is one module and one line here
    "apht": "apht:command",
    "balance": "balance:command",
    "controller": "push:controller_group",
    "devices": "devices:command",
    "export": "export:command",
    "fleet": "fleet:command",
    "frf": "frf:command",
    "fx": "fx:command",
    "identify": "identify:command",
    "iso": "iso:command",
    "info": "info:command",
    "lms": "lms:command",
    "model": "model:command",
    "plant": "plant:command",
    "plot": "plot:command",
    "push": "push:push_command",
    "record": "record:command",
    "report": "report:command",
    "recover": "recover:command",
    "runout": "runout:command",
    "runup": "runup:command",
    "selfsense": "selfsense:command",
    "sim": "sim:command",
    "xcp": "xcp:command",
}


def _summary(target: str) -> str:
    """The first paragraph of a command's docstring (what click makes its short help from), read
    from its module's source without importing it."""
    module, attr = target.split(":")
    source = (Path(__file__).parent / f"{module}.py").read_text()
    for node in ast.parse(source).body:
        if isinstance(node, ast.FunctionDef) and node.name == attr:
            return " ".join((ast.get_docstring(node) or "").split("\n\n")[0].split())
    return ""


class AmbdaqGroup(click.Group):
    """A click group that loads its commands from :data:`COMMANDS` when they run and turns library
    errors into one line and the documented exit code."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        target = COMMANDS.get(name)
        if target is None:
            return None
        return load_object(f".{target}", __package__)

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name = args[0] if args else ""
        if name and not name.startswith("-") and name not in COMMANDS:
            close = difflib.get_close_matches(name, list(COMMANDS), n=1)
            ctx.fail(f"no command {name!r}" + (f": did you mean {close[0]!r}?" if close else ""))
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        limit = formatter.width - 6 - max(len(n) for n in COMMANDS)
        rows = [(name, click.utils.make_default_short_help(_summary(COMMANDS[name]), limit)) for name in sorted(COMMANDS)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx: click.Context):
        _say_warnings()
        try:
            return super().invoke(ctx)
        except click.exceptions.UsageError as err:  # one line, like every other error, with where to look
            where = err.ctx.command_path if err.ctx is not None else "ambdaq"
            click.echo(f"ambdaq: error: {err.format_message()} (see {where} --help)", err=True)
            ctx.exit(err.exit_code)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except BrokenPipeError:  # `ambdaq info FILE | head`: the reader has what it wanted
            _quiet_stdout()
            ctx.exit(1)
        except AmbdaqError as err:
            if ctx.meta.get("ambdaq.debug"):
                raise
            click.echo(f"ambdaq: error: {err}", err=True)
            ctx.exit(err.exit_code)
        except OSError as err:
            if ctx.meta.get("ambdaq.debug"):
                raise
            click.echo(f"ambdaq: error: {err}", err=True)
            ctx.exit(1)
        except MemoryError as err:  # a runtime failure (exit 1): the machine, not the input
            if ctx.meta.get("ambdaq.debug"):
                raise
            click.echo(f"ambdaq: error: out of memory ({err or 'no detail'}): take fewer topics (--topic) or a "
                       "shorter stretch (--start, --end)", err=True)
            ctx.exit(1)
        except Exception as err:  # a bug: one line, the traceback with --debug
            if ctx.meta.get("ambdaq.debug"):
                raise
            click.echo(f"ambdaq: internal error: {type(err).__name__}: {err} (run with --debug for the traceback)", err=True)
            ctx.exit(1)


def _say_warnings() -> None:
    """Print each :class:`~ambdaq.errors.AmbdaqWarning` as one ``ambdaq: warning:`` line on stderr
    (once per place it comes from); other warnings as Python shows them."""
    import warnings

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        if issubclass(category, AmbdaqWarning):
            click.echo(f"ambdaq: warning: {message}", err=True)
        else:
            shown(message, category, filename, lineno, file, line)

    warnings.showwarning = show


def _quiet_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's last flush into the closed pipe says nothing
    (the recipe of the Python docs, "Note on SIGPIPE")."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


@click.group("ambdaq", cls=AmbdaqGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, envvar="AMBDAQ_DEBUG", help="Show tracebacks instead of one-line errors.")
@click.version_option(__version__, prog_name="ambdaq")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Data acquisition and tuning for active magnetic bearing machines."""
    ctx.meta["ambdaq.debug"] = debug


def main() -> None:
    """Console entry point."""
    try:
        cli(prog_name="ambdaq")
    finally:  # the last flush too may find the pipe closed (`ambdaq info FILE | head`)
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _quiet_stdout()
