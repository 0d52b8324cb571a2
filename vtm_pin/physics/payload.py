"""A rigid payload attached to a frame of the robot: a tool, a gripped part, a load.

The payload is a rigid body fixed to one frame of the robot (the tool frame by default). Its
spatial inertia is added to the body of that frame's parent joint, exactly as a URDF parser
merges a link fixed to its parent: the joint carrying the frame then moves the payload with
it. The scenario key ``payload`` gives

- ``mass`` [kg], at least 0,
- ``com``, its centre of mass [m] in the frame's coordinates,
- ``inertia`` (optional), its rotational inertia about the centre of mass [kg m^2], in the
  frame's axes, as URDF's ``{ixx, iyy, izz, ixy, ixz, iyz}``; a point mass when omitted,
- ``frame`` (optional), the frame it is fixed to; the robot's tool frame when omitted.

The robot given to :func:`attach_payload` is left unchanged: it returns a new
:class:`~vtm_pin.physics.robot.Robot` with a copy of the Pinocchio model. :func:`attached`
keeps the robots it made in the robot's cache, so the cases of a study that share a payload
(its classes) share one robot, with its Pinocchio ``Data`` and reduced models.
"""

from __future__ import annotations

import dataclasses
import math
import weakref
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np
import pinocchio as pin

from ..exceptions import PayloadError, excerpt
from ..files.model_cache import ModelCache
from .robot import INERTIA_RTOL, MAX_MASS, MAX_OFFSET, Robot, inertia_problem

#: Entries of the URDF form of a rotational inertia, in the order of its YAML key.
INERTIA_KEYS = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
#: Entries that must be given (the off-diagonal products of inertia default to 0).
REQUIRED_INERTIA_KEYS = ("ixx", "iyy", "izz")
#: Payloads whose robots :func:`attached` keeps per robot: a study's payload classes (six in
#: ``studies/ur10_envelope.yaml``); a drawn payload differs case by case and is built anew.
KEPT_PAYLOADS = 16
#: Units of the fields of :func:`payload_summary`.
UNITS = {"mass": "kg", "com": "m", "inertia": "kg m^2"}


@dataclass(frozen=True)
class Payload:
    """A rigid body fixed to a frame of the robot.

    Construction only normalises the types (``com`` to a tuple of three floats, ``inertia``
    to a read-only (3, 3) float array); :func:`check_payload` judges whether it is physical.

    Attributes:
        mass: Mass [kg], in [0, MAX_MASS].
        com: Centre of mass [m], in the coordinates of ``frame``.
        inertia: Rotational inertia about the centre of mass [kg m^2], shape (3, 3), in the
            axes of ``frame``; None for a point mass (no rotational inertia).
        frame: Frame the payload is fixed to; "" for the robot's tool frame.

    Raises:
        PayloadError: ``mass`` is not a number, ``com`` not three numbers, or ``inertia``
            not a 3 x 3 matrix of numbers (``.key`` names the field).
    """

    mass: float
    com: tuple[float, float, float]
    inertia: np.ndarray | None = None
    frame: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "mass", _to_float(self.mass, "mass", "a number [kg]"))
        object.__setattr__(self, "com", _to_vector(self.com))
        if self.inertia is not None:
            object.__setattr__(self, "inertia", _to_matrix(self.inertia))
        object.__setattr__(self, "frame", str(self.frame))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Payload):
            return NotImplemented
        same_inertia = (self.inertia is None and other.inertia is None) or (
            self.inertia is not None
            and other.inertia is not None
            and bool(np.array_equal(self.inertia, other.inertia))
        )
        return (self.mass, self.com, self.frame) == (other.mass, other.com, other.frame) and (
            same_inertia
        )

    def __hash__(self) -> int:
        # + 0.0 turns -0.0 into 0.0, which compare equal, so that they hash alike.
        inertia = None if self.inertia is None else (self.inertia + 0.0).tobytes()
        return hash((self.mass, self.com, inertia, self.frame))


