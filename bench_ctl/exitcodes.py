"""The exit codes of every `bench-ctl` command and of a procedure run, in one place.

A command returns one of these (tests call `bench_ctl.cli.main(argv) -> int` directly); a run's
`RunOutcome.exit_code` is one. The numbers are the public contract (docs/style.md, "CLI"):
scripts and the batch read them. This module imports nothing of the project, so every layer
that returns an exit code may import it.
"""
from __future__ import annotations

from enum import IntEnum

__all__ = ["ExitCode"]


class ExitCode(IntEnum):
    """What a command or a run ended with.

    OK (0)       passed: the run's criteria held, or the command did what it was asked and found
                 nothing to flag (`diagnose`: the model fits to the noise floor, verdict none).
    FAILED (1)   criteria failed: the work was done and its result fails a criterion (a run's
                 pass criteria, a violated constraint, a report check; `diagnose`: an unmodelled
                 effect explains the gap; `batch`: a capture's criteria failed).
    ABORTED (2)  aborted, refused or bad input: nothing was done, or a run stopped and its safe
                 state was reached (an operator's Ctrl-C, a limit, a precondition, a file, key,
                 value or option refused with one line naming it, an output not written).
    COMMS (3)    communication error (a link lost, a device not answering, a record that fails
                 its integrity check), and any run whose safe state could NOT be confirmed,
                 whatever else happened.
    """

    OK = 0
    FAILED = 1
    ABORTED = 2
    COMMS = 3
