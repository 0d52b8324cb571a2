"""Conservative bounds: one-sided upper bounds of the signed figures, at a stated confidence.

A scenario (or a study's base) asks for bounds with ``bounds: {confidence, brake_wear}``. The
bound of a figure f (T_robot, the tested joint's angle and time, S_s, S_arm) is

    f_upper = max(f, f_worn) + z sqrt(g^T C g) + max(0, -b) / (1 + b) f_worn

* f_worn: the figure with every brake torque (sliding and static) scaled by 1 - brake_wear:
  brakes wear, and makers ask users to re-check stopping distances every year;
* C: the covariance of the calibrated figures (the ``calibration`` section a calibrated
  fragment carries, inflated by chi^2 per degree of freedom when above 1); g: the figure's
  sensitivity to each, by a forward finite difference of one standard deviation (at most half
  the figure's value) from the worn state (linearised propagation: k + 2 runs for k figures,
  where sampling would need hundreds per case; the coverage test checks that the
  linearisation keeps its confidence);
* z: the standard normal quantile of the confidence (1.645 at 95 %, one-sided);
* b: the calibration's shortfall of the times (for times) or distances (for angles and S_s),
  the most negative (simulated - published) / published of its rows (its mean, the residual
  bias, where a section gives no shortfall): a model whose times came out short gets the
  worst of it back (a figure short by b reaches the published one times 1 / (1 + b)), the
  conservative choice.

T, S and S_p follow from the bounded T_robot and S_s through their formulas. Without a
``calibration`` section only the wear allowance applies, and the bound says so. The bound is
never below the nominal figure. A calibration with undetermined figures cannot be bounded:
refused, naming them.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import numpy as np

from ..exceptions import ScenarioError

#: The figures bounded directly, and which residual bias applies to each.
BOUNDED = {
    "robot_stop_time": "stop_time",
    "test_stop_time": "stop_time",
    "stop_angle": "stop_distance",
    "tcp_max_displacement": "stop_distance",
    "arm_max_displacement": "stop_distance",
}
#: The figures derived from the bounded ones through the standards' formulas.
DERIVED = ("overall_stop_time", "iso13855_distance", "ssm_distance")
#: Default one-sided confidence [-].
DEFAULT_CONFIDENCE = 0.95
#: Largest finite-difference step of a figure, as a fraction of its value [-].
MAX_STEP = 0.5


@dataclass(frozen=True)
class BoundSpec:
    """What a scenario's ``bounds`` asks for.

    Attributes:
        confidence: One-sided confidence of the upper bounds [-], in [0.5, 0.9999].
        brake_wear: Fraction the brake torques are reduced by [-], in [0, 0.9].
    """

    confidence: float = DEFAULT_CONFIDENCE
    brake_wear: float = 0.0

    @property
    def z(self) -> float:
        """The standard normal quantile of the confidence."""
        return NormalDist().inv_cdf(self.confidence)


@dataclass(frozen=True)
class Uncertainty:
    """A calibration's figures, their covariance and residual bias (a fragment's section).

    Attributes:
        names: The figures' names.
        values: Their fitted values (SI).
        keys: The scenario key paths each sets.
        covariance: Their covariance (SI, square units).
        bias: Mean relative residual of the calibration's ``stop_time`` and ``stop_distance``.
        source: The published data they were fitted to.
        shortfall: Most negative relative residual of each (<= 0), which bounds add back.
    """

    names: tuple[str, ...]
    values: np.ndarray
    keys: tuple[tuple[str, ...], ...]
    covariance: np.ndarray
    bias: Mapping[str, float]
    source: str
    shortfall: Mapping[str, float] = field(default_factory=dict)

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of each figure (SI)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def steps(self) -> np.ndarray:
        """Each figure's finite-difference step: 1 sigma, at most :data:`MAX_STEP` of its value.

        A figure the table barely constrains would otherwise be moved out of physical range. A
        figure of zero variance has step 0: it is not moved (its covariance row is 0, so it
        adds nothing to a bound).
        """
        return np.minimum(self.sigma, MAX_STEP * np.abs(self.values))

    @property
    def moved(self) -> np.ndarray:
        """Indices of the figures that are moved (step > 0), in order."""
        return np.flatnonzero(self.steps > 0.0)


def parse_bounds(
    raw: Mapping[str, Any], source: str
) -> tuple[BoundSpec | None, Uncertainty | None]:
    """The ``bounds`` a scenario asks for and the ``calibration`` it carries (schema checked).

    Raises:
        ScenarioError: A calibration section whose covariance does not match its figures or is
            not a covariance, or with undetermined figures while bounds are asked for.
    """
    spec = raw.get("bounds")
    bounds = (
        None
        if spec is None
        else BoundSpec(
            float(spec.get("confidence", DEFAULT_CONFIDENCE)), float(spec.get("brake_wear", 0.0))
        )
    )
    section = raw.get("calibration")
    if section is None:
        return bounds, None
    figures = section.get("figures", [])
    rows = section.get("covariance", [])
    n = len(figures)
    covariance = np.array(rows, dtype=float).reshape(n, n) if _square(rows, n) else None
    if covariance is None or not _is_covariance(covariance):
        raise ScenarioError(
            source,
            "calibration.covariance",
            f"must be a symmetric positive semi-definite {len(figures)} x {len(figures)} "
            "matrix, one row per figure",
        )
    undetermined = section.get("undetermined", [])
    if bounds is not None and undetermined:
        raise ScenarioError(
            source,
            "bounds",
            f"the calibration does not determine {', '.join(map(str, undetermined))}: no bound "
            "can cover them; calibrate with fewer figures, or drop bounds",
        )
    uncertainty = Uncertainty(
        names=tuple(str(f["name"]) for f in figures),
        values=np.array([float(f["value"]) for f in figures]),
        keys=tuple(tuple(str(k) for k in f["keys"]) for f in figures),
        covariance=covariance,
        bias={k: float(v) for k, v in section.get("bias", {}).items()},
        source=str(section.get("source", "")),
        shortfall={k: float(v) for k, v in section.get("shortfall", {}).items()},
    )
    return bounds, uncertainty


def _square(rows: Any, n: int) -> bool:
    return (
        isinstance(rows, list)
        and len(rows) == n
        and all(isinstance(r, list) and len(r) == n for r in rows)
    )


def _is_covariance(c: np.ndarray) -> bool:
    if c.size == 0:
        return True
    scale = max(float(np.max(np.abs(c))), 1e-300)
    symmetric = np.allclose(c, c.T, rtol=0.0, atol=1e-9 * scale)
    return bool(symmetric and np.min(np.linalg.eigvalsh(0.5 * (c + c.T))) >= -1e-9 * scale)


def variants(
    raw: Mapping[str, Any], spec: BoundSpec, uncertainty: Uncertainty | None
) -> list[dict[str, Any]]:
    """The scenarios a bound needs, after the nominal one: worn, then one per moved figure.

    ``raw`` is the nominal scenario with its fragments and robot data merged (every brake
    named). The worn scenario scales every brake's sliding and static torque by 1 -
    ``brake_wear``; each figure's scenario moves that figure by its step (one standard
    deviation, see :attr:`Uncertainty.steps`) from the worn one (its keys scaled by
    (value + step) / value). Figures of zero variance are not moved (:attr:`Uncertainty.moved`).
    """
    worn = copy.deepcopy(dict(raw))
    factor = 1.0 - spec.brake_wear
    for brake in worn.get("brakes", {}).values():
        for key in ("sliding_torque", "static_torque"):
            if brake is not None and key in brake:
                brake[key] = brake[key] * factor
    out = [worn]
    if uncertainty is None:
        return out
    for i in uncertainty.moved:
        moved = copy.deepcopy(worn)
        ratio = (uncertainty.values[i] + uncertainty.steps[i]) / uncertainty.values[i]
        for path in uncertainty.keys[i]:
            _scale(moved, path.split("."), ratio)
        out.append(moved)
    return out


def _scale(node: dict[str, Any], parts: Sequence[str], ratio: float) -> None:
    """Multiply the value at a key path by ``ratio`` (paths that are absent are left alone)."""
    for part in parts[:-1]:
        child = node.get(part)
        if not isinstance(child, dict):
            return
        node = child
    if isinstance(node.get(parts[-1]), (int, float)):
        node[parts[-1]] = node[parts[-1]] * ratio


def upper_bounds(
    nominal: Mapping[str, float | None],
    runs: Sequence[Mapping[str, float | None]],
    spec: BoundSpec,
    uncertainty: Uncertainty | None,
) -> dict[str, float | None]:
    """``<figure>_upper`` of each figure of :data:`BOUNDED` (None where it is undefined).

    Args:
        nominal: The nominal run's figures.
        runs: The figures of :func:`variants`' scenarios, in their order.
        spec: The bounds asked for.
        uncertainty: The calibration's figures and covariance, if any.
    """
    worn, moved = runs[0], runs[1:]
    out: dict[str, float | None] = {}
    for name, kind in BOUNDED.items():
        f, fw = nominal.get(name), worn.get(name)
        if f is None or fw is None or any(m.get(name) is None for m in moved):
            out[f"{name}_upper"] = None
            continue
        spread, short = 0.0, 0.0
        if uncertainty is not None:
            spread = _spread([float(m[name] or 0.0) for m in moved], fw, uncertainty)
            short = _shortfall(uncertainty, kind)
        out[f"{name}_upper"] = max(f, fw) + spec.z * spread + shortfall_allowance(short, fw)
    return out


def _shortfall(uncertainty: Uncertainty, kind: str) -> float:
    """The relative residual a bound of ``kind`` adds back for (its worst, else its bias)."""
    return uncertainty.shortfall.get(kind, min(0.0, uncertainty.bias.get(kind, 0.0)))


def _spread(moved: Sequence[float], worn: float, uncertainty: Uncertainty) -> float:
    """sqrt(g^T C g) of one figure from its moved runs (one per :attr:`Uncertainty.moved`)."""
    index = uncertainty.moved
    if index.size == 0:
        return 0.0
    g = (np.asarray(moved) - worn) / uncertainty.steps[index]
    c = uncertainty.covariance[np.ix_(index, index)]
    return float(math.sqrt(max(0.0, float(g @ c @ g))))


def error_gain(spec: BoundSpec, uncertainty: Uncertainty | None) -> float:
    """The most :func:`upper_bounds` can enlarge an error its runs' figures share [-].

    A bound is max(f, f_w) + z sqrt(g^T C g) + a f_w, with g_i = (f_i - f_w) / s_i over the
    moved figures and a = -r / (1 + r) for a shortfall r < 0. Runs whose figures are each off
    by at most d (e.g. the integrator's tolerance) give g's off by at most 2 d / s_i, so the
    bound is off by at most d (1 + a + 2 z sqrt(sum_ij |C_ij| / (s_i s_j))). 1 without a
    calibration (the bound is then the larger of two runs' figures).
    """
    if uncertainty is None:
        return 1.0
    shortfalls = [_shortfall(uncertainty, kind) for kind in set(BOUNDED.values())]
    a = max(-r / (1.0 + r) for r in [*shortfalls, 0.0])
    i = uncertainty.moved
    ratios = np.abs(uncertainty.covariance[np.ix_(i, i)]) / np.outer(
        uncertainty.steps[i], uncertainty.steps[i]
    )
    return 1.0 + a + 2.0 * spec.z * math.sqrt(float(ratios.sum()))


def shortfall_allowance(shortfall: float, figure: float) -> float:
    """What a bound adds back for a calibration that came out short [units of ``figure``].

    A simulated figure s short of the published by the relative residual r = (s - p) / p < 0
    reaches the published only when multiplied by 1 / (1 + r): the allowance is
    -r / (1 + r) times the figure (0 for r >= 0).

    Args:
        shortfall: The relative residual r [-], > -1.
        figure: The (worn) figure it is added to.
    """
    if shortfall >= 0.0:
        return 0.0
    return -shortfall / (1.0 + shortfall) * figure


def describe(spec: BoundSpec, uncertainty: Uncertainty | None) -> dict[str, Any]:
    """How the bounds were made, for summary.json and the report."""
    text = (
        f"One-sided {100 * spec.confidence:g} % upper bounds (z = {spec.z:.3f}): the larger of "
        f"the nominal figure and the figure with every brake torque {100 * spec.brake_wear:g} % "
        "lower (brake wear), plus z times its standard deviation"
    )
    if uncertainty is None:
        text += " (none: the scenario carries no calibration covariance, so only wear counts)"
    else:
        text += (
            f" propagated from the covariance of the {len(uncertainty.names)} figures calibrated "
            f"to {uncertainty.source} (linearised: one finite difference of 1 sigma per figure "
            "from the worn state), plus the calibration's worst shortfall where its figures came "
            f"out short (times {100 * uncertainty.shortfall.get('stop_time', 0.0):+.1f} %, "
            f"distances {100 * uncertainty.shortfall.get('stop_distance', 0.0):+.1f} %)"
        )
    text += ". T, S and S_p follow from the bounded T_robot and S_s through their formulas."
    return {
        "confidence": spec.confidence,
        "z": spec.z,
        "brake_wear": spec.brake_wear,
        "method": "linear",
        "figures": [] if uncertainty is None else list(uncertainty.names),
        "bias": {} if uncertainty is None else dict(uncertainty.bias),
        "shortfall": {} if uncertainty is None else dict(uncertainty.shortfall),
        "text": text,
    }


def derived_uppers(
    separation: Any, metrics: Mapping[str, float | None], upper: Mapping[str, float | None]
) -> dict[str, float | None]:
    """T, S and S_p of the bounded T_robot and S_s (:data:`DERIVED` with ``_upper``).

    S_s is the arm's largest displacement (the tool's where the arm's is not bounded).
    """
    t_robot = upper.get("robot_stop_time_upper")
    reach = upper.get("arm_max_displacement_upper", upper.get("tcp_max_displacement_upper"))
    speed = metrics.get("arm_speed_at_signal", metrics.get("tcp_speed_at_signal"))
    if t_robot is None or reach is None or speed is None:
        return {f"{name}_upper": None for name in DERIVED}
    figures = separation.figures(t_robot, speed, reach)
    return {
        "overall_stop_time_upper": figures["T"],
        "iso13855_distance_upper": figures["S"],
        "ssm_distance_upper": figures["S_p"],
    }
