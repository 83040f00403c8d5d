"""bench-ctl: AVR model validation bench controller."""
import os as _os
import sys as _sys

__version__ = "0.1.0"

# numba's "max" optimisation (an extra O3 round before the full one) is what vectorises the
# kernel's RK4 loop over candidates for the standard structures: at the default level that loop
# stayed scalar in its own build and was vectorised only in copies re-optimised inside a caller,
# so the speed of a process depended on which cached object it happened to load first (EXST1:
# 0.46 or 0.19 ms a candidate on one thread). Set before numba builds its code generator (the
# first @njit of the process); `bench_ctl.engine.optimisation_note` says when it came too
# late. A value the user set is kept. See docs/decisions/0003.
if "NUMBA_OPT" not in _os.environ:
    _os.environ["NUMBA_OPT"] = "max"
    if "numba" in _sys.modules:  # imported already: let it read the variable again
        _sys.modules["numba"].core.config.reload_config()
