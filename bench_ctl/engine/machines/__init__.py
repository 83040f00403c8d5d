"""The machines the excitation system can drive, each a plug-in of the engine's seam (`step`):
its states (a tuple), its algebra at a state (the terminal voltage and field current the exciter
reads first, then what else it carries from a step's end to the next step's first stage), its
derivatives at a field voltage, and how fast Vt and Ifd move the exciter's ceilings.

- `noload`: the d-axis generator at no load (E'q, E''q), the no-load pulse test's;
- `grid`: a GENROU or GENSAL through RE + j XE to an infinite bus, with the swing equation;
- `recorded`: no machine: a record's Vt and Ifd played back (the excitation system alone, open
  loop).
"""
