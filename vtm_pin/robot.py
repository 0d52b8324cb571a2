"""Robot models: load a URDF into Pinocchio and attach drive (gear, rotor) data."""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from .exceptions import JointNotFound, RobotLoadError, RobotNotFound, UnsupportedJoint

#: Folder of the URDF models shipped with the project.
ROBOTS_DIR = Path(__file__).resolve().parent.parent / "robots"


@dataclass(frozen=True)
class Drive:
    """Gear and motor data of one joint.

    Attributes:
        gear_ratio: Motor angle per joint angle [-] (motor side = ratio x joint side).
        rotor_inertia: Rotor inertia about its axis, motor side [kg m^2].
    """

    gear_ratio: float = 1.0
    rotor_inertia: float = 0.0

    @property
    def armature(self) -> float:
        """Reflected rotor inertia on the joint side, ratio^2 x rotor inertia [kg m^2]."""
        return self.gear_ratio**2 * self.rotor_inertia


@dataclass(frozen=True)
class Robot:
    """A Pinocchio model whose joints each have one degree of freedom (nq = nv).

    Attributes:
        name: Name the robot was asked for.
        source: URDF file the model was built from.
        model: Pinocchio model; ``model.armature`` holds the reflected rotor inertias.
        joints: Joint names in velocity order, one per coordinate of ``q`` and ``v``.
        gear_ratio: Gear ratio per joint [-], 1 where no drive is given.
        tool_frame: Frame whose path the stopping report follows (the tool centre point).
        assumptions: Stated assumptions behind the model's figures (from the robot's
            ``<name>.yaml`` beside its URDF), quoted by reports.
    """

    name: str
    source: str
    model: pin.Model
    joints: tuple[str, ...]
    gear_ratio: np.ndarray
    tool_frame: str = ""
    assumptions: tuple[str, ...] = ()

    @property
    def nv(self) -> int:
        """Number of generalized coordinates (= nq = nv)."""
        return int(self.model.nv)

    def joint_index(self, name: str) -> int:
        """Index of joint ``name`` in ``q`` and ``v``.

        Raises:
            JointNotFound: The model has no such joint.
        """
        try:
            return self.joints.index(name)
        except ValueError:
            raise JointNotFound(name, self.joints) from None

    def joint_indices(self, names: Sequence[str]) -> list[int]:
        """Indices of several joints in ``q`` and ``v``, in the given order."""
        return [self.joint_index(name) for name in names]