def inertia_matrix(values: Mapping[str, float]) -> np.ndarray:
    """The rotational inertia matrix given by its URDF entries.

    Args:
        values: ``ixx``, ``iyy``, ``izz`` (required) and ``ixy``, ``ixz``, ``iyz`` (default 0)
            [kg m^2], as in a URDF ``<inertia>`` element.

    Returns:
        The symmetric (3, 3) matrix [kg m^2]; whether it is physical is checked by
        :func:`check_payload`.

    Raises:
        PayloadError: An entry is missing, unknown or not a number (key ``inertia`` or
            ``inertia.<entry>``).
    """
    unknown = [str(k) for k in values if k not in INERTIA_KEYS]
    if unknown:
        raise PayloadError(
            "inertia",
            f"unknown entry '{excerpt(unknown[0])}'; the entries are {', '.join(INERTIA_KEYS)} "
            "[kg m^2]",
        )
    for key in REQUIRED_INERTIA_KEYS:
        if key not in values:
            raise PayloadError(
                f"inertia.{key}",
                f"missing; give {', '.join(REQUIRED_INERTIA_KEYS)} [kg m^2] (the products of "
                "inertia ixy, ixz, iyz default to 0)",
            )
    entry = {
        key: _to_float(values.get(key, 0.0), f"inertia.{key}", "a number [kg m^2]")
        for key in INERTIA_KEYS
    }
    return np.array(
        [
            [entry["ixx"], entry["ixy"], entry["ixz"]],
            [entry["ixy"], entry["iyy"], entry["iyz"]],
            [entry["ixz"], entry["iyz"], entry["izz"]],
        ]
    )


def payload_frame(robot: Robot, payload: Payload) -> str:
    """Name of the frame the payload is fixed to: its ``frame``, else the robot's tool frame."""
    return payload.frame or robot.tool_frame


def check_payload(robot: Robot, payload: Payload) -> str:
    """Refuse a payload that is not physical or names a frame the robot does not have.

    The rules are those of the robot's own links (:func:`vtm_pin.physics.robot.inertia_problem`):
    a finite mass in [0, MAX_MASS] kg, a centre of mass within MAX_OFFSET m of the frame
    along each axis, and a rotational inertia that is symmetric, positive semi-definite,
    at most MAX_MOMENT kg m^2 and whose principal moments obey the triangle inequality (with
    the relative slack INERTIA_RTOL of the largest moment for rounded figures).

    Args:
        robot: The robot the payload is for.
        payload: The payload.

    Returns:
        Name of the frame it is fixed to (see :func:`payload_frame`).

    Raises:
        PayloadError: ``.key`` is ``mass``, ``com``, ``inertia`` or ``frame``.
    """
    mass = payload.mass
    if not (math.isfinite(mass) and 0.0 <= mass <= MAX_MASS):
        raise PayloadError(
            "mass", f"{mass:g} kg is not allowed; give a finite mass in [0, {MAX_MASS:g}] kg"
        )
    if not all(math.isfinite(x) and abs(x) <= MAX_OFFSET for x in payload.com):
        raise PayloadError(
            "com",
            f"{_format_vector(np.array(payload.com))} m is not allowed; give finite "
            f"coordinates, each within {MAX_OFFSET:g} m of the frame's origin",
        )
    if payload.inertia is not None:
        _check_inertia(payload.inertia, mass)
    frame = payload_frame(robot, payload)
    _carrier(robot, frame)
    return frame


def _carrier(robot: Robot, frame: str) -> tuple[int, pin.SE3]:
    """The joint that moves ``frame`` and the frame's placement in it, checked.

    Kept in the robot's kinematic cache by frame name (a study's cases attach to one frame;
    a refused frame is not kept, see :class:`~vtm_pin.files.model_cache.ModelCache`).

    Raises:
        PayloadError: ``.key`` is ``frame``: no such frame, or it is fixed to the ground.
    """

    def find() -> tuple[int, pin.SE3]:
        model = robot.model
        if not model.existFrame(frame):
            frames = ", ".join(f.name for f in model.frames)
            raise PayloadError("frame", f"no frame '{excerpt(frame)}'; frames: {frames}")
        found = model.frames[model.getFrameId(frame)]
        if found.parentJoint == 0:
            moving = ", ".join(f.name for f in model.frames if f.parentJoint != 0)
            raise PayloadError(
                "frame",
                f"frame '{excerpt(frame)}' is fixed to the ground, so a payload on it would "
                f"never move; give a frame that a joint moves: {moving}",
            )
        return int(found.parentJoint), pin.SE3(found.placement)

    return robot.cache.get(("payload_carrier", frame), find, kinematic=True)


