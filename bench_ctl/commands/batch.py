"""`bench-ctl batch MANIFEST.csv [--out DIR] [--scheduler ADDRESS] [--workers N]`: identify,
diagnose and report many captures at once on Dask (docs/fleets.md, bench_ctl.fleet).

Rows resolve inside the manifest's folder unless --allow-outside; a row that cannot run (a file
missing, outside that folder, not a capture) is an error row of summary.csv and the others run;
nothing of a refused file is shown. Our LocalCluster (scheduler, workers, dashboard) listens on
127.0.0.1 unless --host names another address.

Exit codes: 0 every capture passed, 1 some failed their criteria or errored (see summary.csv),
2 bad manifest, an output folder that cannot be written, or interrupted.
"""
from __future__ import annotations

import click


@click.command("batch")
@click.argument("manifest", type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="batch-out", show_default=True,
              help="Output folder: one sub-folder per capture, summary.csv, index.html (resumable).")
@click.option("--scheduler", default=None, help="Address of an existing Dask scheduler (tcp://HOST:PORT); "
              "default: a LocalCluster sized to this machine, started and closed here.")
@click.option("--workers", type=click.IntRange(min=1), default=None, help="LocalCluster worker processes.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address our LocalCluster's scheduler, workers and dashboard listen on (default: this "
                   "machine only).")
@click.option("--evals", type=click.IntRange(min=100), default=1000, show_default=True,
              help="Identification budget of each capture: at least 100 (a few generations of MVMO's swarm "
                   "of 32).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--allow-outside", is_flag=True,
              help="Read rows that name files outside the manifest's folder (refused by default).")
def batch(manifest: str, out_dir: str, scheduler: str | None, workers: int | None, host: str, evals: int,
          seed: int, allow_outside: bool = False) -> int:
    """Run identify + diagnose + report for every capture listed in MANIFEST (CSV)."""
    from bench_ctl.fleet.batch import run_batch

    outcome = run_batch(manifest, out_dir, scheduler=scheduler, workers=workers, evals=evals, seed=seed,
                        echo=click.echo, allow_outside=allow_outside, host=host)
    counts: dict[str, int] = {}
    for r in outcome.rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    click.echo(", ".join(f"{v} {k}" for k, v in counts.items()) + f" in {outcome.wall_s:.1f} s")
    for r in outcome.rows:
        if r["status"] in ("error", "not run"):
            click.echo(f"  {r['status']}: {r['capture']}: {r['error'] or 'interrupted'}", err=True)
    click.echo(f"summary: {outcome.summary_csv}\nindex:   {outcome.index_html}")
    return outcome.exit_code
