"""Robot models: load a URDF (or a ROS xacro description) into Pinocchio, attach drive data."""

from __future__ import annotations

import contextlib
import importlib.metadata
import io
import math
import os
import re
import stat
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from ..exceptions import (
    JointNotFound,
    RobotDataError,
    RobotLoadError,
    RobotNotFound,
    UnsupportedJoint,
    excerpt,
)
from ..files import model_store
from ..files.inputs import (
    MAX_MASS,
    check_schema,
    number,
    read_yaml,
)
from ..files.model_cache import ModelCache
from ..schemas import definition

#: Folder of the URDF models shipped with the project: ``robots/`` at the top of the source
#: tree, installed as the package data ``vtm_pin.robots`` (so an installed wheel has it too).
ROBOTS_DIR = Path(str(resources.files("vtm_pin.robots")))

#: Drive data per joint name, as a scenario's ``drives`` and a robot data file give them: the
#: scenario schema's ``$defs/drives`` (``vtm_pin/schemas/scenario.schema.json``).
DRIVES_SCHEMA: dict[str, Any] = definition("scenario", "drives")
#: One joint's brake, as a scenario's ``brakes.<joint>`` and a robot data file give it (motor
#: side torques and speeds, times in s): the scenario schema's ``$defs/brake``, a mapping.
BRAKE_SCHEMA: dict[str, Any] = {"type": "object", **definition("scenario", "brake")}
#: Schema of a robot data file: ``<name>.yaml`` beside ``<name>.urdf``, or in ``robots/`` for
#: an example-robot-data name.
ROBOT_DATA_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "properties": {
        "drives": DRIVES_SCHEMA,
        "brakes": {
            "type": "object",
            "additionalProperties": BRAKE_SCHEMA,
            "description": "The robot's brakes per joint name, used by every scenario with a "
            "stop unless it gives that joint's brake itself.",
        },
        "rated_payload": number(
            0.0, MAX_MASS, "The maker's rated (maximum) payload [kg]; larger ones are flagged."
        ),
        "tool_frame": {"type": "string", "description": "Frame followed by stopping reports."},
        "assumptions": {
            "type": "array",
            "items": {"type": "string"},
            "description": "Stated assumptions behind the robot's figures, quoted by reports.",
        },
    },
}

#: Largest URDF file read [bytes].
MAX_URDF_BYTES = 10_000_000
#: Largest link mass [kg], principal moment of inertia [kg m^2], and distance of a centre of
#: mass, joint or frame from its parent frame [m] accepted in a robot model.
MAX_MASS, MAX_MOMENT, MAX_OFFSET = 1.0e5, 1.0e5, 100.0
#: Relative slack of the checks of a link's rotational inertia (positive semi-definite, triangle
#: inequality), as a fraction of its largest principal moment: URDF inertias are often rounded
#: to 4 significant digits, which moves a flat plate's moments (I_z = I_x + I_y) by up to 1e-4.
INERTIA_RTOL = 1.0e-3
#: The mass matrix at the neutral configuration counts as singular when its smallest eigenvalue
#: is below this fraction of its largest (the worst example-robot-data arm: 4e-7).
SINGULAR_RTOL = 1.0e-12


