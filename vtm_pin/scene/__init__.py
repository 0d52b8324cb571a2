"""Scenes from files.

The scenario schema and its validation (``scenario``: a file becomes a
:class:`~vtm_pin.core.problem.Problem` plus run settings) and the Annex-B test conditions
(``annex_b``).

May import: core and everything below it.
"""
