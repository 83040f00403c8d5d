"""Linear inequality constraints between named model parameters.

The unit file states the manufacturer's constraints as text, e.g. ``"TA2 <= TA1"``,
``"TA4 >= TA2"``, ``"TA1 + TA3 <= 5"``, ``"S12 >= 1.44*S10"``. This module parses them with a
small tokenizer and recursive-descent parser (no ``eval``) into :class:`LinearConstraint`,
normalised to ``coef @ x <= rhs`` over an ordered list of parameter names, so that the
optimizers (:mod:`bench_ctl.identification.mvmo`) can check and rank candidates.

Grammar (whitespace ignored)::

    constraint := expr REL expr          REL is one of <=  >=  <  >
    expr       := term (("+" | "-") term)*
    term       := unary (("*" | "/") unary)*
    unary      := ("+" | "-") unary | primary
    primary    := NUMBER | NAME | "(" expr ")"

Only linear forms are accepted: a product of two parameter expressions, or a division by
one, is rejected as "not linear". Strict inequalities ``<`` / ``>`` are treated like ``<=`` /
``>=``: a continuous optimizer cannot tell the difference, and the boundary is where a fitted
time constant legitimately ends up.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bench_ctl.exitcodes import BadInput
from bench_ctl.model.dialect import Note, prose

logger = logging.getLogger(__name__)

__all__ = ["ConstraintError", "LinearConstraint", "parse_constraint", "parse_constraints"]


class ConstraintError(BadInput):
    """A constraint text that cannot be parsed or does not fit the parameter names. Its message
    is a `Note` (`bench_ctl.model.dialect`): the constraint's text and the names it gives are
    data, said in a structure's names by the writer that reports it."""


@dataclass(frozen=True, eq=False)
class LinearConstraint:
    """``coef @ x <= rhs`` over the parameters ``names`` (in that order).

    ``expr`` keeps the original text for reports and error messages; ``coef`` is read-only.
    """

    expr: str
    coef: np.ndarray
    rhs: float
    names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        coef = np.array(self.coef, dtype=float).reshape(-1)
        coef.flags.writeable = False
        object.__setattr__(self, "coef", coef)
        object.__setattr__(self, "rhs", float(self.rhs) + 0.0)  # + 0.0 turns -0.0 into 0.0
        object.__setattr__(self, "names", tuple(self.names))
        if self.names and len(self.names) != coef.size:
            raise ConstraintError(Note(
                f"constraint {{!r}}: {coef.size} coefficients for {len(self.names)} names", self.expr))
        if not np.all(np.isfinite(coef)) or not np.isfinite(self.rhs):
            raise ConstraintError(Note("constraint {!r}: non-finite coefficient or bound", self.expr))

    def violation(self, x: Sequence[float] | np.ndarray) -> float:
        """Amount by which ``x`` breaks the constraint, ``max(0, coef @ x - rhs)``."""
        xv = np.asarray(x, dtype=float)
        if xv.shape != self.coef.shape:
            raise ValueError(
                f"constraint {self.expr!r}: x has shape {xv.shape}, expected {self.coef.shape}"
            )
        return max(0.0, float(self.coef @ xv) - self.rhs)

    def violations(self, X: np.ndarray) -> np.ndarray:
        """Vectorised :meth:`violation` for candidates ``X`` of shape ``(n, d)``."""
        Xv = np.asarray(X, dtype=float)
        if Xv.ndim != 2 or Xv.shape[1] != self.coef.size:
            raise ValueError(
                f"constraint {self.expr!r}: X has shape {Xv.shape}, expected (n, {self.coef.size})"
            )
        return np.maximum(0.0, Xv @ self.coef - self.rhs)

    def satisfied(self, x: Sequence[float] | np.ndarray, tol: float = 1e-9) -> bool:
        """True when ``coef @ x <= rhs + tol``."""
        return self.violation(x) <= tol

    def describe(self) -> str:
        """The normalised form as text, e.g. ``-1*TA1 + 1*TA2 <= 0``."""
        names = self.names or tuple(f"x{i}" for i in range(self.coef.size))
        terms = [f"{c:+g}*{n}" for c, n in zip(self.coef, names) if c != 0.0]
        return f"{' '.join(terms)} <= {self.rhs:g}"


