"""Calibration to published stopping data.

The stopping-table CSV (``table``), the fit and its uncertainty (``fit``), model classes
compared (``comparison``) and the calibration's files (``report``).

May import: outputs and everything below it; not :mod:`vtm_pin.study`.
"""
