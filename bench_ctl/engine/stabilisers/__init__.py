"""The stabilisers a unit on the grid can carry, each a plug-in of the engine's seam (`step`): its
states (a tuple), its output added to the exciter's reference, its derivatives, both from the
rotor speed and the electrical power the machine gives.

- `none`: no stabiliser (no states, output 0);
- `ieeest`: IEEEST on the rotor speed, without its notch filters;
- `pss2`: PSS2A and PSS2B on the rotor speed and the electrical power.

A candidate's stabiliser is its machine matrix's PSS_MODEL (`bench_ctl.model.stabilisers`); each
plug-in fills its own derived columns and leaves its gain 0 for a candidate of another
(`derive_columns`), and `kind` names the plug-in a derived matrix needs. `OUTPUT_LIMIT_ROWS` are
the derived rows that bound a stabiliser's output: 0 in all of them holds its output at 0 while its
states keep running (a real PSS's output switch; the on-line plant's `set_pss`).
"""
from __future__ import annotations

import numpy as np

from ..layout import D_P2_VSTMAX, D_P2_VSTMIN, D_PSS_LIM
from . import ieeest, pss2

#: the derived rows bounding a stabiliser's output (IEEEST's +-LSMAX, PSS2's VSTMAX and VSTMIN)
OUTPUT_LIMIT_ROWS = (D_PSS_LIM, D_P2_VSTMAX, D_P2_VSTMIN)


def derive_columns(D: np.ndarray, M: np.ndarray) -> None:
    """Every stabiliser's derived columns of D from the machine matrix M."""
    ieeest.derive_columns(D, M)
    pss2.derive_columns(D, M)


def kind(D: np.ndarray) -> str:
    """The stabiliser plug-in (`variants.STABILISERS`' key) the candidates of the derived matrix D
    need: "none", "ieeest" or "pss2". One call runs one plug-in: candidates with different
    stabilisers are refused."""
    on = [name for name, module in (("ieeest", ieeest), ("pss2", pss2)) if module.present(D)]
    if len(on) > 1:
        raise ValueError("candidates with an IEEEST and candidates with a PSS2A/PSS2B in one run: "
                         "simulate them apart")
    return on[0] if on else "none"