# --------------------------------------------------------------------------- tokenizer

_TOKEN_RE = re.compile(
    r"""
    (?P<ws>\s+)
  | (?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<rel><=|>=|==|=<|=>|!=|<|>|=)
  | (?P<op>[+\-*/()])
    """,
    re.VERBOSE,
)


@dataclass(frozen=True)
class _Token:
    kind: str  # "num", "name", "rel", "op", "end"
    text: str
    pos: int


def _tokenize(text: str) -> list[_Token]:
    tokens: list[_Token] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN_RE.match(text, pos)
        if m is None:
            raise ConstraintError(Note(
                f"constraint {{!r}}: unexpected character {prose(repr(text[pos]))} at column {pos + 1}", text))
        kind = m.lastgroup or ""
        if kind != "ws":
            tokens.append(_Token(kind, m.group(), pos))
        pos = m.end()
    tokens.append(_Token("end", "", len(text)))
    return tokens


# --------------------------------------------------------------------------- parser

@dataclass(frozen=True)
class _Affine:
    """``sum(coef[name] * name) + const``; ``coef`` holds only non-zero entries."""

    coef: dict[str, float]
    const: float

    @property
    def is_constant(self) -> bool:
        return not self.coef

    def scaled(self, k: float) -> _Affine:
        return _Affine({n: c * k for n, c in self.coef.items() if c * k != 0.0}, self.const * k)

    def plus(self, other: _Affine, sign: float = 1.0) -> _Affine:
        coef = dict(self.coef)
        for n, c in other.coef.items():
            coef[n] = coef.get(n, 0.0) + sign * c
        return _Affine({n: c for n, c in coef.items() if c != 0.0}, self.const + sign * other.const)


_MAX_DEPTH = 50  # nested parentheses (keeps the recursion far from Python's limit)


class _Parser:
    def __init__(self, text: str, known: Sequence[str]):
        self.text = text
        self.known = known
        self.known_set = set(known)
        self.tokens = _tokenize(text)
        self.i = 0
        self.depth = 0

    # helpers
    def _peek(self) -> _Token:
        return self.tokens[self.i]

    def _next(self) -> _Token:
        tok = self.tokens[self.i]
        self.i += 1
        return tok

    def _error(self, msg: str, tok: _Token | None = None) -> ConstraintError:
        where = f" at column {tok.pos + 1}" if tok is not None and tok.kind != "end" else ""
        if tok is not None and tok.kind == "end":
            where = " at end of text"
        return ConstraintError(Note(f"constraint {{!r}}: {{}}{where}", self.text, msg))

    # grammar
    def parse(self) -> tuple[_Affine, str, _Affine]:
        if self._peek().kind == "end":
            raise self._error("empty constraint")
        lhs = self._expr()
        rel = self._next()
        if rel.kind in ("name", "num") or (rel.kind == "op" and rel.text == "("):
            raise self._error(f"missing operator before {rel.text!r}", rel)
        if rel.kind != "rel":
            raise self._error(f"expected one of <=, >=, <, > but found {rel.text!r}", rel)
        if rel.text not in ("<=", ">=", "<", ">"):
            raise self._error(
                f"relation {rel.text!r} not supported (only inequalities <=, >=, <, >)", rel
            )
        rhs = self._expr()
        end = self._next()
        if end.kind == "rel":
            raise self._error(
                "more than one relation (write chained bounds as two constraints)", end)
        if end.kind in ("name", "num") or (end.kind == "op" and end.text == "("):
            raise self._error(f"missing operator before {end.text!r}", end)
        if end.kind != "end":
            raise self._error(f"unexpected {end.text!r}", end)
        return lhs, rel.text, rhs

    def _expr(self) -> _Affine:
        value = self._term()
        while self._peek().kind == "op" and self._peek().text in "+-":
            op = self._next().text
            value = value.plus(self._term(), 1.0 if op == "+" else -1.0)
        return value

    def _term(self) -> _Affine:
        value = self._unary()
        while self._peek().kind == "op" and self._peek().text in "*/":
            op_tok = self._next()
            right = self._unary()
            if op_tok.text == "*":
                if not value.is_constant and not right.is_constant:
                    raise self._error(
                        "not linear: product of two parameter expressions "
                        f"({self._names(value)} * {self._names(right)})",
                        op_tok,
                    )
                if value.is_constant:
                    value = right.scaled(value.const)
                else:
                    value = value.scaled(right.const)
            else:
                if not right.is_constant:
                    raise self._error(
                        f"not linear: division by a parameter expression ({self._names(right)})",
                        op_tok,
                    )
                if right.const == 0.0:
                    raise self._error("division by zero", op_tok)
                value = value.scaled(1.0 / right.const)
        return value

    def _unary(self) -> _Affine:
        sign = 1.0
        while self._peek().kind == "op" and self._peek().text in "+-":  # a loop, not recursion
            if self._next().text == "-":
                sign = -sign
        inner = self._primary()
        return inner if sign > 0 else inner.scaled(-1.0)

    def _primary(self) -> _Affine:
        tok = self._next()
        if tok.kind == "num":
            return _Affine({}, float(tok.text))
        if tok.kind == "name":
            if tok.text not in self.known_set:
                hint = [k for k in self.known if k.lower() == tok.text.lower()][:1]
                did_you_mean = " (did you mean {!r}?)" if hint else ""
                raise ConstraintError(Note(
                    f"constraint {{!r}}: unknown parameter {{!r}} at column {tok.pos + 1}{did_you_mean}; "
                    "known parameters: {}", self.text, tok.text, *hint, ", ".join(self.known)))
            return _Affine({tok.text: 1.0}, 0.0)
        if tok.kind == "op" and tok.text == "(":
            self.depth += 1
            if self.depth > _MAX_DEPTH:
                raise self._error(f"more than {_MAX_DEPTH} nested parentheses", tok)
            inner = self._expr()
            self.depth -= 1
            close = self._next()
            if not (close.kind == "op" and close.text == ")"):
                raise self._error(f"expected ')' but found {close.text or 'end'!r}", close)
            return inner
        found = tok.text if tok.kind != "end" else "end of text"
        raise self._error(f"expected a number, a parameter name or '(' but found {found!r}", tok)

    @staticmethod
    def _names(a: _Affine) -> str:
        return " + ".join(sorted(a.coef))


