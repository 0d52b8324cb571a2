"""Calibration: fit the hidden drive and brake figures of a robot to its published stopping data.

Every row of a stopping table (:mod:`vtm_pin.calibration.table`) describes one ISO 10218-1
Annex-B test: the tested joint alone moving at a speed, with a payload, at an extension, in a
direction, stopped in a category. :func:`row_scenario` turns it into the scenario it describes
(the studies' definitions: ``annex_b``, ``payload``, ``stop``), with every joint braked.
:func:`calibrate` then fits the figures named by ``fit`` with
``scipy.optimize.least_squares``, on the published distances and times weighted by their
stated scatter:

    r = ((d_sim - d_pub) / (s_d d_pub), (t_sim - t_pub) / (s_t t_pub))   for every row,

where d is the tested joint's stopping angle [rad], t its stopping time [s] (from the signal
until its speed stays below the rest speed), and s_d, s_t the relative scatter of each (by
default 5 % and 20 %: the published distances are the more reliable figure). The uncertainty of
each fitted figure is the square root of the diagonal of (J^T J)^-1, J the Jacobian of r with
respect to the figures at the optimum: a 1-sigma value if the stated scatter is right. A figure
the table cannot determine (a direction of J^T J with a singular value below
:data:`RANK_RTOL` of the largest, columns scaled to unit norm) is flagged, and the rank is
reported.

The figures (``--fit``): ``delay`` (one brake delay for every joint [s]), ``delay:joint`` (one
per tested joint), ``sliding`` (each tested joint's brake sliding torque, motor side [N m]),
``sliding:shared`` (one for all tested joints), ``static`` / ``static:shared`` (static torque;
otherwise it stays ``STATIC_RATIO`` x the sliding torque), ``rotor_inertia`` /
``rotor_inertia:shared`` (motor side [kg m^2]), ``ramp`` (one brake force rise time [s]), and
the laws that decelerate hardest at the start: ``viscous`` / ``viscous:shared`` (the viscous
brake law's w_v, motor side [rad/s]: the brake torque grows with the slip speed),
``short_circuit`` / ``short_circuit:shared`` (the peak torque of the motors' short-circuit
braking, motor side [N m]) with ``short_circuit_speed`` / ``short_circuit_speed:shared`` (the
motor speed of that peak [rad/s]). Joints the table does not test keep their prior figures,
which are stated as assumptions.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..exceptions import InputError, VtmError, VtmWarning
from ..physics.robot import Robot, RobotCache, load_robot
from .table import (
    StoppingRow,
    StoppingTable,
    check_joints,
    check_robot,
    check_units,
    row_message,
)

if TYPE_CHECKING:
    from ..scene.scenario import Scenario

#: The figures ``fit`` may name: (scenario key, unit, shared by every joint, positive scale).
FIGURES: dict[str, tuple[str, str, bool, bool]] = {
    "delay": ("delay", "s", True, False),
    "delay:joint": ("delay", "s", False, False),
    "sliding": ("sliding_torque", "N m", False, True),
    "sliding:shared": ("sliding_torque", "N m", True, True),
    "static": ("static_torque", "N m", False, True),
    "static:shared": ("static_torque", "N m", True, True),
    "rotor_inertia": ("rotor_inertia", "kg m^2", False, True),
    "rotor_inertia:shared": ("rotor_inertia", "kg m^2", True, True),
    "ramp": ("ramp", "s", True, False),
    "viscous": ("viscous_velocity", "rad/s", False, True),
    "viscous:shared": ("viscous_velocity", "rad/s", True, True),
    "short_circuit": ("short_circuit_torque", "N m", False, True),
    "short_circuit:shared": ("short_circuit_torque", "N m", True, True),
    "short_circuit_speed": ("short_circuit_speed", "rad/s", False, True),
    "short_circuit_speed:shared": ("short_circuit_speed", "rad/s", True, True),
}
#: Scenario keys that live in a joint's drive (the others in its brake).
DRIVE_KEYS = ("gear_ratio", "rotor_inertia", "short_circuit_torque", "short_circuit_speed")
#: Start of the search of a law's figures, in units of the table's fastest motor speed (the
#: speeds) and of the joint's prior sliding torque (the short-circuit torque) [-].
START_SPEED_FRACTION, START_SHORT_CIRCUIT_FRACTION = 1.0, 0.3
DEFAULT_FIT = ("delay", "sliding")
#: Prior brake figures: delay [s], sliding torque as a fraction of the joint's effort limit
#: (joint side, then divided by the gear ratio: motor side; a brake as strong as the drive, so
#: that the search starts where the arm stops rather than falls), static / sliding ratio.
PRIOR_DELAY, PRIOR_EFFORT_FRACTION, STATIC_RATIO = 0.05, 1.0, 1.25
#: Prior rotor inertia [kg m^2] where the robot data give none, when it is fitted.
PRIOR_ROTOR_INERTIA = 1.0e-4
#: Default relative scatter of the published distances and times [-].
DISTANCE_SCATTER, TIME_SCATTER = 0.05, 0.20
#: Singular values of the column-scaled Jacobian below this fraction of the largest mark a
#: direction the table does not determine (finite differences are good to ~1e-6 here).
RANK_RTOL = 1.0e-4
#: Most residual evaluations per fitted figure (a table that does not determine a figure lets
#: it drift; the fit stops here and says so).
MAX_EVALUATIONS_PER_FIGURE = 60
#: Largest delay or ramp fitted [s].
MAX_TIME_FIGURE = 1.0
#: Smallest delay fitted [s]. At 0 a brake engages on a joint that has not started to move,
#: and static friction holds a load that kinetic friction would not: a different branch of
#: the Coulomb model (the outcome jumps between delay 0 and 1e-9 s). Real brakes engage
#: milliseconds after the signal; the search stays on that side.
MIN_DELAY = 1.0e-3
#: Range searched for torques [N m] and rotor inertias [kg m^2]: the scenario's own limits
#: (1e6 N m, 100 kg m^2) with a margin, so that no trial step is refused by the schema.
MIN_POSITIVE, MAX_TORQUE_FIGURE, MAX_INERTIA_FIGURE = 1.0e-9, 1.0e5, 10.0
#: Range searched for the laws' speeds, motor side [rad/s]: from 0.1 rad/s (a law that
#: saturates at once) to the schema's limit (where it is Coulomb's again).
MIN_SPEED_FIGURE, MAX_SPEED_FIGURE = 1.0e-1, 1.0e5
#: Integrator of the row scenarios: adaptive, tight enough that finite differences of the
#: stopping figures (steps of 1e-3 relative) are not noise.
INTEGRATOR = {"method": "dop853", "rtol": 1.0e-10, "atol": 1.0e-12, "output_dt": 1.0e-3}
#: Annex-B direction of each table motion.
DIRECTIONS = {"horizontal": "positive", "down": "down", "up": "up"}
#: The table column each key of a row's scenario comes from, for messages.
_COLUMN_OF = {
    "annex_b.joint": "joint",
    "annex_b.max_speed": "speed_deg_s",
    "annex_b.extension": "extension_pct",
    "annex_b.direction": "motion",
    "payload": "payload_kg",
    "stop.category": "category",
}


class CalibrationError(VtmError):
    """A calibration cannot be set up (an unknown figure, a row the model cannot pose)."""


@dataclass(frozen=True)
class Figure:
    """One fitted figure.

    Attributes:
        name: ``<figure>`` for a shared one, ``<figure>.<joint>`` otherwise.
        key: Scenario key it sets in every joint's brake (or drive) it covers.
        joints: The joints it covers.
        unit: SI unit.
        positive: Fitted on a log scale (torques and inertias), else on [0, 1] s.
    """

    name: str
    key: str
    joints: tuple[str, ...]
    unit: str
    positive: bool


@dataclass(frozen=True)
class RowFit:
    """A table row, published and simulated.

    Attributes:
        row: The row.
        distance: Simulated stopping distance of the tested joint: its largest travel from
            the signal on [rad] (its stopping angle when it stops; a joint that swings back
            is not credited with the swing).
        time: Simulated stopping time of the tested joint [s] (the run's end if it did not
            stop).
        stopped: Whether the tested joint came to rest.
        flags: The kinds of the run's flags (:mod:`vtm_pin.outputs.flags`): a brake that cannot hold
            or stop the load at the row's own test pose makes the fitted figures implausible.
    """

    row: StoppingRow
    distance: float
    time: float
    stopped: bool
    flags: tuple[str, ...] = ()


@dataclass(frozen=True)
class Calibration:
    """The result of a fit.

    Attributes:
        robot: Robot name.
        fit: The figures asked for, as given (``delay``, ``sliding:shared``, ...).
        figures: The fitted figures.
        values: Their fitted values (SI), by figure name.
        uncertainty: 1-sigma uncertainty of each, from the Jacobian (inf if undetermined,
            NaN if held at a bound).
        determined: Whether the table determines each figure.
        at_bound: Whether each figure ended at a bound of its search (a delay of 0, say).
        rows: Published and simulated figures of every row, at the fitted values.
        cost: Half the sum of squared weighted residuals.
        rank: Rank of the weighted Jacobian.
        singular_values: Of the column-scaled Jacobian, largest first.
        evaluations: Residual evaluations (each simulates every row).
        success: Whether least_squares reported convergence.
        message: least_squares' message.
        priors: Brake (and drive) figures of every joint used where not fitted.
        scatter: Relative scatter (distance, time) the residuals were weighted with.
        covariance: Covariance of the figures (SI, square units), from (J^T J)^-1 of the
            weighted residuals; rows and columns of figures held at a bound are 0 (fixed),
            of undetermined ones infinite on the diagonal.
    """

    robot: str
    fit: tuple[str, ...]
    figures: tuple[Figure, ...]
    values: Mapping[str, float]
    uncertainty: Mapping[str, float]
    determined: Mapping[str, bool]
    at_bound: Mapping[str, bool]
    rows: tuple[RowFit, ...]
    cost: float
    rank: int
    singular_values: tuple[float, ...]
    evaluations: int
    success: bool
    message: str
    priors: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    scatter: tuple[float, float] = (DISTANCE_SCATTER, TIME_SCATTER)
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def priors(robot: Robot) -> dict[str, dict[str, Any]]:
    """Prior brake figures of every joint (motor side), and its drive.

    Delay :data:`PRIOR_DELAY`; sliding torque :data:`PRIOR_EFFORT_FRACTION` of the effort
    limit over the gear ratio (1 N m where the URDF gives no effort limit); static torque
    :data:`STATIC_RATIO` x sliding; the drive's gear ratio and rotor inertia as loaded.
    """
    model = robot.model
    out: dict[str, dict[str, Any]] = {}
    for i, joint in enumerate(robot.joints):
        ratio = float(robot.gear_ratio[i])
        effort = float(model.effortLimit[i])
        sliding = PRIOR_EFFORT_FRACTION * effort / ratio if 0.0 < effort < math.inf else 1.0
        rotor = float(model.rotorInertia[i])
        drive = robot.drives.get(joint)
        out[joint] = {
            "delay": PRIOR_DELAY,
            "sliding_torque": sliding,
            "static_torque": STATIC_RATIO * sliding,
            "ramp": 0.0,
            "gear_ratio": ratio,
            "rotor_inertia": rotor,
            "short_circuit_torque": 0.0 if drive is None else drive.short_circuit_torque,
            "short_circuit_speed": 0.0 if drive is None else drive.short_circuit_speed,
        }
    return out


def make_figures(
    fit: Sequence[str],
    tested: Sequence[str],
    joints: Sequence[str] = (),
    shared: Sequence[str] = (),
) -> tuple[Figure, ...]:
    """The figures ``fit`` names, for the joints the fitted rows test (``tested``).

    A shared delay or ramp (the controller's and the brakes' timing) covers every joint of
    the robot (``joints``; the tested ones if not given); other shared figures cover the
    joints of the whole table (``shared``; the tested ones if not given), so that a joint
    left out of a fit gets them too. Per-joint figures cover the tested joints only.

    Raises:
        CalibrationError: An unknown figure, or one named twice.
    """
    figures: list[Figure] = []
    keys: set[str] = set()
    for name in fit:
        if name not in FIGURES:
            raise CalibrationError(
                f"--fit: unknown figure '{name}'; the figures are: {', '.join(FIGURES)}"
            )
        key, unit, is_shared, positive = FIGURES[name]
        if key in keys:
            raise CalibrationError(f"--fit: {key} is named twice ('{name}')")
        keys.add(key)
        base = name.split(":")[0]
        if key == "short_circuit_speed" and not any(
            n.split(":")[0] == "short_circuit" for n in fit
        ):
            raise CalibrationError(
                f"--fit: {name} is the speed of the short-circuit braking's peak: fit it with "
                "short_circuit (its torque), or not at all"
            )
        if is_shared:
            covered = (joints if key in ("delay", "ramp") else shared) or tested
            figures.append(Figure(base, key, tuple(covered), unit, positive))
        else:
            figures += [Figure(f"{base}.{j}", key, (j,), unit, positive) for j in tested]
    return tuple(figures)


def row_scenario(
    row: StoppingRow,
    robot: str,
    values: Mapping[str, float],
    figures: Sequence[Figure],
    prior: Mapping[str, Mapping[str, Any]],
) -> dict[str, Any]:
    """The scenario (parsed-YAML form) of one table row with the figures set to ``values``."""
    drives, brakes = drives_and_brakes(values, figures, prior)
    return {
        "description": f"{row.robot}, table line {row.line}: {row.joint_label or row.joint}",
        "robot": robot,
        "annex_b": {
            "joint": row.joint,
            "speed": 1.0,
            "max_speed": row.speed,
            "extension": row.extension,
            "direction": DIRECTIONS[row.motion],
        },
        "payload": {"mass": row.payload},
        "duration": max(1.0, 3.0 * row.stop_time + 0.5),
        "integrator": dict(INTEGRATOR),
        "drives": drives,
        "stop": {"t": 0.0, "category": row.category},
        "brakes": brakes,
    }


def drives_and_brakes(
    values: Mapping[str, float],
    figures: Sequence[Figure],
    prior: Mapping[str, Mapping[str, Any]],
) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, float]]]:
    """Every joint's drive and brake with the figures set to ``values``, the rest at priors.

    The one rule for both the fit's scenarios and the calibrated fragment: the static torque
    is :data:`STATIC_RATIO` x sliding unless it is fitted, and never below the sliding one.
    """
    spec = {joint: dict(figures) for joint, figures in prior.items()}
    for figure in figures:
        for joint in figure.joints:
            spec[joint][figure.key] = values[figure.name]
    static_fitted = any(f.key == "static_torque" for f in figures)
    drives: dict[str, dict[str, Any]] = {}
    brakes: dict[str, dict[str, Any]] = {}
    for joint, s in spec.items():
        static = s["static_torque"] if static_fitted else STATIC_RATIO * s["sliding_torque"]
        brakes[joint] = {
            "delay": s["delay"],
            "sliding_torque": s["sliding_torque"],
            "static_torque": max(static, s["sliding_torque"]),
            "ramp": s["ramp"],
        }
        if "viscous_velocity" in s:
            brakes[joint] |= {"friction": "viscous", "viscous_velocity": s["viscous_velocity"]}
        drives[joint] = {"gear_ratio": s["gear_ratio"], "rotor_inertia": s["rotor_inertia"]}
        if s["short_circuit_torque"] > 0.0:
            drives[joint] |= {
                "short_circuit_torque": s["short_circuit_torque"],
                "short_circuit_speed": s["short_circuit_speed"],
            }
    return drives, brakes


def row_model(
    row: StoppingRow,
    robot: str,
    values: Mapping[str, float],
    figures: Sequence[Figure],
    prior: Mapping[str, Mapping[str, Any]],
    loader: Callable[..., Robot] = load_robot,
) -> Scenario:
    """The scenario of one row, built and checked (not run).

    Raises:
        CalibrationError: The row's scenario is refused (a pose the robot cannot take, a
            category-1 row: the ramp is not in the table), or a horizontal row whose joint
            moves the tool vertically; one line naming the table file, the row and column.
    """
    from ..scene.scenario import build_scenario

    if row.category != 0:
        raise CalibrationError(
            row_message(
                row,
                "category-1 rows need the drives' ramp, which the table does not give; "
                "calibrate category-0 rows",
                "category",
            )
        )
    raw = row_scenario(row, robot, values, figures, prior)
    try:
        scenario = build_scenario(raw, source="row", name="row", loader=loader)
    except InputError as exc:
        column = next((c for k, c in _COLUMN_OF.items() if f"{exc.key}.".startswith(f"{k}.")), "")
        raise CalibrationError(
            row_message(row, f"its Annex-B scenario is refused: '{exc.key}': {exc.problem}", column)
        ) from exc
    except VtmError as exc:
        raise CalibrationError(row_message(row, f"its Annex-B scenario is refused: {exc}")) from exc
    state = scenario.test_state
    assert state is not None
    if row.motion == "horizontal" and state.vertical:
        raise CalibrationError(
            row_message(
                row,
                f"motion is horizontal, but {row.joint} moves the tool vertically in the "
                "Annex-B pose (give down or up)",
                "motion",
            )
        )
    return scenario


def simulate_row(
    row: StoppingRow,
    robot: str,
    values: Mapping[str, float],
    figures: Sequence[Figure],
    prior: Mapping[str, Mapping[str, Any]],
    loader: Callable[..., Robot] = load_robot,
) -> RowFit:
    """Simulate one row; its tested joint's stopping angle and time.

    Raises:
        CalibrationError: The row's scenario is refused (see :func:`row_model`), or its
            simulation fails; one line naming the table file and the row.
    """
    from ..outputs.pipeline import run

    scenario = row_model(row, robot, values, figures, prior, loader)
    try:
        with warnings.catch_warnings():  # a trial's flags are not the user's: the fit goes on
            warnings.simplefilter("ignore", VtmWarning)
            output = run(scenario)
    except VtmError as exc:
        tried = ", ".join(f"{name} {value:.4g}" for name, value in values.items())
        raise CalibrationError(
            row_message(row, f"simulating it failed at the figures {tried or 'prior'}: {exc}")
        ) from exc
    state = scenario.test_state
    assert state is not None
    joint = output.stopping[output.rule].joints[state.joint_index]
    stopped = joint.stopped
    time = joint.stop_time if stopped else float(output.result.t[-1])
    q = output.result.q[:, state.joint_index]
    kinds = tuple(f.kind for f in output.figures.flags) if output.figures is not None else ()
    return RowFit(row, float(np.max(np.abs(q - q[0]))), time, stopped, kinds)


def check_table(
    table: StoppingTable, robot_name: str, *, robot_differs: bool = False
) -> StoppingTable:
    """Check a table against a robot before anything is fitted; the table to fit.

    In turn: its units (:func:`~vtm_pin.calibration.table.check_units`), its robot
    (:func:`~vtm_pin.calibration.table.check_robot`: the names must match unless
    ``robot_differs``, and then the table returned says so in its sources), its joints, and
    every row's scenario at the prior figures (:func:`row_model`). Each refusal is one line
    naming the table file, the row and the column.

    Args:
        table: The stopping table.
        robot_name: The robot (``--robot``).
        robot_differs: Fit a table measured on another robot on purpose.

    Raises:
        TableError: Units that make a row impossible, another robot's table, a joint the
            robot does not have.
        CalibrationError: A row whose scenario cannot be built.
    """
    check_units(table)
    robot = load_robot(robot_name)
    names = [robot_name]
    if robot_name.lower().endswith(".urdf"):  # a file: its name, or the robot it names
        names = [Path(robot_name).stem, str(robot.model.name)]
    table = check_robot(table, robot_name, names, robot_differs)
    check_joints(table, robot.joints)
    prior = priors(robot)
    cache = RobotCache()
    for row in table.rows:
        row_model(row, robot_name, {}, (), prior, cache)
    return table


def residuals(fits: Sequence[RowFit], scatter: tuple[float, float]) -> np.ndarray:
    """Weighted residuals: distance then time of every row (see the module docstring)."""
    out = []
    for fit in fits:
        out.append((fit.distance - fit.row.stop_distance) / (scatter[0] * fit.row.stop_distance))
        out.append((fit.time - fit.row.stop_time) / (scatter[1] * fit.row.stop_time))
    return np.array(out)


def calibrate(
    table: StoppingTable,
    robot_name: str,
    fit: Sequence[str] = DEFAULT_FIT,
    *,
    scatter: tuple[float, float] = (DISTANCE_SCATTER, TIME_SCATTER),
    rows: Sequence[StoppingRow] | None = None,
    progress: Callable[[int], None] | None = None,
) -> Calibration:
    """Fit ``fit`` to the table's rows (or to ``rows``, a subset of them).

    Args:
        table: The published stopping table.
        robot_name: The robot (a name vtm-pin can load).
        fit: The figures to fit (see :data:`FIGURES`).
        scatter: Relative scatter of the published distances and times [-].
        rows: The rows to fit; all by default.
        progress: Called with the number of residual evaluations so far.

    Raises:
        CalibrationError: Bad figures or rows (see :func:`simulate_row`).
        TableError: A row impossible as read (a unit mistake), or a joint the robot does not
            have.
    """
    from scipy.optimize import least_squares

    check_units(table)
    robot = load_robot(robot_name)
    check_joints(table, robot.joints)
    used = list(table.rows if rows is None else rows)
    if not fit:
        raise CalibrationError("--fit: name at least one figure")
    tested = list(dict.fromkeys(row.joint for row in used))
    figures = make_figures(fit, tested, robot.joints, table.joints)
    prior = priors(robot)
    _check_short_circuit(figures, prior)
    motor = max(row.speed * float(robot.gear_ratio[robot.joint_index(row.joint)]) for row in used)
    x0 = np.array([_to_x(f, _start(f, prior, motor)) for f in figures])
    lower = np.array([_lower(f) for f in figures])
    upper = np.array([_upper(f) for f in figures])
    cache = RobotCache()
    count = [0]

    def fits_at(x: np.ndarray) -> list[RowFit]:
        values = {f.name: _from_x(f, xi) for f, xi in zip(figures, x, strict=True)}
        return [simulate_row(r, robot_name, values, figures, prior, cache) for r in used]

    def fun(x: np.ndarray) -> np.ndarray:
        count[0] += 1
        if progress is not None:
            progress(count[0])
        return residuals(fits_at(x), scatter)

    solution = least_squares(
        fun,
        np.clip(x0, lower, upper),
        bounds=(lower, upper),
        x_scale="jac",
        diff_step=1e-3,
        max_nfev=MAX_EVALUATIONS_PER_FIGURE * len(figures),
    )
    values = {f.name: _from_x(f, xi) for f, xi in zip(figures, solution.x, strict=True)}
    # Jacobian with respect to the figures themselves (SI), not their log scale.
    scale = np.array(
        [_from_x(f, xi) if f.positive else 1.0 for f, xi in zip(figures, solution.x, strict=True)]
    )
    J = solution.jac / scale
    active = solution.active_mask != 0  # figures held at a bound of their search
    sigma, determined, rank, singular, covariance = _uncertainty(J, active)
    return Calibration(
        robot=robot_name,
        fit=tuple(fit),
        figures=figures,
        values=values,
        uncertainty={f.name: float(s) for f, s in zip(figures, sigma, strict=True)},
        determined={f.name: bool(d) for f, d in zip(figures, determined, strict=True)},
        at_bound={f.name: bool(a) for f, a in zip(figures, active, strict=True)},
        rows=tuple(fits_at(solution.x)),
        cost=float(solution.cost),
        rank=rank,
        singular_values=tuple(float(s) for s in singular),
        evaluations=count[0],
        success=bool(solution.success),
        message=str(solution.message),
        priors=prior,
        scatter=scatter,
        covariance=covariance,
    )


#: Search range of the positive figures by key (log scale), the others' in s.
_RANGES = {
    "rotor_inertia": (MIN_POSITIVE, MAX_INERTIA_FIGURE),
    "viscous_velocity": (MIN_SPEED_FIGURE, MAX_SPEED_FIGURE),
    "short_circuit_speed": (MIN_SPEED_FIGURE, MAX_SPEED_FIGURE),
}


def _check_short_circuit(figures: Sequence[Figure], prior: Mapping[str, Mapping[str, Any]]) -> None:
    """A fitted short-circuit torque needs the speed of its peak: fitted, or in the robot data.

    Raises:
        CalibrationError: A joint whose short-circuit torque is fitted has no such speed.
    """
    speeds = {j for f in figures if f.key == "short_circuit_speed" for j in f.joints}
    for figure in figures:
        if figure.key != "short_circuit_torque":
            continue
        missing = [
            j for j in figure.joints if j not in speeds and not prior[j]["short_circuit_speed"] > 0
        ]
        if missing:
            raise CalibrationError(
                f"--fit: {figure.name} needs the speed of the short-circuit braking's peak: fit "
                f"short_circuit_speed too (the robot data give none for {', '.join(missing)})"
            )


def _lower(figure: Figure) -> float:
    """The lower bound of a figure's search variable (log scale for torques and inertias)."""
    if figure.positive:
        return math.log(_RANGES.get(figure.key, (MIN_POSITIVE, MAX_TORQUE_FIGURE))[0])
    return MIN_DELAY if figure.key == "delay" else 0.0


