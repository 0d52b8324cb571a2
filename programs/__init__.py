"""Programs shipped with vtm_pin (joint trajectories as CSV), read as package data."""
