"""The pass / fail summary of a report, and an independent re-check of the constraints.

Each `Check` is `pass`, `fail`, `warn` or `n/a`; the overall verdict is FAIL when any check
fails, PASS WITH WARNINGS when one warns (the reader of a bare "PASS" would take a fit 30 times
the noise floor for a validated model), else PASS. What fails: the re-simulation blew up,
the reported MSE is not reproduced by re-simulating the result's parameters on the capture, a
constraint is violated (as reported, or as re-evaluated here), an identified value lies outside
its bounds (the `local` peer ignores them by design). What warns: the MSE is more than
`noise_ratio_limit` times the noise floor, a parameter is not determined by the capture, an
identified value sits on a bound.
"""
from __future__ import annotations

import ast
import math
import operator
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bench_ctl.units.unit import bounded_values

MSE_REL_TOL = 1e-3
DEFAULT_NOISE_RATIO_LIMIT = 2.0
AT_BOUND_FRACTION = 1e-3

_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv}
_CMP = {ast.LtE: "<=", ast.Lt: "<", ast.GtE: ">=", ast.Gt: ">"}


@dataclass(frozen=True)
class Check:
    name: str
    status: str  # "pass" | "fail" | "warn" | "n/a"
    detail: str


PASS, PASS_WARN, FAIL = "PASS", "PASS WITH WARNINGS", "FAIL"


def overall(checks: list[Check]) -> str:
    if any(c.status == "fail" for c in checks):
        return FAIL
    return PASS_WARN if any(c.status == "warn" for c in checks) else PASS


def verdict_class(verdict: str) -> str:
    """The one-word style class of a verdict (PASS, WARN, FAIL)."""
    return "WARN" if verdict == PASS_WARN else verdict


def _eval(node: ast.AST, values: Mapping[str, float]) -> float:
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
            and not isinstance(node.value, bool):
        return float(node.value)
    if isinstance(node, ast.Name):
        if node.id not in values:
            raise KeyError(node.id)
        return float(values[node.id])
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _eval(node.operand, values)
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        return _BINOPS[type(node.op)](_eval(node.left, values), _eval(node.right, values))
    raise ValueError(f"unsupported expression {ast.dump(node)}")


def constraint_margin(expr: str, values: Mapping[str, float]) -> float | None:
    """Smallest slack of an (in)equality chain like `0 <= TA2 <= TA1` (>= 0 when satisfied), or
    None when the text is not an arithmetic comparison of known parameters."""
    try:
        tree = ast.parse(expr, mode="eval").body
        if not isinstance(tree, ast.Compare) or not all(type(o) in _CMP for o in tree.ops):
            return None
        terms = [_eval(n, values) for n in [tree.left, *tree.comparators]]
    except (SyntaxError, KeyError, ValueError, ZeroDivisionError):
        return None
    margins = []
    for op, a, b in zip(tree.ops, terms, terms[1:]):
        margins.append(b - a if _CMP[type(op)] in ("<=", "<") else a - b)
    return min(margins)


def recheck_constraints(constraints: list[Mapping[str, Any]],
                        values: Mapping[str, float]) -> list[dict[str, Any]]:
    """The result's constraints, each with the re-evaluated margin and verdict added
    (`recheck_margin`, `recheck_satisfied`; None when the text could not be evaluated)."""
    out = []
    for c in constraints:
        margin = constraint_margin(str(c.get("expr", "")), values)
        ok = None if margin is None else margin >= -1e-9 * max(1.0, abs(margin))
        out.append({**c, "recheck_margin": margin, "recheck_satisfied": ok})
    return out


def summary_checks(*, sim_failures: list[str], mse_recomputed: float,
                   mse_reported: Any, constraints: list[Mapping[str, Any]],
                   noise_floor: float | None, noise_source: str,
                   noise_ratio_limit: float, determined: Mapping[str, Any] | None,
                   at_bounds: list[str], n_captures: int,
                   outside_bounds: list[str] = ()) -> list[Check]:
    checks = [Check("capture integrity", "pass",
                    f"SHA-256 of {n_captures} capture file(s) matches the result")]
    if sim_failures:
        checks.append(Check("fit and re-simulation", "fail", "; ".join(sim_failures)))
    else:
        checks.append(Check("fit and re-simulation", "pass",
                            "the model ran to the end of every capture"))
    if isinstance(mse_reported, (int, float)) and not isinstance(mse_reported, bool):
        tol = MSE_REL_TOL * abs(float(mse_reported)) + 1e-15
        ok = abs(mse_recomputed - float(mse_reported)) <= tol
        checks.append(Check("reported MSE reproduced", "pass" if ok else "fail",
                            f"re-simulated {mse_recomputed:.6g}, reported {float(mse_reported):.6g}"
                            f" (tolerance {MSE_REL_TOL:g} relative)"))
    else:
        checks.append(Check("reported MSE reproduced", "fail",
                            f"the result's mse is {mse_reported!r}, not a number"))
    if not constraints:
        checks.append(Check("constraints", "n/a", "the result lists no constraints"))
    else:
        bad = [str(c.get("expr")) for c in constraints
               if c.get("satisfied") is not True or c.get("recheck_satisfied") is False]
        checks.append(Check("constraints", "fail" if bad else "pass",
                            f"violated: {', '.join(bad)}" if bad else
                            f"all {len(constraints)} satisfied (as reported and re-evaluated)"))
    if noise_floor is None or not noise_floor > 0:
        checks.append(Check("fit vs noise floor", "n/a", "no noise floor known"))
    else:
        ratio = mse_recomputed / noise_floor
        checks.append(Check("fit vs noise floor", "pass" if ratio <= noise_ratio_limit else "warn",
                            f"MSE / noise floor = {ratio:.3g} (limit {noise_ratio_limit:g}; "
                            f"noise floor {noise_floor:.3g} pu², {noise_source})"))
    if not determined:
        checks.append(Check("parameters determined", "n/a", "no identifiability block"))
    else:
        und = [k for k, v in determined.items() if v is not True]
        checks.append(Check("parameters determined", "warn" if und else "pass",
                            f"not determined by the capture: {', '.join(und)}" if und else
                            f"all {len(determined)} determined by the capture"))
    if outside_bounds:
        checks.append(Check("parameters inside bounds", "fail",
                            f"outside its bounds: {', '.join(outside_bounds)}"))
    else:
        checks.append(Check("parameters inside bounds", "warn" if at_bounds else "pass",
                            f"at a bound: {', '.join(at_bounds)}" if at_bounds else
                            "no identified value sits on a bound"))
    return checks


def params_at_bounds(params: Mapping[str, Any], bounds: Mapping[str, Any]) -> list[str]:
    out = []
    for name, value, lo, hi in bounded_values(params, bounds):
        tol = AT_BOUND_FRACTION * (hi - lo)
        if math.isfinite(tol) and (value - lo <= tol or hi - value <= tol):
            out.append(name)
    return out
