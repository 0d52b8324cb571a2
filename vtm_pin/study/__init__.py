"""Studies of many cases.

Study files to cases (``cases``: a new study axis goes here), running them in process, on
a pool or on a Dask cluster with a resumable store (``runner``), the executors that run
them (``executors``: a new executor goes here) and the study report (``report``).

May import: outputs and everything below it; not :mod:`vtm_pin.calibration`.
"""
