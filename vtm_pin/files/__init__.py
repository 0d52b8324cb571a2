"""Reading and writing files safely.

Bounded YAML and text input with one-line errors (``inputs``), output folders written all
at once (``staging``), the Pinocchio data cache (``model_cache``), the models kept on disk
between runs (``model_store``) and Ctrl-C handling (``interrupts``).

May import: :mod:`vtm_pin.exceptions` and :mod:`vtm_pin.schemas` only.
"""
