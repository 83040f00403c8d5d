"""The exit codes of every `bench-ctl` command and of a procedure run, and the one error that
means bad input, in one place.

A command returns one of these (tests call `bench_ctl.cli.main(argv) -> int` directly); a run's
`RunOutcome.exit_code` is one. The numbers are the public contract (docs/style.md, "CLI"):
scripts and the batch read them. Every error that means "bad input" (a file, key, value or option
refused, an output path refused) derives from `BadInput`; `bench_ctl.cli.main` ends a command on
one with its message on one line and `BadInput.exit_code`, and on any other exception with
`ExitCode.BUG` (a bug, said as such). This module imports nothing of the project, so every layer
that returns an exit code or refuses an input may import it.
"""
from __future__ import annotations

from enum import IntEnum

__all__ = ["ExitCode", "BadInput"]


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
    BUG (70)     an error bench-ctl did not expect: a bug, not the input (said on one line, the
                 traceback with -v); 70 is EX_SOFTWARE of sysexits.h.
    """

    OK = 0
    FAILED = 1
    ABORTED = 2
    COMMS = 3
    BUG = 70


class BadInput(ValueError):
    """Bad input: the message, one line, names the file, key, value or option refused and why. A
    command ends on it with `exit_code` (`bench_ctl.cli.main`); each layer's input error derives
    from it (`UnitError`, `CaptureError`, `FormatError`, `InputError`, `OutputRefused`, ...), and
    is a ValueError, as Python's own errors of a bad value are."""

    exit_code = ExitCode.ABORTED