def _upper(figure: Figure) -> float:
    """The upper bound of a figure's search variable (log scale for torques and inertias)."""
    if not figure.positive:
        return MAX_TIME_FIGURE
    return math.log(_RANGES.get(figure.key, (MIN_POSITIVE, MAX_TORQUE_FIGURE))[1])


def _start(
    figure: Figure, prior: Mapping[str, Mapping[str, Any]], motor_speed: float = 100.0
) -> float:
    """The start of a figure's search: its prior (a rotor inertia of 0 starts at 1e-4).

    A law's figure without a prior starts from the table: its speeds at the fastest motor
    speed of the rows (``motor_speed`` [rad/s]), the short-circuit torque at
    :data:`START_SHORT_CIRCUIT_FRACTION` of the joint's prior sliding torque.
    """
    joint = prior[figure.joints[0]]
    value = float(joint.get(figure.key) or 0.0)
    if figure.key == "rotor_inertia" and value <= 0.0:
        return PRIOR_ROTOR_INERTIA
    if figure.key in ("viscous_velocity", "short_circuit_speed") and value <= 0.0:
        return START_SPEED_FRACTION * motor_speed
    if figure.key == "short_circuit_torque" and value <= 0.0:
        return START_SHORT_CIRCUIT_FRACTION * float(joint["sliding_torque"])
    return value


