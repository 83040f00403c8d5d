"""What a command says while the engine compiles (a fresh machine, a first run): the hook the
engine calls around a compilation (`compiling`), kept apart from the engine so that the console
can install its own without importing numba.

By default a compilation is logged; the CLI installs `console` (a line on stderr, on a terminal
with the seconds counting while it waits).
"""
from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator

log = logging.getLogger(__name__)

#: (what, about how many seconds) -> a context manager around the wait
Notice = Callable[[str, float], contextlib.AbstractContextManager]


@contextlib.contextmanager
def logged(what: str, estimate_s: float) -> Iterator[None]:
    """The default notice: a log line before and after."""
    t0 = time.perf_counter()
    log.info("compiling the %s: first run only, about %.0f s", what, estimate_s)
    yield
    log.info("compiled the %s in %.1f s", what, time.perf_counter() - t0)


@contextlib.contextmanager
def console(what: str, estimate_s: float) -> Iterator[None]:
    """The console's notice: "compiling the WHAT (first run only, about N s)" on stderr, on a
    terminal with the seconds counting, then how long it took. Nothing when stderr is closed."""
    stream = sys.stderr
    if stream is None or getattr(stream, "closed", True):
        with logged(what, estimate_s):
            yield
        return
    tty = bool(getattr(stream, "isatty", lambda: False)())
    line = f"compiling the {what} (first run only, about {estimate_s:.0f} s)"
    t0 = time.perf_counter()
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(1.0):
            _write(stream, f"\r{line} ... {time.perf_counter() - t0:.0f} s")

    _write(stream, line + (" ..." if tty else "\n"))
    ticker = threading.Thread(target=tick, name="compile-notice", daemon=True) if tty else None
    if ticker:
        ticker.start()
    try:
        yield
    finally:
        stop.set()
        if ticker:
            ticker.join()
        took = f"compiled in {time.perf_counter() - t0:.0f} s"
        _write(stream, f"\r{line}: {took}\n" if tty else f"  {took}\n")


def _write(stream, text: str) -> None:
    try:
        stream.write(text)
        stream.flush()
    except (OSError, ValueError):  # the console went away: the work goes on
        pass


_notice: Notice = logged


def install(notice: Notice | None) -> Notice:
    """Install the notice `compiling` uses (None: logging); returns the previous one."""
    global _notice
    old = _notice
    _notice = notice or logged
    return old


_said = threading.local()   # how deep this thread is inside a notice


def compiling(what: str, estimate_s: float) -> contextlib.AbstractContextManager:
    """The context a compilation runs in: the installed notice; inside another notice on this
    thread nothing more (the outer one covers the wait: one line, not one per function)."""
    return contextlib.nullcontext() if getattr(_said, "depth", 0) else _counted(_notice(what, estimate_s))


@contextlib.contextmanager
def _counted(notice: contextlib.AbstractContextManager) -> Iterator[None]:
    with notice:
        _said.depth = getattr(_said, "depth", 0) + 1
        try:
            yield
        finally:
            _said.depth -= 1