@dataclass(frozen=True)
class Drive:
    """Gear and motor data of one joint.

    Attributes:
        gear_ratio: Motor angle per joint angle [-] (motor side = ratio x joint side).
        rotor_inertia: Rotor inertia about its axis, motor side [kg m^2].
        short_circuit_torque: Peak torque of the motor's short-circuit braking, motor side
            [N m]; 0: the motor does not brake (:class:`~vtm_pin.physics.drives.ShortCircuit`).
        short_circuit_speed: Motor speed of that peak [rad/s], > 0 with short-circuit braking
            (0 without).
    """

    gear_ratio: float = 1.0
    rotor_inertia: float = 0.0
    short_circuit_torque: float = 0.0
    short_circuit_speed: float = 0.0

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any]) -> Drive:
        """A drive from its mapping (a scenario's or robot data file's ``drives.<joint>``).

        Raises:
            ValueError: ``short_circuit_torque`` without ``short_circuit_speed`` or the other
                way round (the message says which key is missing).
        """
        torque = spec.get("short_circuit_torque")
        speed = spec.get("short_circuit_speed")
        if (torque is None) != (speed is None):
            missing = "short_circuit_speed" if speed is None else "short_circuit_torque"
            raise ValueError(
                f"{missing}: short_circuit_torque [N m] and short_circuit_speed [rad/s] go "
                "together (motor side)"
            )
        return cls(
            gear_ratio=float(spec.get("gear_ratio", 1.0)),
            rotor_inertia=float(spec.get("rotor_inertia", 0.0)),
            short_circuit_torque=0.0 if torque is None else float(torque),
            short_circuit_speed=0.0 if speed is None else float(speed),
        )

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
        drives: The drive of every joint that has one (robot data, then the caller's).
        rated_payload: The maker's rated payload [kg] from the robot data file; None if not
            known.
        cache: Reduced models and Pinocchio Data built from ``model`` (see
            :mod:`vtm_pin.files.model_cache`); a new robot, or a copy with another model, starts
            with an empty one. ``model`` must not be changed in place once it is used.
    """

    name: str
    source: str
    model: pin.Model
    joints: tuple[str, ...]
    gear_ratio: np.ndarray
    tool_frame: str = ""
    assumptions: tuple[str, ...] = ()
    drives: Mapping[str, Drive] = field(default_factory=dict)
    rated_payload: float | None = None
    cache: ModelCache = field(default_factory=ModelCache, init=False, repr=False, compare=False)

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
    packages: Mapping[str, str] | None = None,
) -> Robot:
    """Load a robot by URDF or xacro path, by a ``robots/`` name, or by example-robot-data name.

    Args:
        spec: A path to a ``.urdf`` or ``.xacro`` file, the stem of a file in ``robots/``
            (``planar_3r``) or an example-robot-data name (``ur5``, ``panda``).
        drives: Gear ratio and rotor inertia per joint name. Pinocchio's ``crba`` and ``aba``
            ignore ``model.rotorInertia``, so the reflected inertia ratio^2 x J_rotor is
            written into ``model.armature``.
        base_dir: Folder that relative URDF paths are resolved against (the scenario's).
        packages: ROS package name -> folder, for a xacro file's ``$(find pkg)`` and
            ``package://`` (relative folders resolved against ``base_dir``); packages that
            hold the xacro file (a ``package.xml`` above it) are found without it.

    Returns:
        The loaded robot.

    Raises:
        RobotNotFound: ``spec`` names no robot.
        RobotLoadError: The URDF does not parse, its parser reported an error, it has no
            moving joint, or its inertias are not physical (the message names the link).
        RobotDataError: The robot data file beside the URDF is malformed.
        UnsupportedJoint: A joint has nq != nv (``continuous``, spherical, free-flyer).
        JointNotFound: ``drives`` names a joint the model does not have.
    """
    text = str(spec)
    model, source = _load_model(text, base_dir, packages or {})
    joints = _check_joints(model)
    if not joints:
        raise RobotLoadError(
            source, "has no moving joint; vtm-pin needs at least one revolute or prismatic joint"
        )
    _check_geometry(model, source)
    sidecar = _read_sidecar(robot_data_file(text, source), joints)
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
    _check_mass_matrix(model, source)
    tool_frame = sidecar.get("tool_frame") or _default_tool_frame(model)
    if not model.existFrame(tool_frame):
        raise RobotLoadError(
            source, f"tool frame '{excerpt(tool_frame)}' is not a frame of the model"
        )
    return Robot(
        name=text,
        source=source,
        model=model,
        joints=joints,
        gear_ratio=gear_ratio,
        tool_frame=tool_frame,
        assumptions=tuple(sidecar.get("assumptions", ())),
        drives=all_drives,
        rated_payload=sidecar.get("rated_payload"),
    )


class RobotCache:
    """:func:`load_robot` with memory: one load per robot, drives and folder, most recent kept.

    For the many runs of a study or a fit: the robot returned is shared, and nothing in a run
    modifies it (a payload is attached to a copy). A study or fit that varies the drives
    loads a new robot for each; only the :attr:`size` most recently used are kept.
    """

    def __init__(self, size: int = 16) -> None:
        self.size = size
        self._robots = ModelCache(size)  # the same least-recently-used store

    def __call__(
        self,
        spec: str | Path,
        drives: Mapping[str, Drive] | None = None,
        base_dir: Path | None = None,
        packages: Mapping[str, str] | None = None,
    ) -> Robot:
        """The robot :func:`load_robot` returns for these arguments, loaded once."""
        found = tuple(sorted((packages or {}).items()))
        key = (str(spec), tuple(sorted((drives or {}).items())), str(base_dir), found)
        return self._robots.get(
            key, lambda: load_robot(spec, drives=drives, base_dir=base_dir, packages=packages)
        )


def _load_model(
    text: str, base_dir: Path | None, packages: Mapping[str, str]
) -> tuple[pin.Model, str]:
    """The Pinocchio model ``text`` names, and the file it was built from."""
    try:
        path = Path(text)
        if not path.is_absolute() and base_dir is not None and (base_dir / path).exists():
            path = base_dir / path
        is_path = text != "" and (path.suffix.lower() in (".urdf", ".xacro") or path.exists())
        problem = "no such file" if not path.exists() else "not a URDF or xacro file"
        is_file = path.is_file()
        local = ROBOTS_DIR / f"{text}.urdf"
        is_local = not is_path and "/" not in text and text != "" and local.is_file()
    except (OSError, ValueError) as exc:  # a name too long for a path, or with a NUL in it
        raise RobotNotFound(text, list_local_robots(), list_example_robots()) from exc
    if is_path:
        if not is_file:
            raise RobotLoadError(text, problem)
        if path.suffix.lower() == ".xacro":
            folders = {name: str(base_dir / d if base_dir else d) for name, d in packages.items()}
            return _build_from_xacro(path, folders), str(path)
        return _build_from_urdf(path), str(path)
    if is_local:
        return _build_from_urdf(local), str(local)
    if text not in list_example_robots():
        raise RobotNotFound(text, list_local_robots(), list_example_robots())
    model, source = _EXAMPLE_MODELS.get(text, lambda: _load_example(text))
    return pin.Model(model), source  # a copy: the caller writes its armature


def _load_example(name: str) -> tuple[pin.Model, str]:
    """An example-robot-data robot's model, from the models kept on disk if it is there.

    Its loader also builds the meshes (~0.45 s for the UR10), so the model it built is kept
    (:mod:`vtm_pin.files.model_store`, exact, checked against the URDF and the versions).
    """
    versions = {"pinocchio": pin.__version__, "example-robot-data": _version("example-robot-data")}
    kept = model_store.read(name, versions)
    if kept is not None:
        return kept
    import example_robot_data as erd

    with _parser_messages() as messages:
        try:
            wrapper = erd.load(name)
        except Exception as exc:  # the loader raises bare exceptions of several kinds
            raise RobotLoadError(name, excerpt(" ".join(str(exc).split()), 200)) from exc
    _refuse_parser_errors(messages, name)
    source = str(getattr(wrapper, "urdf", name))
    model_store.write(name, versions, wrapper.model, source)
    return wrapper.model, source


def _version(package: str) -> str:
    """The installed version of ``package``; "" if it cannot be told."""
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return ""


#: The example-robot-data models this process has loaded, by name (never modified: copied).
_EXAMPLE_MODELS = ModelCache(16)


def example_models() -> dict[str, tuple[pin.Model, str]]:
    """The example-robot-data models this process has loaded (model, file), by name.

    For :func:`keep_example_models` in another process: a study's pool workers get their
    driver's (~19 kB a UR10 pickled), and do not build them again from the URDF (its loader
    builds the meshes too: ~0.45 s a worker for the UR10).
    """
    return {str(name): entry for name, entry in _EXAMPLE_MODELS.items()}


def keep_example_models(models: Mapping[str, tuple[pin.Model, str]]) -> None:
    """Keep ``models`` (from :func:`example_models`) as this process's loaded ones.

    A pickled Pinocchio model is its original (``==``, and its dynamics to the bit).
    """
    for name, (model, source) in models.items():
        _EXAMPLE_MODELS.get(name, lambda: (model, source))  # noqa: B023 (called at once)


def robot_data_file(spec: str, urdf: str | Path | None = None) -> Path | None:
    """The robot data file of the robot ``spec`` names; None if it has none.

    ``<name>.yaml`` beside the robot's URDF (``urdf`` when it is known, else ``spec`` if it is
    a URDF path; beside ``<name>.xacro`` or ``<name>.urdf.xacro`` too), or, for a name,
    ``robots/<name>.yaml`` (an example-robot-data robot's data
    is kept there too). Only the file's place: whether it is robot data (no ``robot`` key) is
    decided when it is read.
    """
    try:
        candidates = []
        if urdf is not None and str(urdf).lower().endswith((".urdf", ".xacro")):
            candidates.append(_data_beside(Path(urdf)))
        elif Path(spec).suffix.lower() in (".urdf", ".xacro"):
            candidates.append(_data_beside(Path(spec)))
        if spec and "/" not in spec and Path(spec).suffix == "":
            candidates.append(ROBOTS_DIR / f"{spec}.yaml")
        return next((c for c in candidates if c.is_file()), None)
    except (OSError, ValueError):  # a name too long for a path, or with a NUL in it
        return None


def _data_beside(path: Path) -> Path:
    """``<name>.yaml`` beside ``<name>.urdf``, ``<name>.xacro`` or ``<name>.urdf.xacro``."""
    name = path.name
    for suffix in (".xacro", ".urdf"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    return path.with_name(f"{name}.yaml")


def robot_data(spec: str, base_dir: Path | None = None) -> Mapping[str, Any]:
    """The robot data file of ``spec`` (a scenario's ``robot``), parsed and checked; {} if none.

    Raises:
        RobotDataError: The file is malformed; the message names it and the key.
    """
    path = Path(spec)
    if base_dir is not None and not path.is_absolute():
        try:
            if (base_dir / path).exists():
                spec = str(base_dir / path)
        except (OSError, ValueError):
            pass
    found = robot_data_file(spec)
    if found is None:
        return {}
    try:
        stat = found.stat()
    except (OSError, ValueError):
        stat = None
    key = (str(found), stat.st_mtime_ns if stat else 0, stat.st_size if stat else 0)
    return _DATA.get(key, lambda: _parse_robot_data(found))


def _parse_robot_data(path: Path) -> Mapping[str, Any]:
    """A robot data file, parsed and checked (read only: it is shared through the cache)."""
    raw = read_yaml(path, RobotDataError)
    if raw is None or (isinstance(raw, Mapping) and "robot" in raw):
        return {}
    check_schema(raw, ROBOT_DATA_SCHEMA, str(path), RobotDataError)
    return dict(raw)


#: Parsed robot data files by (path, modification time, size): a study builds many cases.
_DATA = ModelCache(16)


def _read_sidecar(path: Path | None, joints: Sequence[str]) -> dict[str, Any]:
    """Drives, tool frame, rated payload and assumptions from the robot data file, if any.

    A file there with a ``robot`` key is a scenario (every scenario names its robot), not
    robot data: it is ignored. Robot data follow :data:`ROBOT_DATA_SCHEMA`, the same rules as
    a scenario's ``drives``.

    Raises:
        RobotDataError: The file is malformed; the message names it and the key.
    """
    try:
        if path is None or not path.is_file():
            return {}
    except (OSError, ValueError):
        return {}
    raw = read_yaml(path, RobotDataError)
    if raw is None or (isinstance(raw, Mapping) and "robot" in raw):
        return {}
    check_schema(raw, ROBOT_DATA_SCHEMA, str(path), RobotDataError)
    drives = {}
    for joint, d in raw.get("drives", {}).items():
        if joint not in joints:
            raise RobotDataError(
                str(path),
                f"drives.{excerpt(joint)}",
                f"unknown joint; the joints are: {', '.join(joints)}",
            )
        try:
            drives[joint] = Drive.from_spec(d)
        except ValueError as exc:
            raise RobotDataError(str(path), f"drives.{excerpt(joint)}", str(exc)) from exc
    for joint in raw.get("brakes", {}):
        if joint not in joints:
            raise RobotDataError(
                str(path),
                f"brakes.{excerpt(joint)}",
                f"unknown joint; the joints are: {', '.join(joints)}",
            )
    rated = raw.get("rated_payload")
    return {
        "drives": drives,
        "tool_frame": raw.get("tool_frame"),
        "assumptions": list(raw.get("assumptions", [])),
        "rated_payload": None if rated is None else float(rated),
    }


def _default_tool_frame(model: pin.Model) -> str:
    """``tool0`` if the model has it, else its last frame."""
    names = [frame.name for frame in model.frames]
    return "tool0" if "tool0" in names else names[-1]


def _build_from_urdf(path: Path) -> pin.Model:
    """Parse a URDF; an error urdfdom reports (even one it then skips) refuses the file."""
    _check_file(path)
    return _build(lambda: pin.buildModelFromUrdf(str(path)), str(path))


#: What ``pip`` installs to read xacro files.
XACRO_EXTRA = "pip install 'vtm_pin[xacro]'"


def _build_from_xacro(path: Path, packages: Mapping[str, str]) -> pin.Model:
    """Expand a xacro file (:func:`xacro_urdf`) and parse the URDF it gives."""
    xml = xacro_urdf(path, packages)
    return _build(lambda: pin.buildModelFromXML(xml), str(path))


def xacro_urdf(path: Path, packages: Mapping[str, str]) -> str:
    """The URDF text a xacro file expands to (xacrodoc, no ROS needed).

    ``$(find pkg)`` and ``package://`` resolve to ``packages``, or to a package holding the
    file (a folder above it with a ``package.xml``). Mesh files are not read.

    Raises:
        RobotLoadError: The file is not a regular UTF-8 file, the xacro extra is missing, or
            xacro cannot expand it (one line saying why).
    """
    _check_file(path)
    try:
        from xacrodoc import XacroDoc
        from xacrodoc import packages as finder
    except ImportError as exc:
        raise RobotLoadError(
            str(path), f"a xacro robot needs the xacro extra: {XACRO_EXTRA}"
        ) from exc
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            finder.reset()  # the package folders of another scenario are forgotten
            finder.update_package_cache(dict(packages))
            xml = XacroDoc.from_file(str(path), resolve_packages=False).to_urdf_string()
    except Exception as exc:  # xacro raises exceptions of many kinds
        raise RobotLoadError(str(path), _xacro_problem(exc)) from exc
    return str(xml)


def _xacro_problem(exc: Exception) -> str:
    """What xacro's exception says, in one line; a missing package says how to give it."""
    cause = getattr(exc, "exc", None) or exc  # xacro wraps the error it met
    if type(cause).__name__ == "PackageNotFoundError":
        return (
            f"xacro: ROS package '{excerpt(' '.join(map(str, cause.args)))}' not found: give "
            "its folder in the scenario's robot_packages (or keep the file inside the package, "
            "below its package.xml)"
        )
    message = re.sub(r"^<class '[\w.]+'>: ", "", " ".join(str(cause).split()))
    return excerpt(f"xacro: {message or type(cause).__name__}", 200)


def _check_file(path: Path) -> None:
    """Refuse what is not a regular UTF-8 text file of at most :data:`MAX_URDF_BYTES`."""
    try:
        if not stat.S_ISREG(path.stat().st_mode):  # a named pipe would hang the readers
            raise RobotLoadError(str(path), "is not a regular file (a folder, pipe or device)")
        with path.open("rb") as file:
            data = file.read(MAX_URDF_BYTES + 1)
        if len(data) > MAX_URDF_BYTES:
            raise RobotLoadError(str(path), f"is larger than {MAX_URDF_BYTES} bytes")
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RobotLoadError(
            str(path), f"is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"
        ) from exc
    except OSError as exc:
        raise RobotLoadError(str(path), f"cannot read the file ({exc.strerror})") from exc


def _build(build: Callable[[], pin.Model], source: str) -> pin.Model:
    """The model ``build`` makes; an error its URDF parser reports refuses it."""
    with _parser_messages() as messages:
        try:
            model = build()
        except (RuntimeError, ValueError) as exc:
            error: Exception | None = exc
        else:
            error = None
    if error is not None:
        reason = messages[0] if messages else " ".join(str(error).split())
        raise RobotLoadError(source, excerpt(reason, 200)) from error
    _refuse_parser_errors(messages, source)
    return model


@contextmanager
def _parser_messages() -> Iterator[list[str]]:
    """Capture what urdfdom writes to stderr; yields its ``Error:`` lines once the block ends."""
    messages: list[str] = []
    with tempfile.TemporaryFile(mode="w+", errors="replace") as log:
        saved = os.dup(2)
        sys.stderr.flush()
        os.dup2(log.fileno(), 2)
        try:
            yield messages
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            log.seek(0)
            for line in log:
                if line.strip().startswith("Error:"):
                    messages.append(line.strip().removeprefix("Error:").strip())


def _refuse_parser_errors(messages: Sequence[str], source: str) -> None:
    """Refuse a model its URDF parser complained about, naming the link when it says which."""
    if not messages:
        return
    links = [m.group(1) for m in (re.search(r"[Ll]ink \[([^\]]*)\]", x) for x in messages) if m]
    where = f"link '{excerpt(links[0])}': " if links else ""
    raise RobotLoadError(source, excerpt(f"{where}{'; '.join(messages)}", 200))


def _link_name(model: pin.Model, jid: int) -> str:
    """The URDF link moved by joint ``jid`` (its body frame), for messages."""
    for frame in model.frames:
        if frame.parentJoint == jid and frame.type == pin.FrameType.BODY:
            return str(frame.name)
    return str(model.names[jid])


def _check_geometry(model: pin.Model, source: str) -> None:
    """Refuse non-physical inertias and placements, naming the link (or frame).

    Each Pinocchio body (a link with the links fixed to it) must have a finite mass in
    [0, MAX_MASS] kg, its centre of mass and every joint and frame within MAX_OFFSET m of
    their parent frame, and a rotational inertia that is positive semi-definite and obeys the
    triangle inequality of principal moments (each at most the sum of the other two).
    """
    for jid in range(1, model.njoints):
        problem = inertia_problem(model.inertias[jid])
        offset = model.jointPlacements[jid].homogeneous
        if problem is None and not (np.all(np.isfinite(offset)) and _within(offset[:3, 3])):
            problem = (
                f"joint '{model.names[jid]}' is placed off its parent (beyond {MAX_OFFSET:g} m)"
            )
        if problem is not None:
            raise RobotLoadError(source, f"link '{excerpt(_link_name(model, jid))}': {problem}")
    for frame in model.frames:
        placement = frame.placement.homogeneous
        if not (np.all(np.isfinite(placement)) and _within(placement[:3, 3])):
            raise RobotLoadError(
                source,
                f"frame '{excerpt(frame.name)}' is placed off its joint (not finite or beyond "
                f"{MAX_OFFSET:g} m)",
            )


def _within(offset: np.ndarray) -> bool:
    return bool(np.max(np.abs(offset)) <= MAX_OFFSET)


def inertia_problem(inertia: pin.Inertia) -> str | None:
    """What is unphysical about one body's inertia, or None."""
    mass = float(inertia.mass)
    lever, rotational = np.asarray(inertia.lever), np.asarray(inertia.inertia)
    if not (math.isfinite(mass) and np.all(np.isfinite(lever)) and np.all(np.isfinite(rotational))):
        return "its inertia is not finite (a mass or moment that is nan or inf)"
    if not 0.0 <= mass <= MAX_MASS:
        return f"mass {mass:g} kg is outside [0, {MAX_MASS:g}] kg"
    if not _within(lever):
        return f"its centre of mass is more than {MAX_OFFSET:g} m from the link frame"
    moments = np.linalg.eigvalsh(0.5 * (rotational + rotational.T))
    shown = ", ".join(f"{x:.4g}" for x in moments)
    slack = INERTIA_RTOL * max(float(moments[-1]), 0.0)
    if moments[0] < -slack:
        return (
            f"rotational inertia is not positive semi-definite (principal moments {shown} kg m^2)"
        )
    if moments[-1] > MAX_MOMENT:
        return f"principal moment {moments[-1]:.4g} kg m^2 is above {MAX_MOMENT:g} kg m^2"
    if moments[2] > moments[0] + moments[1] + slack:
        return (
            f"principal moments {shown} kg m^2 break the triangle inequality (each must be at "
            "most the sum of the other two)"
        )
    return None


def _check_mass_matrix(model: pin.Model, source: str) -> None:
    """Refuse a model whose mass matrix (with rotor inertias) is singular at q = neutral.

    Each moving joint must move some mass or inertia (the links after it, or its rotor): a
    body with zero mass and zero inertia at the end of a chain leaves its joint's row of M
    zero, and forward dynamics would divide by it.
    """
    data = model.createData()
    n = model.nv  # eigenpy gives a 1-joint model's matrices as vectors: shape them back
    M = np.reshape(pin.crba(model, data, pin.neutral(model)), (n, n))
    M = np.triu(M) + np.triu(M, 1).T
    if not np.all(np.isfinite(M)):
        raise RobotLoadError(source, "its mass matrix is not finite (check the joint axes)")
    scale = max(float(np.max(np.abs(M))), np.finfo(float).tiny)
    J = np.reshape(pin.computeJointJacobians(model, data, pin.neutral(model)), (6, n))
    axes = np.linalg.norm(J, axis=0)
    for jid in range(1, model.njoints):
        i = model.joints[jid].idx_v
        if not axes[i] > 0.0:
            raise RobotLoadError(
                source, f"joint '{excerpt(model.names[jid])}' has no axis (its <axis> is zero)"
            )
        if M[i, i] <= SINGULAR_RTOL * scale:
            raise RobotLoadError(
                source,
                f"joint '{excerpt(model.names[jid])}' moves no mass or inertia: link "
                f"'{excerpt(_link_name(model, jid))}' and the links after it have none about its "
                "axis (give them an <inertial> with mass > 0, or the joint a rotor inertia)",
            )
    eigenvalues, vectors = np.linalg.eigh(M)
    if eigenvalues[0] <= SINGULAR_RTOL * eigenvalues[-1]:
        names = [
            model.names[jid]
            for jid in range(1, model.njoints)
            if abs(vectors[model.joints[jid].idx_v, 0]) > 0.1
        ]
        raise RobotLoadError(
            source,
            f"its mass matrix is singular at the neutral configuration: joints "
            f"{', '.join(names)} move no inertia together (check the links' <inertial> data)",
        )


def _check_joints(model: pin.Model) -> tuple[str, ...]:
    names = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nq != joint.nv or joint.nv != 1:
            raise UnsupportedJoint(model.names[jid], joint.shortname())
        names.append(model.names[jid])
    order = np.argsort([model.joints[j].idx_v for j in range(1, model.njoints)])
    return tuple(names[i] for i in order)
