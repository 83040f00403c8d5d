"""Tests for bench_ctl.identification.constraints: parsing, normalisation, violation checks.

Expected coefficients are worked out by hand from the constraint text (normal form
``coef @ x <= rhs`` over the given name order), not copied from the parser's output.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench_ctl.identification.constraints import (
    ConstraintError,
    LinearConstraint,
    parse_constraint,
    parse_constraints,
)

NAMES = ["TA1", "TA2", "TA3", "TA4", "S10", "S12"]


@pytest.mark.parametrize(
    "text, coef, rhs",
    [
        ("TA2 <= TA1", [-1, 1, 0, 0, 0, 0], 0.0),
        ("TA4 >= TA2", [0, 1, 0, -1, 0, 0], 0.0),
        ("TA1 + TA3 <= 5", [1, 0, 1, 0, 0, 0], 5.0),
        ("S12 >= 1.44*S10", [0, 0, 0, 0, 1.44, -1], 0.0),
        ("2*TA2 - TA1 <= 0.5", [-1, 2, 0, 0, 0, 0], 0.5),
        ("TA2 < TA1", [-1, 1, 0, 0, 0, 0], 0.0),
        ("TA4 > TA2", [0, 1, 0, -1, 0, 0], 0.0),
        # constants on both sides, parentheses, unary minus, division by a number, exponents
        ("3 + TA1 <= 2*(TA2 - 1) + 7", [1, -2, 0, 0, 0, 0], 2.0),
        ("-(TA1 - 2*TA3)/2 >= -1", [0.5, 0, -1, 0, 0, 0], 1.0),
        ("TA1*2.5e-1 <= .5", [0.25, 0, 0, 0, 0, 0], 0.5),
        ("-" * 5001 + "TA1 <= +-+1", [-1, 0, 0, 0, 0, 0], -1.0),  # odd count of minus
        ("TA1 - TA1 + TA2 <= 1", [0, 1, 0, 0, 0, 0], 1.0),
        ("  TA2<=TA1  ", [-1, 1, 0, 0, 0, 0], 0.0),
    ],
)
def test_parse_normal_form(text: str, coef: list[float], rhs: float) -> None:
    c = parse_constraint(text, NAMES)
    assert c.expr == text
    np.testing.assert_allclose(c.coef, coef, rtol=0, atol=1e-15)
    assert c.rhs == pytest.approx(rhs, abs=1e-15)
    assert c.names == tuple(NAMES)


def test_violation_satisfied_and_vectorised() -> None:
    c = parse_constraint("TA2 <= TA1", NAMES)
    x_ok = np.array([2.0, 1.0, 0, 0, 0, 0])
    x_bad = np.array([1.0, 1.75, 0, 0, 0, 0])
    assert c.violation(x_ok) == 0.0
    assert c.violation(x_bad) == pytest.approx(0.75)
    assert c.satisfied(x_ok) and not c.satisfied(x_bad)
    assert c.satisfied([1.0, 1.0 + 1e-10, 0, 0, 0, 0])  # within the default tolerance
    assert not c.satisfied([1.0, 1.0 + 1e-10, 0, 0, 0, 0], tol=1e-12)
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 3, (50, 6))
    np.testing.assert_allclose(c.violations(X), [c.violation(x) for x in X])
    np.testing.assert_allclose(c.violations(X), np.maximum(0.0, X[:, 1] - X[:, 0]))

    s = parse_constraint("S12 >= 1.44*S10", NAMES)
    assert s.violation([0, 0, 0, 0, 1.0, 1.0]) == pytest.approx(0.44)
    assert s.violation([0, 0, 0, 0, 1.0, 1.5]) == 0.0


def test_shape_errors() -> None:
    c = parse_constraint("TA2 <= TA1", NAMES)
    with pytest.raises(ValueError, match="TA2 <= TA1"):
        c.violation([1.0, 2.0])
    with pytest.raises(ValueError, match=r"\(n, 6\)"):
        c.violations(np.zeros((3, 4)))


def test_unknown_name_error_names_text_name_and_known() -> None:
    with pytest.raises(ConstraintError) as e:
        parse_constraint("TA5 <= TA1", NAMES)
    msg = str(e.value)
    assert "'TA5 <= TA1'" in msg and "'TA5'" in msg
    for n in NAMES:
        assert n in msg
    assert isinstance(e.value, ValueError)
    with pytest.raises(ConstraintError, match="did you mean 'TA1'"):
        parse_constraint("ta1 >= 0", NAMES)


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("TA1*TA2 <= 1", "not linear"),
        ("(TA1 + 1)*(TA2 - 1) <= 1", "not linear"),
        ("TA1/TA2 <= 1", "not linear"),
        ("TA1/0 <= 1", "division by zero"),
        ("TA1 == TA2", "not supported"),
        ("TA1 = TA2", "not supported"),
        ("TA1 <= TA2 <= 3", "more than one relation"),
        ("TA1 + TA2", "expected one of"),
        ("TA1 <=", "expected a number"),
        ("TA1 <= (TA2", "expected ')'"),
        ("TA1 <= TA2)", "unexpected ')'"),
        ("2TA1 <= 3", "missing operator"),
        ("TA1 <= 2 ^ 3", "unexpected character '^'"),
        ("", "empty constraint"),
        ("1 <= 2", "no parameter"),
        ("TA1 - TA1 <= 1", "no parameter"),
        ("__import__('os') <= 1", "unexpected character"),
        ("__import__ <= 1", "unknown parameter '__import__'"),
        ("TA1 <= 1e", "missing operator before 'e'"),
        ("(" * 60 + "TA1" + ")" * 60 + " <= 1", "nested parentheses"),
        ("TA1 <= 2 TA2", "missing operator before 'TA2'"),
    ],
)
def test_parse_errors(text: str, fragment: str) -> None:
    with pytest.raises(ConstraintError, match="constraint") as e:
        parse_constraint(text, NAMES)
    assert fragment in str(e.value)
    assert repr(text) in str(e.value)


def test_parse_constraints_and_name_checks() -> None:
    cs = parse_constraints(["TA2 <= TA1", "TA4 >= TA2"], NAMES)
    assert isinstance(cs, tuple) and [c.expr for c in cs] == ["TA2 <= TA1", "TA4 >= TA2"]
    with pytest.raises(ConstraintError, match="one string"):
        parse_constraints("TA2 <= TA1", NAMES)
    with pytest.raises(ConstraintError, match="given twice"):
        parse_constraint("TA2 <= TA1", ["TA1", "TA2", "TA1"])
    with pytest.raises(ConstraintError, match="must be text"):
        parse_constraint(3, NAMES)  # type: ignore[arg-type]


def test_constraint_is_frozen_and_read_only() -> None:
    c = parse_constraint("TA2 <= TA1", NAMES)
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.rhs = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        c.coef[0] = 5.0
    # direct construction (optimizers build constraints in transformed spaces)
    d = LinearConstraint("x1 <= x0", np.array([-1.0, 1.0]), 0.0)
    assert d.violation([0.0, 2.0]) == 2.0
    assert d.describe() == "-1*x0 +1*x1 <= 0"
    with pytest.raises(ConstraintError, match="coefficients"):
        LinearConstraint("x", np.array([1.0, 2.0]), 0.0, ("a",))
