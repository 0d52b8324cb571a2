"""Which model class a published stopping table supports: fit each, compare, recommend.

A *model class* is a set of figures to fit (:data:`vtm_pin.calibration.fit.FIGURES`): which laws
act and which of their figures each joint has of its own. The built-in classes
(:data:`CLASSES`) go from a constant brake torque to brakes whose torque grows with the slip
speed, one per joint. Each is fitted to the same table (:func:`vtm_pin.calibration.fit.calibrate`)
and judged on three tests, each stated with its threshold:

* **scatter**: every residual within 2 of its stated scatter, and, with degrees of freedom
  left, chi^2 not beyond its 95 % point (p >= 0.05);
* **bias**: the mean signed relative residual of the times, and of the distances, is not
  significant: below t_(0.975, m-1) standard errors of the rows' own spread (a t-test over the
  m rows), or below a quarter of the stated scatter. The stated time scatter (20 % by default)
  is wider than a bias of 16-22 %, so chi^2 alone would pass a class whose times are all short;
* **short**: no published time or distance is under-predicted by more than ``short_tolerance``
  (5 % by default): short stopping figures are the unsafe direction;
* **plausible**: at every row's own test pose the fitted brakes hold the arm and stop a moving
  joint (no ``brake_cannot_hold`` or ``brake_cannot_stop`` flag): figures that reproduce the
  table with an arm that slides on under its own weight are not physical.

A class *fits* if it passes all four and the table determines every figure it fits. The
recommended class is the simplest that fits (fewest free figures); if none fits, among the
plausible, determined classes the one whose figures fall least short (else the least short of
all), and the tool says so.

For each class also: AIC = chi^2 + 2 k and BIC = chi^2 + k ln n (k free figures, n residuals;
-2 ln L up to a constant for Gaussian scatter of the stated size), and the leave-one-out check
with every figure shared by the joints (``sliding`` -> ``sliding:shared``, ...): fitted on the
other joints' rows, each joint's rows are predicted. It tests whether the class carries over
from joint to joint, which an exactly determined per-joint fit cannot show.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .fit import (
    DISTANCE_SCATTER,
    TIME_SCATTER,
    Calibration,
    CalibrationError,
    LeftOut,
    RowFit,
    calibrate,
    leave_one_out,
)
from .table import StoppingTable

#: The built-in model classes, simplest first: name -> (what it is, the figures it fits).
CLASSES: dict[str, tuple[str, tuple[str, ...]]] = {
    "coulomb": (
        "constant brake torque after one brake delay (each tested joint's torque)",
        ("delay", "sliding"),
    ),
    "viscous": (
        "brake torque growing with the slip speed, tau_c (1 + w / w_v), one w_v for every "
        "tested joint (brakes of one type)",
        ("delay", "sliding", "viscous:shared"),
    ),
    "short_circuit": (
        "constant brake torque plus the motors' short-circuit braking from the signal, one "
        "torque-speed curve for every tested joint (motors of one type)",
        ("delay", "sliding", "short_circuit:shared", "short_circuit_speed:shared"),
    ),
    "viscous:joint": (
        "brake torque growing with the slip speed, each tested joint's brake with its own w_v "
        "(the brake delay held at its prior: one row per joint cannot also determine it)",
        ("sliding", "viscous"),
    ),
}
#: A residual beyond this many stated scatters fails the scatter test [-].
MAX_SIGMAS = 2.0
#: p-value below which chi^2 says the residuals exceed the stated scatter [-].
CHI2_LEVEL = 0.05
#: A mean relative residual below this fraction of the stated scatter is no bias worth
#: naming, however consistent [-].
BIAS_FLOOR = 0.25
#: Default largest under-prediction of a published time or distance [-] (the unsafe side).
SHORT_TOLERANCE = 0.05


@dataclass(frozen=True)
class Bias:
    """The mean signed relative residual of one figure over the rows.

    Attributes:
        mean: Mean of (simulated - published) / published [-].
        standard_error: Sample standard deviation / sqrt(rows); NaN for one row.
        t: mean / standard_error (NaN for one row).
        critical: t_(0.975, rows - 1) (NaN for one row).
        biased: Whether the mean is significant and above the floor.
    """

    mean: float
    standard_error: float
    t: float
    critical: float
    biased: bool


@dataclass(frozen=True)
class ClassFit:
    """One model class fitted to the table, and how it fares.

    Attributes:
        name: The class's name (a key of :data:`CLASSES`, or ``custom``).
        description: What the class assumes.
        calibration: The fit.
        free: Figures free of their search bounds (k).
        residuals: Number of weighted residuals (n = 2 x rows).
        chi2: Sum of squared weighted residuals.
        dof: n - k.
        p_value: Probability of a chi^2 at least this large if the scatter is right (NaN for
            dof <= 0).
        aic: chi^2 + 2 k.
        bic: chi^2 + k ln n.
        time_bias: Bias of the times.
        distance_bias: Bias of the distances.
        shortest: Most negative relative residual of a time or distance [-] (the furthest a
            published figure is under-predicted), 0 if none is.
        reasons: Why the class does not fit (empty if it does).
        loo: Leave-one-out checks with every figure shared (empty if not run).
    """

    name: str
    description: str
    calibration: Calibration
    free: int
    residuals: int
    chi2: float
    dof: int
    p_value: float
    aic: float
    bic: float
    time_bias: Bias
    distance_bias: Bias
    shortest: float
    reasons: tuple[str, ...]
    loo: tuple[LeftOut, ...] = ()

    @property
    def fits(self) -> bool:
        """Within the scatter, unbiased, and nothing short beyond the tolerance."""
        return not self.reasons

    @property
    def chi2_per_dof(self) -> float:
        """chi^2 / dof (NaN if no degree of freedom is left: the class is exactly determined)."""
        return self.chi2 / self.dof if self.dof > 0 else math.nan


@dataclass(frozen=True)
class Comparison:
    """Every class compared on one table, and the one recommended.

    Attributes:
        classes: The fits, in the order compared (simplest first).
        chosen: The recommended class's name.
        none_fits: True if no class fits (the chosen one is the least short).
        short_tolerance: The short test's tolerance [-].
    """

    classes: tuple[ClassFit, ...]
    chosen: str
    none_fits: bool
    short_tolerance: float

    @property
    def best(self) -> ClassFit:
        """The recommended class's fit."""
        return next(c for c in self.classes if c.name == self.chosen)


