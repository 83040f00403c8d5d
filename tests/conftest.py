"""Fixtures shared by the identification tests: the reference unit and a synthetic truth."""
from __future__ import annotations

import pytest

from bench_ctl.model.unit import Unit, apply_overrides, reference_unit
from truth import TRUTH


@pytest.fixture(scope="session")
def unit() -> Unit:
    return reference_unit()


@pytest.fixture(scope="session")
def truth_unit(unit: Unit) -> Unit:
    return apply_overrides(unit, [f"{k}={v}" for k, v in TRUTH.items()])
