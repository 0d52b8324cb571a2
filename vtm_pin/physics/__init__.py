"""The robot and its laws.

URDF models and drives (``robot``), generated chains (``chain``), kinematics, payloads,
brake friction laws (``friction``: a new friction law goes here), drive laws (``drives``),
the brake state machine (``brakes``) and the stop categories (``stop``).

May import: numerics, standards, files, schemas and exceptions.
"""