def shared(fit: Sequence[str]) -> tuple[str, ...]:
    """The figures of ``fit`` with every per-joint figure shared by the joints."""
    out = []
    for name in fit:
        base = name.split(":")[0]
        out.append(base if base in ("delay", "ramp") else f"{base}:shared")
    return tuple(dict.fromkeys(out))


def bias(published: np.ndarray, simulated: np.ndarray, scatter: float) -> Bias:
    """The bias of one figure over the rows (see the module docstring)."""
    from scipy.stats import t as student

    relative = (simulated - published) / published
    mean = float(np.mean(relative))
    m = relative.size
    if m < 2:
        return Bias(mean, math.nan, math.nan, math.nan, False)
    se = float(np.std(relative, ddof=1)) / math.sqrt(m)
    critical = float(student.ppf(0.975, m - 1))
    t_value = mean / se if se > 0.0 else (math.inf if mean else 0.0)
    biased = abs(t_value) > critical and abs(mean) > BIAS_FLOOR * scatter
    return Bias(mean, se, t_value, critical, biased)


def judge(
    name: str,
    description: str,
    calibration: Calibration,
    short_tolerance: float = SHORT_TOLERANCE,
    loo: Sequence[LeftOut] = (),
) -> ClassFit:
    """A fitted class's statistics and the reasons it does not fit (see the module docstring)."""
    from scipy.stats import chi2 as chi2_dist

    rows = calibration.rows
    s_d, s_t = calibration.scatter
    d_pub = np.array([r.row.stop_distance for r in rows])
    d_sim = np.array([r.distance for r in rows])
    t_pub = np.array([r.row.stop_time for r in rows])
    t_sim = np.array([r.time for r in rows])
    sigmas = np.concatenate([(d_sim - d_pub) / (s_d * d_pub), (t_sim - t_pub) / (s_t * t_pub)])
    chi2 = float(np.sum(sigmas**2))
    free = sum(not calibration.at_bound[f.name] for f in calibration.figures)
    n = sigmas.size
    dof = n - free
    p_value = float(chi2_dist.sf(chi2, dof)) if dof > 0 else math.nan
    time_bias = bias(t_pub, t_sim, s_t)
    distance_bias = bias(d_pub, d_sim, s_d)
    relative = np.concatenate([(d_sim - d_pub) / d_pub, (t_sim - t_pub) / t_pub])
    shortest = float(min(0.0, np.min(relative)))
    undetermined = [n for n, ok in calibration.determined.items() if not ok]
    reasons = _reasons(
        rows, undetermined, dof, sigmas, p_value, time_bias, distance_bias, short_tolerance
    )
    return ClassFit(
        name=name,
        description=description,
        calibration=calibration,
        free=free,
        residuals=n,
        chi2=chi2,
        dof=dof,
        p_value=p_value,
        aic=chi2 + 2.0 * free,
        bic=chi2 + free * math.log(n),
        time_bias=time_bias,
        distance_bias=distance_bias,
        shortest=shortest,
        reasons=tuple(reasons),
        loo=tuple(loo),
    )


