"""Study files shipped with vtm_pin, read as package data (``vtm-pin study ur10_annex_b``)."""
