"""Sim-to-real gap diagnosis: where the model misses, which unmodelled effect, how far it shrinks.

`diagnose(capture, unit, holdout=...)` -> `Diagnosis` (docs/formats.md, schema "bench-ctl/diagnosis/1");
`blind` generates and scores the blind suite.
"""
from bench_ctl.identification.localize import DiagnosisError

from .diagnose import SCHEMA, Budget, diagnose
from .diagnosis_file import BaseFit, Diagnosis, EffectEntry, Step, read_diagnosis

__all__ = ["SCHEMA", "BaseFit", "Budget", "Diagnosis", "DiagnosisError", "EffectEntry", "Step", "diagnose",
           "read_diagnosis"]