def _reasons(
    rows: Sequence[RowFit],
    undetermined: Sequence[str],
    dof: int,
    sigmas: np.ndarray,
    p_value: float,
    time_bias: Bias,
    distance_bias: Bias,
    short_tolerance: float,
) -> list[str]:
    """Why a class does not fit, one phrase per failed test (empty if it fits)."""
    reasons = []
    m = len(rows)
    if dof < 0:
        reasons.append(
            f"{-dof} more free figures than published figures: the table cannot determine them"
        )
    beyond = [
        f"row {rows[i % m].row.line} {('distance', 'time')[i // m]} {sigmas[i]:+.1f} sigma"
        for i in np.flatnonzero(np.abs(sigmas) > MAX_SIGMAS).tolist()
    ]
    if beyond:
        reasons.append(f"beyond {MAX_SIGMAS:g} x the scatter: {', '.join(beyond)}")
    if p_value < CHI2_LEVEL:
        reasons.append(f"chi2 beyond its 95 % point (p = {p_value:.2g})")
    for what, b in (("times", time_bias), ("distances", distance_bias)):
        if b.biased:
            reasons.append(
                f"{what} biased: mean {100 * b.mean:+.1f} % ({b.t:+.1f} standard errors over "
                f"{m} rows, t_0.975 = {b.critical:.2f})"
            )
    short = _short(rows, short_tolerance)
    if short:
        reasons.append(f"short by more than {100 * short_tolerance:g} %: {short}")
    implausible = _implausible(rows)
    if implausible:
        reasons.append(f"{IMPLAUSIBLE}: {implausible}")
    if undetermined:
        reasons.append(f"{UNDETERMINED}: {', '.join(undetermined)} (no bound can cover them)")
    return reasons


#: The start of the reason a class's fitted brakes are not physical, and of the reason the
#: table leaves some of its figures undetermined.
IMPLAUSIBLE, UNDETERMINED = "not physical", "not determined by the table"


def _implausible(rows: Sequence[RowFit]) -> str:
    """The rows whose fitted brakes cannot hold or stop the arm at their test pose, as text."""
    found = [
        f"row {fit.row.line} ({fit.row.joint}) {kind}"
        for fit in rows
        for kind in fit.flags
        if kind in ("brake_cannot_hold", "brake_cannot_stop")
    ]
    return ", ".join(found)


