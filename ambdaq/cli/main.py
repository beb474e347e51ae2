"""The ``ambdaq`` command group and its error handling.

Exit codes: 0 success, 1 runtime failure (device, I/O), 2 bad usage or bad input.  Errors are one
line on stderr; ``--debug`` (or ``AMBDAQ_DEBUG=1``) shows the traceback instead.
"""

from __future__ import annotations

import os
import sys

import click

from .. import __version__
from ..errors import AmbdaqError


class AmbdaqGroup(click.Group):
    """A click group that turns library errors into one line and the documented exit code."""

    def invoke(self, ctx: click.Context):
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
        except Exception as err:  # a bug: one line, the traceback with --debug
            if ctx.meta.get("ambdaq.debug"):
                raise
            click.echo(f"ambdaq: internal error: {type(err).__name__}: {err} (run with --debug for the traceback)", err=True)
            ctx.exit(1)


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


def _register() -> None:
    from . import devices, export, frf, fx, identify, info, lms, model, plot, push, record, recover, runout, selfsense, sim

    for module in (record, sim, devices, info, export, plot, recover, runout, lms, frf, fx, model, identify, selfsense):
        cli.add_command(module.command)
    cli.add_command(push.push_command)
    cli.add_command(push.controller_group)


_register()


def main() -> None:
    """Console entry point."""
    try:
        cli(prog_name="ambdaq")
    finally:  # the last flush too may find the pipe closed (`ambdaq info FILE | head`)
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _quiet_stdout()
