"""When an effect counts: the diagnosis' significance rule and its constants, in one place
(docs/model.md, "When an effect counts").

Every figure is in -2 log-likelihood units (n ln mse): a model's fit gain over another is the fall
of the BIC on the capture (`fit_check.bic`: n ln(mse) + k ln(n)), its check gain the fall of the
check's deviance (`fit_check.check_deviance`: the left-out windows and the holdout), its blocks gain
the fall of the interleaved blocks' deviance (`fit_check.block_deviance`).

- significant (`significance`): fit gain > SIGNIFICANT, and check gain > CHECK_GAIN or blocks gain
  > ONE_REGIME_GAIN, and the model breaks no constraint. The verdict, `explained_by`'s steps and
  its drops all ask this.
- worth checking (`worth_checking`): the check is computed only for effects whose fit gain already
  exceeds SIGNIFICANT (no check can make the others significant).
- close to the best (`close_to_best`): an effect within 2 x SIGNIFICANT of the best fit is polished
  on the full record, as the leaders are: the polish may move it past the best one.
- strong (`strong`): at the noise floor only an effect whose fit gain exceeds STRONG and whose
  check gain exceeds SIGNIFICANT (or blocks gain ONE_REGIME_GAIN) gives a verdict.
- kept without the check (`kept_without_check`): an effect whose removal loses more than
  KEEP_WITHOUT_CHECK on the fit stays without consulting the check.
- a step of `explained_by` (`step_gain`): an effect added to others must also gain more than
  STEP_REL of the error left (n ln(1 / (1 - STEP_REL))).
- ambiguous: two significant effects whose scores differ by less than AMBIGUOUS.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from bench_ctl.identification.fit_check import bic, block_deviance, check_deviance
from bench_ctl.identification.model_fits import ModelFit, Setup

__all__ = ["SIGNIFICANT", "CHECK_GAIN", "STRONG", "ONE_REGIME_GAIN", "AMBIGUOUS", "KEEP_WITHOUT_CHECK",
           "STEP_REL", "Significance", "significance", "worth_checking", "close_to_best", "strong",
           "kept_without_check", "step_gain", "criteria"]

#: BIC improvement (n ln mse units, i.e. -2 log-likelihood) an effect must bring to count
SIGNIFICANT = 10.0
#: improvement of the check's deviance an effect must bring to count (the check's samples were
#: not fitted: an effect that only fits noise does not improve them)
CHECK_GAIN = 2.0
#: BIC improvement that counts even when the base model is within the noise floor's uncertainty
#: (about a 1 % lower MSE on a 10 000-sample record)
STRONG = 100.0
#: improvement of the interleaved blocks' deviance that accepts an effect the windows cannot judge:
#: the blocks sample every regime in both halves, so they judge nearly where the fit was made and
#: must show a strong gain (as STRONG) where the windows need only CHECK_GAIN
ONE_REGIME_GAIN = 100.0
#: two effects whose scores differ by less than this explain the capture equally well
AMBIGUOUS = 6.0
#: a fit loss this large when an effect is taken out keeps it without consulting the check
KEEP_WITHOUT_CHECK = 10 * STRONG
#: an effect added to others must explain at least this share of the error left: below it, the
#: differences between any plant and any model of it (integration, edge timing, a slightly other
#: limit rule) are of that size, and a flexible effect fits them (docs/decisions/0010, appendix)
STEP_REL = 0.01


class Significance(NamedTuple):
    """A model's gains over a reference model and whether they make it count."""
    fit: float          # fall of the BIC on the capture
    check: float        # fall of the check's deviance
    significant: bool


def significance(st: Setup, ref: ModelFit, m: ModelFit) -> Significance:
    """m over ref: the BIC falls by more than SIGNIFICANT, the check's deviance by more than
    CHECK_GAIN or the interleaved blocks' by more than ONE_REGIME_GAIN, and m breaks no
    constraint."""
    gain_fit = bic(st.n, ref.mse, ref.k) - bic(st.n, m.mse, m.k)
    gain_check = check_deviance(ref, m)
    judged = gain_check > CHECK_GAIN or block_deviance(ref, m) > ONE_REGIME_GAIN
    return Significance(gain_fit, gain_check, bool(gain_fit > SIGNIFICANT and judged and m.feasible))


def worth_checking(gain_fit: float) -> bool:
    """Whether an effect's fit gain leaves it a chance to be significant (so its check is computed)."""
    return gain_fit > SIGNIFICANT


def close_to_best(bic_over_best: float) -> bool:
    """Whether an effect's BIC lies close enough to the best one's for a polish to matter."""
    return bic_over_best < 2 * SIGNIFICANT


def strong(delta_bic: float, delta_check: float, delta_blocks: float | None, *, has_check: bool) -> bool:
    """Whether a significant effect's gains count at the noise floor (delta_blocks None: not
    checked)."""
    blocks = -math.inf if delta_blocks is None else delta_blocks
    return delta_bic > STRONG and (not has_check or delta_check > SIGNIFICANT or blocks > ONE_REGIME_GAIN)


def kept_without_check(fit_loss: float) -> bool:
    """Whether taking an effect out loses so much of the fit that the check could not change it."""
    return fit_loss > KEEP_WITHOUT_CHECK


def step_gain(n: int) -> float:
    """The fit gain an effect added to others must exceed on a record of n samples."""
    return max(SIGNIFICANT, -n * math.log(1.0 - STEP_REL))


def criteria() -> dict[str, float]:
    """The constants as a diagnosis JSON's `criteria` names them."""
    return {"significant_delta": SIGNIFICANT, "check_gain": CHECK_GAIN, "strong_delta": STRONG,
            "one_regime_gain": ONE_REGIME_GAIN, "ambiguous_delta": AMBIGUOUS}
