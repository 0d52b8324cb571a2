"""The hybrid simulation.

What to simulate (``problem``), topologies and loop closures, one smooth phase
(``phase``), the scalar hybrid loop (``simulation``), the batched engine (``batch``) and
the frozen records of a run (``results``).

May import: physics and everything below it.
"""