def predict(calibration: Calibration, rows: Sequence[StoppingRow]) -> list[RowFit]:
    """Simulate ``rows`` with the fitted figures (e.g. rows left out of the fit)."""
    cache = RobotCache()
    return [
        simulate_row(
            row,
            calibration.robot,
            calibration.values,
            calibration.figures,
            calibration.priors,
            cache,
        )
        for row in rows
    ]


@dataclass(frozen=True)
class LeftOut:
    """A leave-one-out check: fit without one joint's rows, then predict them.

    Attributes:
        joint: The joint left out.
        calibration: The fit on the other joints' rows.
        predictions: The left-out rows, simulated with that fit.
    """

    joint: str
    calibration: Calibration
    predictions: tuple[RowFit, ...]


def leave_one_out(
    table: StoppingTable,
    robot_name: str,
    fit: Sequence[str] = DEFAULT_FIT,
    *,
    scatter: tuple[float, float] = (DISTANCE_SCATTER, TIME_SCATTER),
) -> list[LeftOut]:
    """For each tested joint: fit on the other joints' rows and predict its own.

    Only figures shared by the joints (``delay``, ``sliding:shared``, ...) carry over to the
    joint left out; per-joint figures are not fitted for it, so it keeps its priors there.
    """
    checks = []
    for joint in table.joints:
        kept = [row for row in table.rows if row.joint != joint]
        left = [row for row in table.rows if row.joint == joint]
        calibration = calibrate(table, robot_name, fit, scatter=scatter, rows=kept)
        checks.append(LeftOut(joint, calibration, tuple(predict(calibration, left))))
    return checks


