"""The unit as a record ran it: a record taken with the stabiliser's output switched off (the
first step of `pss_step`, its sidecar's `test.pss_on` false) is simulated with the unit's
stabiliser output held at 0, its states running -- what the exciter's PSS switch does on the
device and on the simulated bench (`OnlinePlant.set_pss`).

Every simulation of a record goes through `grid_as_recorded`: identification, the diagnosis and
the report's re-simulation fit and show the PSS-off record as it was taken, not with a stabiliser
that was not acting.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

#: the [grid] values that hold a stabiliser's output at 0 (IEEEST's +-LSMAX, PSS2A/PSS2B's VSTMAX
#: and VSTMIN), its states running
PSS_OUTPUT_OFF: dict[str, float] = {"PSS_LSMAX": 0.0, "PSS2_VSTMAX": 0.0, "PSS2_VSTMIN": 0.0}


def pss_switched_off(capture: Any) -> bool:
    """Whether the record was taken with the PSS's output switched off (its sidecar says so; a
    record that does not say is taken as the unit runs)."""
    test = (getattr(capture, "meta", None) or {}).get("test") or {}
    return test.get("pss_on") is False


def grid_as_recorded(grid: Mapping[str, float], capture: Any) -> dict[str, float]:
    """The unit's [grid] values as `capture` was taken: the stabiliser's output held at 0 when the
    record was taken with the PSS off, else `grid` unchanged."""
    return {**grid, **PSS_OUTPUT_OFF} if pss_switched_off(capture) else dict(grid)
