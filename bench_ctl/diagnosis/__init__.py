"""Sim-to-real gap diagnosis: where the model misses, which unmodelled effect, how far it shrinks.

`diagnose(capture, unit, holdout=...)` -> diagnosis dict (docs/formats.md, schema "bench-ctl/diagnosis/1");
`blind` generates and scores the blind suite.
"""
from .diagnose import SCHEMA, Budget, diagnose
from .localize import DiagnosisError

__all__ = ["SCHEMA", "Budget", "DiagnosisError", "diagnose"]
