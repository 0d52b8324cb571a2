"""What a signed figure rests on, as pure functions of numbers.

ISO 13855:2024's S and ISO/TS 15066's S_p with the stopping chain (``separation``), and
conservative upper bounds (``bounds``).

May import: :mod:`vtm_pin.exceptions`.
"""
