"""The model catalogue: the parameters (`params`) of the reference unit, its effects and the grid,
the diagnosis' unmodelled effects (`effects`), the standard excitation structures (`structures`),
and the translation between a structure's standard names and the engine's (`dialect`)."""