def _to_x(figure: Figure, value: float) -> float:
    return math.log(value) if figure.positive else value


def _from_x(figure: Figure, x: float) -> float:
    return math.exp(x) if figure.positive else float(x)


def _uncertainty(
    J: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]:
    """1-sigma uncertainties, whether determined, the rank, singular values and covariance.

    The rank is read off the Jacobian with unit-norm columns (so that seconds and N m
    compare); a figure is undetermined when it has a component above 0.1 in a direction of
    the null space. A figure held at a bound (``active``) is the fit's answer but has no
    curvature there: it gets no reported uncertainty (NaN), and the others' are those with it
    fixed. The covariance, which bounds propagate, is that of every figure from the whole
    Jacobian (a bound held by noisy data must not make its figure certain); where that
    leaves a figure undetermined, the free figures' covariance with it fixed (its row and
    column 0). An undetermined figure's variance is inf.
    """
    sigma, determined, rank, s, free_cov = _free_uncertainty(J[:, ~active])
    n = J.shape[1]
    out_sigma = np.full(n, np.nan)
    out_sigma[~active] = sigma
    out_determined = np.ones(n, dtype=bool)
    out_determined[~active] = determined
    _, all_determined, _, _, covariance = _free_uncertainty(J)
    if active.any() and not np.all(all_determined[active]):
        covariance = np.zeros((n, n))
        covariance[np.ix_(~active, ~active)] = free_cov
    return out_sigma, out_determined, rank + int(np.count_nonzero(active)), s, covariance


def _free_uncertainty(
    J: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]:
    """:func:`_uncertainty` of the figures free of their bounds."""
    if J.shape[1] == 0:
        return np.zeros(0), np.zeros(0, dtype=bool), 0, np.zeros(0), np.zeros((0, 0))
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0.0] = 1.0
    scaled = J / norms
    _, singular, vt = np.linalg.svd(scaled, full_matrices=True)
    n = J.shape[1]
    s = np.zeros(n)
    s[: singular.size] = singular
    keep = s > RANK_RTOL * max(float(s[0]), np.finfo(float).tiny)
    rank = int(np.count_nonzero(keep))
    null = vt[~keep]
    determined = ~np.any(np.abs(null) > 0.1, axis=0) if null.size else np.ones(n, dtype=bool)
    covariance = np.linalg.pinv(scaled.T @ scaled, rcond=RANK_RTOL**2) / np.outer(norms, norms)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    sigma[~determined] = np.inf
    covariance[np.diag_indices_from(covariance)] = np.where(determined, np.diag(covariance), np.inf)
    return sigma, determined, rank, s, covariance