def _check_names(names: Sequence[str]) -> tuple[str, ...]:
    out = tuple(str(n) for n in names)
    seen: set[str] = set()
    for n in out:
        if n in seen:
            raise ConstraintError(Note("parameter name {!r} given twice in {}", n, str(list(out))))
        seen.add(n)
    return out


def parse_constraint(text: str, names: Sequence[str]) -> LinearConstraint:
    """Parse one inequality between parameters ``names`` into ``coef @ x <= rhs``.

    Raises :class:`ConstraintError` (a ``ValueError``) naming the constraint text for syntax
    errors, unknown parameter names (listing the known ones), non-linear terms, and
    constraints without any parameter (``"1 <= 2"``).
    """
    if not isinstance(text, str):
        raise ConstraintError(Note(f"constraint must be text, got {prose(type(text).__name__)}: {{}}", repr(text)))
    known = _check_names(names)
    lhs, rel, rhs = _Parser(text, known).parse()
    diff = lhs.plus(rhs, -1.0)  # lhs - rhs  (REL)  0
    if rel in (">=", ">"):
        diff = diff.scaled(-1.0)
    if diff.is_constant:
        raise ConstraintError(Note(
            "constraint {!r}: no parameter left after simplification (always "
            f"{'true' if diff.const <= 0 else 'false'})", text))
    coef = np.array([diff.coef.get(n, 0.0) for n in known])
    con = LinearConstraint(expr=text, coef=coef, rhs=-diff.const, names=known)
    logger.debug("parsed constraint %r as %s", text, con.describe())
    return con


def parse_constraints(texts: Iterable[str], names: Sequence[str]) -> tuple[LinearConstraint, ...]:
    """Parse several constraints over the same parameter names (see :func:`parse_constraint`)."""
    if isinstance(texts, str):
        raise ConstraintError(Note("expected a list of constraints, got one string {!r}", texts))
    return tuple(parse_constraint(t, names) for t in texts)
