"""The stabilisers a unit on the grid can carry, each a plug-in of the engine's seam (`step`): its
states (a tuple), its output added to the exciter's reference, its derivatives, both from the
rotor speed and the electrical power the machine gives.

- `none`: no stabiliser (no states, output 0);
- `ieeest`: IEEEST on the rotor speed, without its notch filters.
"""