def _short(rows: Sequence[RowFit], tolerance: float) -> str:
    """The rows whose time or distance is under-predicted beyond ``tolerance``, as text."""
    found = []
    for fit in rows:
        row = fit.row
        for what, sim, pub in (
            ("time", fit.time, row.stop_time),
            ("distance", fit.distance, row.stop_distance),
        ):
            relative = (sim - pub) / pub
            if relative < -tolerance:
                found.append(f"row {row.line} ({row.joint}) {what} {100 * relative:+.1f} %")
    return ", ".join(found)


def compare(
    table: StoppingTable,
    robot: str,
    classes: Sequence[str] = tuple(CLASSES),
    *,
    scatter: tuple[float, float] = (DISTANCE_SCATTER, TIME_SCATTER),
    short_tolerance: float = SHORT_TOLERANCE,
    workers: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Fit every class of ``classes`` to ``table``, judge it, and recommend one.

    Args:
        table: The published stopping table.
        robot: The robot (a name vtm-pin can load).
        classes: Names of :data:`CLASSES`, simplest first.
        scatter: Relative scatter of the published distances and times [-].
        short_tolerance: Largest under-prediction a fitting class may leave [-].
        workers: Processes for the fits; all cores by default.
        progress: Called with a fit's description each time one is done.

    Raises:
        CalibrationError: An unknown class, or a fit that cannot be set up.
    """
    unknown = [c for c in classes if c not in CLASSES]
    if unknown or not classes:
        raise CalibrationError(
            f"--classes: '{', '.join(unknown) or ''}' unknown; the classes are: "
            f"{', '.join(CLASSES)}"
        )
    # Every fit is independent: the classes' and their leave-one-out checks (one per distinct
    # shared variant: a per-joint class and its shared one check alike), on all cores.
    loo_fits = list(dict.fromkeys(shared(CLASSES[name][1]) for name in classes))
    jobs: list[tuple[str, tuple[str, ...]]] = [("fit", CLASSES[name][1]) for name in classes]
    if len(table.joints) > 1:
        jobs += [("loo", fit) for fit in loo_fits]
    done = run_jobs(table, robot, jobs, scatter, workers, progress)
    fits = []
    for name in classes:
        description, fit = CLASSES[name]
        checks = done.get(("loo", shared(fit)), [])
        calibration = done[("fit", fit)]
        assert isinstance(calibration, Calibration) and isinstance(checks, list)
        fits.append(judge(name, description, calibration, short_tolerance, checks))
    return recommend(fits, short_tolerance)


def run_jobs(
    table: StoppingTable,
    robot: str,
    jobs: Sequence[tuple[str, tuple[str, ...]]],
    scatter: tuple[float, float],
    workers: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[tuple[str, tuple[str, ...]], Calibration | list[LeftOut]]:
    """The fits (``fit``) and leave-one-out checks (``loo``) of ``jobs``, on ``workers`` processes.

    One worker (or one job) runs them here; more use a process pool (``forkserver`` where
    available, BLAS pinned to one thread), as studies do.
    """
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    count = min(len(jobs), workers or len(os.sched_getaffinity(0)))
    if count <= 1:
        out: dict[tuple[str, tuple[str, ...]], Calibration | list[LeftOut]] = {}
        for job in jobs:
            out[job] = _run_job(table, robot, job, scatter)
            if progress is not None:
                progress(f"{job[0]} {','.join(job[1])}")
        return out
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    saved = os.environ.get("OMP_NUM_THREADS")
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        with ProcessPoolExecutor(count, mp_context=context) as pool:
            futures = {pool.submit(_run_job, table, robot, job, scatter): job for job in jobs}
            out = {}
            for future in futures:
                out[futures[future]] = future.result()
                if progress is not None:
                    job = futures[future]
                    progress(f"{job[0]} {','.join(job[1])}")
            return out
    finally:
        if saved is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = saved


def _run_job(
    table: StoppingTable,
    robot: str,
    job: tuple[str, tuple[str, ...]],
    scatter: tuple[float, float],
) -> Calibration | list[LeftOut]:
    """One fit, or one class's leave-one-out checks (in a worker process)."""
    kind, fit = job
    if kind == "fit":
        return calibrate(table, robot, fit, scatter=scatter)
    return leave_one_out(table, robot, fit, scatter=scatter)


def recommend(fits: Sequence[ClassFit], short_tolerance: float) -> Comparison:
    """The simplest class that fits, else the least short plausible one (ties: lower AIC)."""
    order = sorted(fits, key=lambda c: (c.free, c.aic, list(fits).index(c)))
    fitting = [c for c in order if c.fits]
    if fitting:
        return Comparison(tuple(fits), fitting[0].name, False, short_tolerance)
    usable = [
        c for c in order if not any(r.startswith((IMPLAUSIBLE, UNDETERMINED)) for r in c.reasons)
    ]
    least = max(usable or order, key=lambda c: (c.shortest, -c.aic))
    return Comparison(tuple(fits), least.name, True, short_tolerance)


def warning_line(comparison: Comparison) -> str | None:
    """One line naming what the recommended class leaves wrong, or None if nothing."""
    best = comparison.best
    if best.fits and best.dof <= 0:
        return (
            f"the chosen class {best.name} is exactly determined by the table ({best.free} free "
            f"figures, {best.residuals} published figures): the table cannot test it"
            + _loo_text(best)
        )
    if best.fits:
        return None
    if len(comparison.classes) == 1:
        lead = f"the figures fitted ({best.description}) do not fit the table"
    elif comparison.none_fits:
        lead = (
            f"no model class fits the table; using {best.name}, the plausible, determined "
            "class whose figures fall least short"
        )
    else:
        lead = f"the chosen class {best.name} does not fit"
    return f"{lead}: {'; '.join(best.reasons)}"


def loo_misses(fit: ClassFit) -> tuple[float, float]:
    """The largest relative miss of a left-out distance and time [-] (NaN without checks)."""
    pairs = [
        (
            abs(p.distance - p.row.stop_distance) / p.row.stop_distance,
            abs(p.time - p.row.stop_time) / p.row.stop_time,
        )
        for check in fit.loo
        for p in check.predictions
    ]
    if not pairs:
        return math.nan, math.nan
    return max(d for d, _ in pairs), max(t for _, t in pairs)


def _loo_text(fit: ClassFit) -> str:
    distance, time = loo_misses(fit)
    if math.isnan(distance):
        return ""
    return (
        f"; with its figures shared by the joints, a left-out joint's distance is missed by up "
        f"to {100 * distance:.0f} % and its time by up to {100 * time:.0f} %"
    )


def describe_comparison(comparison: Comparison) -> list[dict[str, object]]:
    """The comparison table as JSON-ready rows (NaN as None)."""
    out = []
    for c in comparison.classes:
        out.append(
            {
                "class": c.name,
                "description": c.description,
                "fit": list(c.calibration.fit),
                "figures": len(c.calibration.figures),
                "free": c.free,
                "residuals": c.residuals,
                "chi2": c.chi2,
                "dof": c.dof,
                "chi2_per_dof": _num(c.chi2_per_dof),
                "p_value": _num(c.p_value),
                "aic": c.aic,
                "bic": c.bic,
                "time_bias": _bias(c.time_bias),
                "distance_bias": _bias(c.distance_bias),
                "shortest": c.shortest,
                "fits": c.fits,
                "reasons": list(c.reasons),
                "chosen": c.name == comparison.chosen,
                "values": dict(c.calibration.values),
                "leave_one_out": [
                    {
                        "joint": check.joint,
                        "rows": [
                            {
                                "line": p.row.line,
                                "distance_published": p.row.stop_distance,
                                "distance_predicted": p.distance,
                                "time_published": p.row.stop_time,
                                "time_predicted": p.time,
                            }
                            for p in check.predictions
                        ],
                    }
                    for check in c.loo
                ],
            }
        )
    return out


def _bias(b: Bias) -> Mapping[str, object]:
    return {
        "mean": b.mean,
        "standard_error": _num(b.standard_error),
        "t": _num(b.t),
        "critical": _num(b.critical),
        "biased": b.biased,
    }


def _num(x: float) -> float | None:
    return x if math.isfinite(x) else None
