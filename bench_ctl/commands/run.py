"""`bench-ctl run PROCEDURE --bench BENCH.toml [--dry-run] [--yes] [--out DIR]`.

Runs a procedure from `procedures/` through the runner (bench_ctl.runner.run_procedure) and
prints how it ended, the safe state of each device and the files written. Exit code: 0 passed,
1 criteria failed, 2 aborted / refused, 3 communication error or safe state not confirmed.
"""
from __future__ import annotations

import datetime as dt
import logging
from pathlib import Path

import click

from bench_ctl.exitcodes import ExitCode
from bench_ctl.runner.config import ConfigError
from bench_ctl.runner.runner import OutputExists, OutputUnusable, RunOutcome, run_procedure

log = logging.getLogger(__name__)


def _parse_param(text: str) -> tuple[str, float | int | str]:
    key, eq, raw = text.partition("=")
    if not eq or not key.strip():
        raise click.BadParameter(f"{text!r}: expected NAME=VALUE", param_hint="--param")
    raw = raw.strip()
    for cast in (int, float):
        try:
            return key.strip(), cast(raw)
        except ValueError:
            pass
    return key.strip(), raw


def print_outcome(outcome: RunOutcome) -> None:
    """The operator's summary of a run (nothing when the terminal is gone: a hang-up ended the
    run, and its outcome is in the audit)."""
    try:
        _print_outcome(outcome)
    except OSError as exc:
        log.warning("the outcome could not be printed (%s); it is in %s", exc, outcome.audit_path)


def _print_outcome(outcome: RunOutcome) -> None:
    err = outcome.exit_code != ExitCode.OK
    click.secho(f"{outcome.procedure}: {outcome.status.upper()} (exit {outcome.exit_code})",
                fg="green" if not err else ("yellow" if outcome.exit_code == ExitCode.FAILED else "red"),
                bold=True, err=err)
    click.echo(outcome.message, err=err)
    for line in outcome.not_saved:
        if line not in outcome.message:
            click.secho(f"  {line}", fg="red", bold=True, err=True)
    if outcome.expects_capture and outcome.started and not _on_disk(outcome.capture_path) and \
            not any("capture" in line for line in outcome.not_saved):
        kept = "; the recorder's record is saved raw (below)" if _on_disk(outcome.raw_path) else ""
        click.secho(f"  capture: NOT SAVED - the run ended before its capture was written (the reason is above){kept}",
                    fg="red", bold=True, err=True)
    for c in outcome.criteria:
        mark = "PASS" if c.passed else "FAIL"
        click.echo(f"  [{mark}] {c.name}: {c.text()}".rstrip())
    for r in outcome.safe_state:
        line = f"  safe state {r.device}: {r.action}"
        click.secho(line, fg=None if r.ok else "red", bold=not r.ok, err=not r.ok)
    for label, path in (("capture", outcome.capture_path), ("sidecar", outcome.sidecar_path),
                        ("raw download", outcome.raw_path), ("audit", outcome.audit_path),
                        ("log", outcome.log_path)):
        if _on_disk(path):
            click.echo(f"  {label}: {path}")
    earlier = [p for p in outcome.data.get("captures", []) if Path(p) != outcome.capture_path and _on_disk(Path(p))]
    for path in earlier:   # a test of several records (pss_step): the ones before the last
        click.echo(f"  earlier capture: {path}")


def _on_disk(path: Path | None) -> bool:
    return path is not None and Path(path).exists()


@click.command("run")
@click.argument("procedure")
@click.option("--bench", "bench_path", required=True, type=click.Path(dir_okay=False),
              help="Bench config (TOML): device addresses, profiles, safety limits.")
@click.option("--dry-run", is_flag=True,
              help="Start the embedded simulated bench and run against it (no confirmation).")
@click.option("--yes", is_flag=True, help="Do not ask before writing to real devices.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Output folder (default runs/PROCEDURE-YYYYmmddTHHMMSS); never overwritten.")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="Override a procedure parameter, e.g. amplitude_pu=0.04 (repeatable).")
def run(procedure: str, bench_path: str, dry_run: bool, yes: bool, out_dir: str | None,
        params: tuple[str, ...]) -> int:
    """Run PROCEDURE (no_load_pulse, comms_check, ...) on the bench."""
    if out_dir is None:
        stamp = dt.datetime.now().strftime("%Y%m%dT%H%M%S")
        out_dir = str(Path("runs") / f"{procedure}-{stamp}")
    try:
        outcome = run_procedure(procedure, bench_path, out_dir, dry_run=dry_run, yes=yes,
                                params=dict(_parse_param(p) for p in params),
                                progress=True)
    except (ConfigError, OutputExists, OutputUnusable) as exc:
        click.secho(f"refused: {exc}", fg="red", err=True)
        return ExitCode.ABORTED
    print_outcome(outcome)
    return outcome.exit_code
