"""Exceptions raised by vtm_pin, all rooted in :class:`VtmError`."""

from __future__ import annotations

from collections.abc import Sequence

#: Fixed-base arms of example-robot-data named first when a robot is not found.
_ARMS = ("ur3", "ur5", "ur10", "panda", "kinova", "xarm7", "z1", "so100")


class VtmError(Exception):
    """Base class of every error vtm_pin raises on purpose."""


class RobotNotFound(VtmError):
    """A robot name is neither a URDF path, a file in ``robots/`` nor an example-robot-data name."""

    def __init__(self, name: str, local: Sequence[str], remote: Sequence[str]) -> None:
        self.name = name
        self.local = list(local)
        self.remote = list(remote)
        arms = [r for r in _ARMS if r in self.remote]
        more = len(self.remote) - len(arms)
        super().__init__(
            f"Robot '{name}' not found: not a URDF path, not in robots/ ({', '.join(local)}), "
            f"and not an example-robot-data name ({', '.join(arms)} and {more} more)"
        )


class RobotLoadError(VtmError):
    """A URDF file exists but Pinocchio could not build a model from it."""

    def __init__(self, source: str, reason: str) -> None:
        self.source = source
        self.reason = reason
        super().__init__(f"Could not load robot from '{source}': {reason}")


class UnsupportedJoint(VtmError):
    """A joint whose configuration and velocity dimensions differ (continuous, spherical, free)."""

    def __init__(self, joint: str, kind: str) -> None:
        self.joint = joint
        self.kind = kind
        super().__init__(
            f"Joint '{joint}' of type {kind} is not supported: vtm_pin needs joints with "
            "nq = nv (revolute with limits, prismatic); use 'revolute' instead of 'continuous'"
        )


class JointNotFound(VtmError):
    """A joint name that the model does not have."""

    def __init__(self, name: str, joints: Sequence[str]) -> None:
        self.name = name
        self.joints = list(joints)
        super().__init__(f"Joint '{name}' not in the model; its joints are: {', '.join(joints)}")


class ScenarioError(VtmError):
    """A scenario file is malformed: names the file, the key and what is allowed."""

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source = source
        self.key = key
        self.problem = problem
        where = f"{source}: " if source else ""
        key_text = f"'{key}': " if key else ""
        super().__init__(f"{where}{key_text}{problem}")


class TransitionError(VtmError):
    """A transition could not be computed (redundant or rank-deficient constraints)."""


class SimulationError(VtmError):
    """The simulation diverged or was asked for something it cannot do."""


class BrakeError(VtmError):
    """A brake or stop figure is out of range."""


class ConstraintError(VtmError):
    """A holonomic constraint is malformed, redundant, or cannot be met."""


class VtmWarning(UserWarning):
    """Something was corrected or assumed on the user's behalf; the run goes on."""
