"""Exceptions raised by vtm_pin, all rooted in :class:`VtmError`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

#: Fixed-base arms of example-robot-data named first when a robot is not found.
_ARMS = ("ur3", "ur5", "ur10", "panda", "kinova", "xarm7", "z1", "so100")
#: Longest excerpt of a user's value quoted in a message [characters].
EXCERPT_LENGTH = 60


def excerpt(value: object, limit: int = EXCERPT_LENGTH) -> str:
    r"""A short one-line rendering of a value for a message: ``limit`` characters at most.

    Strings are shown without quotes and with control characters escaped (a newline becomes
    ``\n``); other values by ``repr``. Longer text is cut and ends with "…".
    """
    if isinstance(value, int) and value.bit_length() > 4 * limit:  # repr may refuse: too long
        return (
            f"{'-' if value < 0 else ''}<an integer of {int(value.bit_length() * 0.30103)} digits>"
        )
    text = repr(value)[1:-1] if isinstance(value, str) else repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


class VtmError(Exception):
    """Base class of every error vtm_pin raises on purpose.

    Errors pickle whatever their constructor's arguments (a pool worker's error reaches the
    driver): they are rebuilt from their message and attributes, not by calling ``__init__``.
    """

    def __reduce__(self) -> tuple[Any, ...]:
        return _rebuild, (type(self), self.args, self.__dict__)


def _rebuild(cls: type[VtmError], args: tuple[Any, ...], state: dict[str, Any]) -> VtmError:
    error = cls.__new__(cls)
    error.args = args
    error.__dict__.update(state)
    return error


class RobotNotFound(VtmError):
    """A robot name is neither a URDF path, a file in ``robots/`` nor an example-robot-data name."""

    def __init__(self, name: str, local: Sequence[str], remote: Sequence[str]) -> None:
        self.name = name
        self.local = list(local)
        self.remote = list(remote)
        arms = [r for r in _ARMS if r in self.remote]
        more = len(self.remote) - len(arms)
        super().__init__(
            f"Robot '{excerpt(name)}' not found: not a URDF path, not in robots/ "
            f"({', '.join(local)}), and not an example-robot-data name "
            f"({', '.join(arms)} and {more} more)"
        )


class RobotLoadError(VtmError):
    """A URDF file exists but Pinocchio could not build a model from it."""

    def __init__(self, source: str, reason: str) -> None:
        self.source = source
        self.reason = reason
        super().__init__(f"Could not load robot from '{excerpt(source, 200)}': {reason}")


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
        super().__init__(
            f"Joint '{excerpt(name)}' not in the model; its joints are: {', '.join(joints)}"
        )


class InputError(VtmError):
    """An input file or option is malformed: names the file, the key and what is allowed.

    Attributes:
        source: The file (or ``"command line"``); "" when the input was not read from a file.
        key: Key path in the file (``integrator.dt``, ``events[0].t``); "" for the whole file.
        problem: What is wrong and what is allowed, one line.
    """

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source = source
        self.key = key
        self.problem = problem
        where = f"{source}: " if source else ""
        key_text = f"'{key}': " if key else ""
        super().__init__(f"{where}{key_text}{problem}")


class ScenarioError(InputError):
    """A scenario file is malformed: names the file, the key and what is allowed."""


class RobotDataError(InputError):
    """A robot data file (``<name>.yaml`` beside a URDF) is malformed."""


class OutputError(VtmError):
    """The results of a run cannot be written into their folder.

    Attributes:
        folder: The output folder asked for.
        problem: Why it cannot be written, one line.
    """

    def __init__(self, folder: str, problem: str) -> None:
        self.folder = folder
        self.problem = problem
        super().__init__(f"Cannot write the results: {problem}")


class SettingError(VtmError):
    """A setting of a scenario section is out of range; names its key within the section.

    Raised by the modules that build one section of a scenario (``payload``, ``annex_b``);
    the scenario reader re-raises it as a :class:`ScenarioError` with the full key path.

    Attributes:
        key: Key within the section (``mass``, ``inertia``, ``extension``), "" for all of it.
        problem: What is wrong and what is allowed, one line.
    """

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f"'{key}': {problem}" if key else problem)


class PayloadError(SettingError):
    """A payload is not physical, or names a frame the robot does not have."""


class ConditionsError(SettingError):
    """Annex-B test conditions that the robot cannot be posed or moved in."""


class StudyError(InputError):
    """A study file is malformed, or its output folder holds another study's results."""


class TransitionError(VtmError):
    """A transition could not be computed (redundant or rank-deficient constraints)."""


class SimulationError(VtmError):
    """The simulation diverged or was asked for something it cannot do."""


class ProblemError(SimulationError):
    """A simulation problem the simulation cannot run; names the key in scenario terms.

    Attributes:
        key: The key path (``events[1].lock``, ``brakes``, ``stop.t``).
        problem: What is wrong and what is allowed, one line.
    """

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f"'{key}': {problem}")


class StepLimitError(SimulationError):
    """An integrator would need more steps than its ``max_steps`` allows.

    Attributes:
        steps: Steps needed (fixed step) or taken so far (adaptive).
        limit: The integrator's ``max_steps``.
    """

    def __init__(self, message: str, steps: float, limit: int) -> None:
        self.steps = steps
        self.limit = limit
        super().__init__(message)


class BrakeError(VtmError):
    """A brake or stop figure is out of range."""


class ConstraintError(VtmError):
    """A holonomic constraint is malformed, redundant, or cannot be met."""


class ConstraintNotMet(ConstraintError):
    """A frame constraint activated where its frames are apart (or off its docking target).

    Attributes:
        name: The constraint's name.
        t: Activation time [s].
        distance: Largest residual of its translation rows at activation [m].
        angle: Largest residual of its rotation rows at activation [rad].
    """

    def __init__(
        self, name: str, t: float, distance: float, angle: float, tolerance: float
    ) -> None:
        self.name = name
        self.t = t
        self.distance = distance
        self.angle = angle
        super().__init__(
            f"Constraint '{excerpt(name)}' activates at t = {t:g} s {distance:.3g} m and "
            f"{angle:.3g} rad away from where it holds; it must activate within {tolerance:g} m "
            "and rad of it (move its target or its activation time)"
        )


class VtmWarning(UserWarning):
    """Something was corrected or assumed on the user's behalf; the run goes on."""