def list_local_robots() -> list[str]:
    """Names of the URDF models in ``robots/`` (file stems)."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.urdf"))


def list_example_robots() -> list[str]:
    """Names that example-robot-data can load."""
    from example_robot_data.robots_loader import ROBOTS

    return sorted(ROBOTS)


def load_robot(
    spec: str | Path,
    drives: Mapping[str, Drive] | None = None,
    base_dir: Path | None = None,
) -> Robot:
    """Load a robot by URDF path, by name of a file in ``robots/``, or by example-robot-data name.

    Args:
        spec: A path to a ``.urdf`` file, the stem of a file in ``robots/`` (``planar_3r``)
            or an example-robot-data name (``ur5``, ``panda``).
        drives: Gear ratio and rotor inertia per joint name. Pinocchio's ``crba`` and ``aba``
            ignore ``model.rotorInertia``, so the reflected inertia ratio^2 x J_rotor is
            written into ``model.armature``.
        base_dir: Folder that relative URDF paths are resolved against (the scenario's).

    Returns:
        The loaded robot.

    Raises:
        RobotNotFound: ``spec`` names no robot.
        RobotLoadError: The URDF exists but does not parse.
        UnsupportedJoint: A joint has nq != nv (``continuous``, spherical, free-flyer).
        JointNotFound: ``drives`` names a joint the model does not have.
    """
    text = str(spec)
    path = Path(text)
    if not path.is_absolute() and base_dir is not None and (base_dir / path).exists():
        path = base_dir / path
    if path.suffix.lower() == ".urdf" or path.exists():
        if not path.is_file():
            raise RobotLoadError(text, "no such file")
        model = _build_from_urdf(path)
        source = str(path)
    elif (ROBOTS_DIR / f"{text}.urdf").is_file():
        source = str(ROBOTS_DIR / f"{text}.urdf")
        model = _build_from_urdf(Path(source))
    elif text in list_example_robots():
        import example_robot_data as erd

        try:
            wrapper = erd.load(text)
        except Exception as exc:  # the loader raises bare exceptions of several kinds
            raise RobotLoadError(text, str(exc)) from exc
        model = wrapper.model
        source = str(getattr(wrapper, "urdf", text))
    else:
        raise RobotNotFound(text, list_local_robots(), list_example_robots())
    joints = _check_joints(model)
    sidecar = _read_sidecar(Path(source).with_suffix(".yaml"))
    all_drives = {**sidecar.get("drives", {}), **(drives or {})}
    gear_ratio = np.ones(len(joints))
    for joint, drive in all_drives.items():
        if joint not in joints:
            raise JointNotFound(joint, joints)
        i = joints.index(joint)
        gear_ratio[i] = drive.gear_ratio
        model.armature[i] = drive.armature
        model.rotorGearRatio[i] = drive.gear_ratio
        model.rotorInertia[i] = drive.rotor_inertia
    tool_frame = sidecar.get("tool_frame") or _default_tool_frame(model)
    if not model.existFrame(tool_frame):
        raise RobotLoadError(source, f"tool frame '{tool_frame}' is not a frame of the model")
    return Robot(
        name=text,
        source=source,
        model=model,
        joints=joints,
        gear_ratio=gear_ratio,
        tool_frame=tool_frame,
        assumptions=tuple(sidecar.get("assumptions", ())),
    )


def _read_sidecar(path: Path) -> dict[str, Any]:
    """Drives, tool frame and assumptions from ``<urdf stem>.yaml``, if that file exists."""
    if not path.is_file():
        return {}
    try:
        raw = yaml.safe_load(path.read_text()) or {}
        if not isinstance(raw, dict) or set(raw) - {"drives", "tool_frame", "assumptions"}:
            raise ValueError("keys must be drives, tool_frame, assumptions")
        drives = {
            str(joint): Drive(float(d.get("gear_ratio", 1.0)), float(d.get("rotor_inertia", 0.0)))
            for joint, d in (raw.get("drives") or {}).items()
        }
    except (yaml.YAMLError, ValueError, AttributeError, TypeError) as exc:
        raise RobotLoadError(str(path), f"bad robot data file: {exc}") from exc
    return {
        "drives": drives,
        "tool_frame": raw.get("tool_frame"),
        "assumptions": [str(a) for a in raw.get("assumptions") or []],
    }


def _default_tool_frame(model: pin.Model) -> str:
    """``tool0`` if the model has it, else its last frame."""
    names = [frame.name for frame in model.frames]
    return "tool0" if "tool0" in names else names[-1]


def _build_from_urdf(path: Path) -> pin.Model:
    """Parse a URDF with urdfdom's own messages caught instead of printed to stderr."""
    with tempfile.TemporaryFile(mode="w+") as log:
        saved = os.dup(2)
        sys.stderr.flush()
        os.dup2(log.fileno(), 2)
        try:
            model = pin.buildModelFromUrdf(str(path))
            error = None
        except (RuntimeError, ValueError) as exc:
            error = exc
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        log.seek(0)
        details = [line.strip() for line in log if line.strip().startswith("Error:")]
    if error is not None:
        reason = details[0].removeprefix("Error:").strip() if details else str(error).strip()
        raise RobotLoadError(str(path), reason) from error
    return model


def _check_joints(model: pin.Model) -> tuple[str, ...]:
    names = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nq != joint.nv or joint.nv != 1:
            raise UnsupportedJoint(model.names[jid], joint.shortname())
        names.append(model.names[jid])
    order = np.argsort([model.joints[j].idx_v for j in range(1, model.njoints)])
    return tuple(names[i] for i in order)
