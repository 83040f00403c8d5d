"""The procedure runner: bench config, audit log, safety checks, and `run_procedure`.

    from bench_ctl.runner import run_procedure
    outcome = run_procedure("no_load_pulse", "benches/example.toml", "out/", dry_run=True)
    outcome.exit_code, outcome.capture_path, outcome.audit_path

See `runner.py` for the exit paths and `config.py` for the bench config format. This package
wires drivers (and, for dry runs, the simulators) together; the analysis core does not import it.
"""
from bench_ctl.runner.config import BenchConfig, ConfigError, load_bench_config
from bench_ctl.runner.runner import OutputExists, OutputUnusable, RunOutcome, run_procedure

__all__ = ["BenchConfig", "ConfigError", "OutputExists", "OutputUnusable", "RunOutcome",
           "load_bench_config", "run_procedure"]