def attach_payload(robot: Robot, payload: Payload) -> Robot:
    """The robot with the payload rigidly fixed to its frame.

    The payload's spatial inertia, placed at ``frame.placement * SE3(I, com)``, is added to
    the inertia of the body of the frame's parent joint, in a copy of the Pinocchio model.
    Armature, limits and every other field are kept. A payload of mass 0 (a point mass)
    leaves the dynamics exactly as they were.

    Args:
        robot: The robot; it is left unchanged.
        payload: The payload.

    Returns:
        A copy of ``robot`` whose ``model`` carries the payload.

    Raises:
        PayloadError: The payload is not physical or its frame is not in the model
            (see :func:`check_payload`).
    """
    jid, placement = _carrier(robot, check_payload(robot, payload))
    model = pin.Model(robot.model)
    parameters = None  # the bodies' parameters: the robot's, the payload's added
    if payload.mass > 0.0:  # mass 0 has no inertia either (check_payload): nothing to add
        body = _body_inertia(payload.mass, payload.inertia)
        body.lever = np.array(payload.com)
        placed = placement.act(body)  # in the joint's frame
        model.inertias[jid] = model.inertias[jid] + placed
        parameters = body_parameters(robot).copy()  # the other bodies are the robot's
        parameters[jid] = model.inertias[jid].toDynamicParameters()
        parameters.flags.writeable = False
    loaded = dataclasses.replace(robot, model=model)
    loaded.cache.share_kinematics(robot.cache)  # the same joints: its kinematic entries hold
    if parameters is not None:
        loaded.cache.get(PARAMETERS, lambda: parameters)
        made = Attachment(weakref.ref(robot), jid, payload.mass, tuple(placed.lever.tolist()))
        loaded.cache.get(ATTACHMENT, lambda: made)
    return loaded


#: The key of a payload copy's :class:`Attachment` in its cache.
ATTACHMENT = "attachment"


@dataclass(frozen=True)
class Attachment:
    """What :func:`attach_payload` added to a robot, kept in the copy's cache.

    (A payload copy's gravity bound is then bounded from its robot's, see
    :func:`vtm_pin.outputs.flags.holding_flags`.)

    Attributes:
        robot: The robot without the payload, by weak reference (None once it is gone).
        joint: Pinocchio's index of the joint whose body carries the payload.
        mass: The payload's mass [kg], above 0.
        lever: Its centre of mass in that joint's frame [m].
    """

    robot: weakref.ref[Robot]
    joint: int
    mass: float
    lever: tuple[float, ...]


def attachment(robot: Robot) -> Attachment | None:
    """How ``robot`` was made by :func:`attach_payload` with a payload of mass > 0, or None."""
    found = robot.cache.find(ATTACHMENT)
    return found if isinstance(found, Attachment) else None


#: The key of :func:`body_parameters` in a robot's cache.
PARAMETERS = "body_parameters"


def body_parameters(robot: Robot) -> np.ndarray:
    """Each body's dynamic parameters, kept in the robot's cache (read-only).

    Pinocchio's ``toDynamicParameters`` of each joint's body (joint 0, the world, first):
    mass [kg], first moment m c [kg m] and rotational inertia about the joint's origin
    [kg m^2], shape (njoints, 10), to the bit. A robot with a payload has them from
    :func:`attach_payload`, which reads only the body it changed (its report's gravity bound,
    its batch key and its lane's compiled dynamics then read no inertia).
    """

    def read() -> np.ndarray:
        parameters = np.array([inertia.toDynamicParameters() for inertia in robot.model.inertias])
        parameters.flags.writeable = False
        return parameters

    return robot.cache.get(PARAMETERS, read)


def attached(robot: Robot, payload: Payload) -> Robot:
    """:func:`attach_payload`, the robot kept in ``robot``'s cache for the next equal payload.

    Equal to the bit (mass, centre of mass, inertia and frame as stored): the same robot,
    whose Pinocchio ``Data`` and reduced models its runs then share (every call computes what
    it reads, see :mod:`vtm_pin.files.model_cache`). Measured on the UR10 envelope study's
    six payload classes (issue 27): a case's build takes ~0.17 ms less, as its copy of the
    model, its ``Data`` and its Annex-B evaluator's are not made again. Up to
    :data:`KEPT_PAYLOADS` payloads a robot, least recently used evicted; a payload
    drawn case by case misses and costs a look-up more than :func:`attach_payload`.

    Raises:
        PayloadError: As :func:`attach_payload` (nothing is kept then).
    """
    inertia = None if payload.inertia is None else payload.inertia.tobytes()
    key = (np.array([payload.mass, *payload.com]).tobytes(), inertia, payload.frame)
    kept = robot.cache.get("payloads", lambda: ModelCache(KEPT_PAYLOADS))
    return kept.get(key, lambda: attach_payload(robot, payload))


