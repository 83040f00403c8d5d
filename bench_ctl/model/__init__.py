"""The plant and excitation models: the compiled kernel, the unit on the grid, the structures."""
import sys

#: numba's SSA pass recurses over the control-flow graph of the function it compiles; the kernel's
#: chunk runners and RK4 loops are large enough that a cold compilation nested in a caller's type
#: inference (`run_kernel` called before `identify.warm_up` has filled the cache) passes Python's
#: default limit of 1000 frames and fails with RecursionError (measured 2026-11-27 with
#: `benchmarks/online_speed.py` on an empty cache). Python 3.11 calls Python functions without
#: C recursion, so a higher limit costs nothing until it is used.
RECURSION_LIMIT = 20000
if sys.getrecursionlimit() < RECURSION_LIMIT:
    sys.setrecursionlimit(RECURSION_LIMIT)
