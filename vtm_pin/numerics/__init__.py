"""The mechanics' numerics, independent of any particular robot.

M, bias forces and locked forward dynamics (``dynamics``), lock Jacobians
(``constraints``), the transition rules (``transitions/``: a new transition rule goes here)
and the integrators (``integrators/``).

May import: :mod:`vtm_pin.exceptions`.
"""