def describe_payload(payload: Payload, frame: str) -> str:
    """One line stating the payload assumption for reports, SI units.

    Args:
        payload: The payload.
        frame: The frame it is fixed to (:func:`payload_frame`: the tool frame when
            ``payload.frame`` is "").

    Returns:
        For example "Payload 5 kg rigidly attached to frame tool0, centre of mass at
        [0, 0, 0.05] m in that frame, a point mass (no rotational inertia)."
    """
    head = (
        f"Payload {_number(payload.mass)} kg rigidly attached to frame {frame}, centre of mass "
        f"at {_format_vector(np.array(payload.com))} m in that frame, "
    )
    if payload.inertia is None:
        return head + "a point mass (no rotational inertia)."
    inertia = payload.inertia
    entries = {
        "ixx": inertia[0, 0],
        "iyy": inertia[1, 1],
        "izz": inertia[2, 2],
        "ixy": inertia[0, 1],
        "ixz": inertia[0, 2],
        "iyz": inertia[1, 2],
    }
    shown = ", ".join(f"{key} {_number(value)}" for key, value in entries.items())
    return head + f"rotational inertia about the centre of mass {shown} kg m^2 in the frame's axes."


def payload_summary(payload: Payload, frame: str) -> dict[str, Any]:
    """The payload as JSON-ready data (floats, lists and strings only).

    Args:
        payload: The payload.
        frame: The frame it is fixed to (see :func:`describe_payload`).

    Returns:
        ``mass`` [kg], ``com`` [m] (3 numbers in the frame), ``inertia`` [kg m^2] (3 x 3
        nested lists about the centre of mass, or None for a point mass), ``frame`` and
        ``units`` (the unit of each figure).
    """
    inertia = None if payload.inertia is None else payload.inertia.tolist()
    return {
        "mass": payload.mass,
        "com": list(payload.com),
        "inertia": inertia,
        "frame": frame,
        "units": dict(UNITS),
    }


def _check_inertia(inertia: np.ndarray, mass: float) -> None:
    """Refuse an unphysical rotational inertia about the centre of mass [kg m^2]."""
    if not np.all(np.isfinite(inertia)):
        raise PayloadError("inertia", "has an entry that is nan or inf; give finite kg m^2")
    asymmetry = float(np.max(np.abs(inertia - inertia.T)))
    if asymmetry > INERTIA_RTOL * float(np.max(np.abs(inertia))):
        raise PayloadError(
            "inertia",
            f"is not symmetric (entries differ by up to {asymmetry:.4g} kg m^2 across the "
            "diagonal); give a symmetric matrix, as ixx, iyy, izz, ixy, ixz, iyz",
        )
    problem = inertia_problem(_body_inertia(0.0, inertia))
    if problem is not None:
        raise PayloadError("inertia", problem)
    if mass == 0.0 and np.any(inertia != 0.0):
        raise PayloadError(
            "inertia",
            "a payload of mass 0 kg cannot have a rotational inertia; give a mass > 0 or "
            "omit the inertia",
        )


def _body_inertia(mass: float, rotational: np.ndarray | None) -> pin.Inertia:
    """Spatial inertia of a body [kg, kg m^2] with its centre of mass at its frame's origin.

    ``rotational`` None: a point mass. Built through the attributes, since
    ``pin.Inertia(m, c, I)`` refuses a rotational inertia with a slightly negative principal
    moment that :data:`INERTIA_RTOL` allows (and one that :func:`check_payload` must judge
    itself). The matrix is symmetrised first.
    """
    body = pin.Inertia.Zero()
    body.mass = mass
    if rotational is not None:
        body.inertia = 0.5 * (rotational + rotational.T)
    return body


def _to_float(value: object, key: str, allowed: str) -> float:
    """``value`` as a float; PayloadError ``key`` when it is not a real number (or a bool)."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise PayloadError(key, f"{excerpt(value)} is not a number; give {allowed}")
    return float(value)


def _to_vector(value: object) -> tuple[float, float, float]:
    """The centre of mass as three floats [m]."""
    try:
        items = list(value)  # type: ignore[call-overload]
    except TypeError:
        items = []
    if len(items) != 3:
        raise PayloadError("com", f"{excerpt(value)} is not 3 numbers; give [x, y, z] in m")
    x, y, z = (_to_float(item, "com", "[x, y, z] in m") for item in items)
    return (x, y, z)


def _to_matrix(value: object) -> np.ndarray:
    """The rotational inertia as a read-only (3, 3) float array [kg m^2]."""
    try:
        matrix = np.array(value, dtype=float)
    except (TypeError, ValueError):
        matrix = np.zeros(0)
    if matrix.shape != (3, 3):
        raise PayloadError(
            "inertia", "is not a 3 x 3 matrix of numbers; give ixx, iyy, izz, ixy, ixz, iyz"
        )
    matrix.flags.writeable = False
    return matrix


def _number(value: float) -> str:
    """A number for a report line: up to 6 significant digits, no negative zero."""
    return f"{value + 0.0:g}"


def _format_vector(vector: np.ndarray) -> str:
    return "[" + ", ".join(_number(float(x)) for x in vector) + "]"
