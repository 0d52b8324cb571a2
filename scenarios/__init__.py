"""Scenario files shipped with vtm_pin, read as package data (``vtm-pin run pendulum3r``)."""
