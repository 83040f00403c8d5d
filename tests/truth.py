"""The AVR parameters of the synthetic captures in the identification tests: inside the bounds
and constraints of the reference unit, away from its defaults."""
TRUTH = {"KAVR": 200.0, "TA1": 1.0, "TA2": 0.3, "TA3": 0.1, "TA4": 2.0, "TE": 0.03}
