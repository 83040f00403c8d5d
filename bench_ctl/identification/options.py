"""The MVMO option sets, named by what they search (`mvmo.DEFAULT_OPTIONS` for the rest).

Why each: docs/decisions/0015-one-fitting-stack.md; the figures behind them: docs/benchmarks.md,
"MVMO defaults and option sets" and "Diagnosis constants".
"""
from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

__all__ = ["IDENTIFY", "WHOLE_BOX", "PROFILE", "BLACK_BOX", "EDGE_POLISH_SHARE", "EDGE_POLISH_MAX",
           "RESTART_RESERVE_SHARE", "RESTART_RESERVE_MAX"]

#: identification of a whole record (`bench-ctl identify`, the diagnosis' base model): 32
#: particles, since a generation is one kernel call whose cost per candidate falls with the batch;
#: longer local searches along the gain / lag ridge of the pulse response
IDENTIFY: Mapping[str, Any] = MappingProxyType({"particles": 32, "local_search_evals": 500})

#: the diagnosis' search of a model + effect over the whole box on the coarse record (restarts
#: share the budget): a wide swarm finds a dead time's narrow basin more often than 8 particles
WHOLE_BOX: Mapping[str, Any] = MappingProxyType({"particles": 32, "local_search_evals": None})

#: the diagnosis' profile searches (the model with an effect held) and the blind suite's
#: visibility fits: MVMO's defaults, whose many short local searches from good particles find the
#: AVR model's narrow basins more reliably than one polish of the final best
PROFILE: Mapping[str, Any] = MappingProxyType({"particles": 8, "local_search_evals": None})

#: a box-constrained search of a few hundred evaluations with nothing known of the landscape (the
#: CEC 2015 expensive suite, benchmarks/mvmo_cec.py): MVMO's defaults with the local search's
#: gradient by central differences, which follow an ill-conditioned valley to its floor where
#: forward ones stall (rotated Discus: below 1e-7 against 3-6), with a step 10x the forward one's
#: (their error is second order in the step, so a longer step loses less to rounding)
BLACK_BOX: Mapping[str, Any] = MappingProxyType({"fd_scheme": "central", "fd_step": 1e-6})

#: share of an identification's budget (at most EDGE_POLISH_MAX evaluations) given to the joint
#: polish that follows an MVMO search with the setpoint edge instants held mid-interval
EDGE_POLISH_SHARE = 0.15
EDGE_POLISH_MAX = 200

#: share of an identification's budget (at most RESTART_RESERVE_MAX evaluations) kept from MVMO
#: for the restarts, from the start point (the unit's values) and from the structure's exchanged
#: pairs: without it MVMO and the polish leave them some 30 evaluations, too few to polish out of
#: an exchanged basin
RESTART_RESERVE_SHARE = 0.15
RESTART_RESERVE_MAX = 150
