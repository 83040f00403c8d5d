"""The `bench-ctl` command line: parses, then dispatches to plain functions.

Each sub-command lives in its own module (imported only when used, so `bench-ctl sim` does not
pay for compiling the identification kernel). Exit codes (docs/style.md): 0 pass, 1 criteria
failed, 2 aborted / safe state reached / bad input, 3 communication error, 70 a bug:
`bench_ctl.exitcodes`. `main` is the one place that maps errors to exit codes: a `BadInput`
(every layer's input error) or an `OSError` a command did not expect ends it with one line and
exit 2, any other exception as a bug (exit 70, one line; the traceback with `-v`).
"""
from __future__ import annotations

import importlib
import logging
import os
import sys
import traceback

import click

from bench_ctl import compile_notice
from bench_ctl.exitcodes import BadInput, ExitCode

# name -> "module:attribute" of a click.Command
COMMANDS = {
    "simulate": "bench_ctl.commands.simulate:simulate",
    "identify": "bench_ctl.commands.identify:identify",
    "diagnose": "bench_ctl.commands.diagnose:diagnose",
    "report": "bench_ctl.commands.report:report",
    "import": "bench_ctl.commands.import_export:import_export",
    "sim": "bench_ctl.commands.sim:sim",
    "run": "bench_ctl.commands.run:run",
    "demo": "bench_ctl.commands.demo:demo",
    "batch": "bench_ctl.commands.batch:batch",
    "models": "bench_ctl.commands.models:models",
    "export": "bench_ctl.commands.export:export",
    "warm-up": "bench_ctl.commands.warm_up:warm_up",
}


class LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        target = COMMANDS.get(name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                return None  # not built yet
            raise
        return getattr(module, attr)


#: libraries whose log lines stay off the console (a run's log file keeps them) unless -vv
QUIET_LIBRARIES = ("pymodbus", "distributed", "dask", "tornado", "bokeh")


class _LibraryFilter(logging.Filter):
    """Keeps the libraries' own log lines (pymodbus' "No response received", Dask's INFO) off the
    console: bench-ctl says what went wrong in its own words; the run's log file has them."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.name.startswith(QUIET_LIBRARIES) or record.levelno >= logging.CRITICAL


#: -v given to the command being run (the traceback of a bug is shown with it)
_verbose = 0


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug, with the "
              "libraries' own lines).")
@click.version_option(package_name="bench-ctl")
def cli(verbose: int) -> None:
    """bench-ctl: pulse test, AVR identification (MVMO), validation report, gap diagnosis."""
    global _verbose
    _verbose = verbose
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    compile_notice.install(compile_notice.console)   # a first run says what it compiles
    if verbose < 2:
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.StreamHandler) and not isinstance(handler, logging.FileHandler):
                handler.addFilter(_LibraryFilter())
        # Dask's own console handler (it does not propagate): its INFO lines off the console
        os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")


def _standard_streams() -> None:
    """A standard stream closed by the shell (`2>&-`) is reopened on /dev/null at its number
    (else the first file a run opens would take fd 2 and receive every stray write), and what
    would go to a closed stderr goes to stdout: a refusal is still said."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    if sys.stdout is None:
        sys.stdout = open(os.devnull, "w", encoding="utf-8")  # noqa: SIM115 - for the process' life
    if sys.stderr is None:
        sys.stderr = sys.stdout


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code instead of exiting (tests call it directly)."""
    _standard_streams()
    global _verbose
    _verbose = 0
    try:
        rv = cli.main(args=argv, prog_name="bench-ctl", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return ExitCode.ABORTED
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except BadInput as exc:
        click.echo(f"error: {exc}", err=True)
        return exc.exit_code
    except OSError as exc:   # an input a command reads without its own check: a folder, a permission
        click.echo(f"error: {exc.filename}: {exc.strerror}" if exc.filename else f"error: {exc}", err=True)
        return ExitCode.ABORTED
    except Exception as exc:  # noqa: BLE001 - anything else is a bug, said as such
        return _bug(exc)
    return int(rv or 0)


def _bug(exc: Exception) -> int:
    """One line saying an unexpected error is bench-ctl's, not the input's; the traceback with -v."""
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    at = f" at {where.filename.rsplit('/', 1)[-1]}:{where.lineno}" if where else ""
    click.echo(f"internal error (a bug in bench-ctl, not in the input): {type(exc).__name__}: {exc}{at}; "
               + ("the traceback follows" if _verbose else "run again with -v for the traceback"), err=True)
    if _verbose:
        click.echo("".join(traceback.format_exception(exc)).rstrip(), err=True)
    return ExitCode.BUG


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
