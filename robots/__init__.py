"""Robot models shipped with vtm_pin (URDF and robot data files), read as package data."""
