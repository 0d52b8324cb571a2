r"""MuJoCo against vtm_pin on the UR10 study's brake stops, at equal accuracy (issue 27).

Cases: the first ``--cases`` samples of ``studies/ur10_envelope.yaml`` (UR10, category-0 stop at
t = 0, Annex-B pose by tested joint, speed and extension, a payload class; Coulomb brakes of
``robots/ur10.yaml`` engaging 50 ms after the signal, no short-circuit braking). By default
1,250: one worker's batch of the 10,000-case study on 2 workers (as ``study_floor.py``). Fewer
cases understate both sides: on 120 MuJoCo met 1 % at dt = 1 ms (largest error 0.88 %), on
1,250 it needs 0.5 ms (1.15 % at 1 ms); and a smaller batch carries more of the batched
engine's per-batch cost per case.

vtm_pin side: the cases run as a study worker runs them
(:func:`vtm_pin.study.runner.run_cases`: build, simulate, stopping report), once with the
batched engine (all cases in one call; a payload class with fewer than
:data:`vtm_pin.core.batch.MIN_LANES` cases goes to the scalar engine, as in a study) and
once with the scalar engine. Its figures (DOP853, rtol 1e-8) are the reference.

MuJoCo side, per case: the same URDF; each moving body's inertia copied from vtm_pin's model
(payload included, :func:`mujoco_reference.copy_link_inertias`); the rotor inertias as
``armature``; no joint limits, damping or contacts; vtm_pin's gravity; q0, v0 of the built
scenario; no drive torque (category 0). At each brake's delay the joint's ``frictionloss``
becomes its sliding torque on the joint side (gear ratio x motor side). MuJoCo's dry friction
is a soft constraint: with its default impedance a held joint creeps (the friction force is
a stiff damper, not a stop), so the brakes' friction rows are made as stiff as MuJoCo lets
them: ``solimpfriction`` d = 0.9999 (MuJoCo's largest) at every penetration, and
``solreffriction`` time constant 2 dt (the smallest MuJoCo accepts). MuJoCo has one friction
level: a joint sticks while its load stays within the sliding torque, whereas vtm_pin holds
up to the static torque (1.2 x sliding here). Semi-implicit Euler (MuJoCo's ``Euler``; no
damping, so ``implicitfast`` is the same) at a fixed step dt; all cases in one
``mujoco.rollout`` call (one thread), stepped in chunks until the vtm_pin duration or until
every joint of every case has stayed below the rest speed for a whole chunk (0.1 s).

Because of that single level, a case in which a brake of vtm_pin's run holds more than its
sliding torque (:func:`holding_over_sliding`) is beyond MuJoCo's model: its errors are printed
apart ("beyond") and left out of the equal-accuracy step.

Figures, per case, as :mod:`vtm_pin.outputs.stopping` defines them: the tested joint's
stopping time (its speed below the rest speed, 1e-3 rad/s, for good) and stopping angle
|q(end) - q(signal)|, and the robot's stopping time (every joint at rest). Relative error:
|MuJoCo - vtm_pin| / vtm_pin for the times; for the angle the denominator is at least
:data:`ANGLE_FLOOR`. For each dt of ``--dt`` (coarse to fine) the largest error over the
cases; the equal-accuracy step is the largest dt at which every case is within ``--tol``
(1 %) on every figure. The ratio printed is MuJoCo's time per case at that dt over vtm_pin's
(simulation alone, and with build and report). Times are medians of ``--repeats``
interleaved rounds. Run it with ``OMP_NUM_THREADS=1``:

    OMP_NUM_THREADS=1 python benchmarks/mujoco_brake_peer.py [--cases 1250] [--repeats 3] \
        [--dt 2e-3 1e-3 5e-4 2.5e-4 2e-4 1e-4] [--out DIR]
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import mujoco.rollout
import mujoco_reference as mr
import numpy as np
from matplotlib.figure import Figure

import vtm_pin as vp
from vtm_pin.core.batch import model_key
from vtm_pin.core.simulation import simulate
from vtm_pin.outputs.stopping import compute_stopping_report, rest_times
from vtm_pin.physics.friction import Coulomb
from vtm_pin.scene.scenario import build_scenario
from vtm_pin.study.cases import Study, case_scenario, load_study
from vtm_pin.study.runner import CaseTask, run_cases

ROOT = Path(__file__).resolve().parent.parent
STUDY = ROOT / "studies" / "ur10_envelope.yaml"
#: MuJoCo steps [s], coarse to fine.
DT = (2e-3, 1e-3, 5e-4, 2.5e-4, 2e-4, 1e-4)
#: Largest relative error of every figure at "equal accuracy" [-].
TOLERANCE = 0.01
#: Smallest denominator of a stopping angle's relative error [rad] (a tested joint travels at
#: least 0.3 x 2.16 rad/s x 50 ms = 0.03 rad before its brake engages).
ANGLE_FLOOR = 0.01
#: Figures compared, as named in a study's records.
FIGURES = ("test_stop_time", "stop_angle", "robot_stop_time")
#: Simulated time per rollout call [s]; the run ends after a whole chunk at rest.
CHUNK_TIME = 0.1
#: MuJoCo's stiffest friction impedance (mjMAXIMP) and its solreffriction time constant in dt.
STIFF_IMPEDANCE = 0.9999
TIMECONST_STEPS = 2.0


@dataclass(frozen=True)
class PeerCases:
    """The study's cases and their built scenarios.

    Attributes:
        study: The study.
        tasks: What a study worker is given, one per case.
        scenarios: The built scenarios (for MuJoCo), one per case.
        tested: Index of each case's tested joint.
    """

    study: Study
    tasks: tuple[CaseTask, ...]
    scenarios: tuple[vp.Scenario, ...]
    tested: tuple[int, ...]


@dataclass(frozen=True)
class MujocoStops:
    """MuJoCo's figures of every case at one dt, and its wall time.

    Attributes:
        dt: Step [s].
        figures: Figure name -> one value per case ([s] or [rad]).
        wall: Wall time of the rollout calls of all cases [s].
        total: Wall time of the whole replay of all cases [s]: models compiled, initial
            states, rollouts, figures.
        end_time: Simulated time when the run ended [s].
        steps: Steps taken per case.
    """

    dt: float
    figures: dict[str, np.ndarray]
    wall: float
    total: float
    end_time: float
    steps: int


def load_cases(study_path: Path, count: int) -> PeerCases:
    """The first ``count`` cases of the study, as tasks and as built scenarios."""
    study = load_study(study_path)
    base_dir = study.scenario.parent
    tasks, scenarios, tested = [], [], []
    for case in study.cases()[:count]:
        tasks.append(CaseTask(study.base, str(base_dir), str(study.scenario), study.name, case))
        scenario = build_scenario(
            case_scenario(study.base, case), str(study.scenario), base_dir, study.name
        )
        check_replayable(scenario)
        scenarios.append(scenario)
        tested.append(scenario.robot.joint_index(str(case.values["joint"])))
    return PeerCases(study, tuple(tasks), tuple(scenarios), tuple(tested))


def check_replayable(scenario: vp.Scenario) -> None:
    """Refuse what the MuJoCo replay does not model.

    Raises:
        ValueError: Not a category-0 stop at t = 0, a brake that is not Coulomb friction at
            full torque from engagement, or locks or frame constraints.
    """
    stop = scenario.stop
    if stop is None or stop.category != 0 or stop.t != 0.0:
        raise ValueError("the MuJoCo brake replay needs a category-0 stop at t = 0")
    if scenario.events or scenario.constraints:
        raise ValueError("the MuJoCo brake replay takes no locks or frame constraints")
    for brake in scenario.brakes:
        if not isinstance(brake.friction, Coulomb) or brake.friction.ramp != 0.0:
            raise ValueError(f"brake on {brake.joint}: Coulomb friction without a ramp only")


def run_vtm_pin(cases: PeerCases, engine: str) -> tuple[list[dict], float]:
    """Run the cases as a study worker does; their records and the call's wall time [s]."""
    start = time.perf_counter()
    records = run_cases(list(cases.tasks), engine)
    wall = time.perf_counter() - start
    bad = [r["status"] for r in records if r["status"] != "ok"]
    if bad:
        raise RuntimeError(f"vtm_pin: {len(bad)} cases not ok, e.g. {bad[0]}")
    return records, wall


def vtm_pin_figures(records: Sequence[dict]) -> dict[str, np.ndarray]:
    """Figure name -> one value per case, from the study records."""
    return {name: np.array([r["metrics"][name] for r in records]) for name in FIGURES}


def brake_phases(scenario: vp.Scenario) -> list[tuple[float, np.ndarray]]:
    """(start time [s], joint-side friction torque per joint [N m]) of each brake phase."""
    robot = scenario.robot
    starts = sorted({0.0, *(b.delay for b in scenario.brakes)})
    phases = []
    for start in starts:
        torque = np.zeros(robot.nv)
        for brake in scenario.brakes:
            if brake.delay <= start:
                j = robot.joint_index(brake.joint)
                torque[j] = brake.sliding(0.0, 1.0, float(robot.gear_ratio[j]))
        phases.append((start, torque))
    return phases


def brake_model(scenario: vp.Scenario, dt: float) -> mujoco.MjModel:
    """The case's MuJoCo model (friction off): inertias, armature, stiff friction rows."""
    spec = mr._spec(scenario, dt)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    mr.drop_geometry(spec)
    mr.copy_link_inertias(spec, scenario.robot)
    for joint in spec.joints:
        joint.solimp_friction = np.array([STIFF_IMPEDANCE, STIFF_IMPEDANCE, 0.001, 0.5, 2.0])
        joint.solref_friction = np.array([TIMECONST_STEPS * dt, 1.0])
    return spec.compile()


def phase_models(
    scenarios: Sequence[vp.Scenario], dt: float
) -> tuple[list[int], list[list[mujoco.MjModel]]]:
    """Each brake phase's first step and its model per case (one compile per payload class).

    A later phase's model is a copy of the first with the brakes' friction set. A brake
    engages at the first step at or after its delay (on the grid when dt divides it).

    Raises:
        ValueError: The cases' brakes engage at different times.
    """
    starts = [t for t, _ in brake_phases(scenarios[0])]
    compiled: dict[tuple[bytes, int], mujoco.MjModel] = {}
    per_phase: list[list[mujoco.MjModel]] = [[] for _ in starts]
    for scenario in scenarios:
        phases = brake_phases(scenario)
        if [t for t, _ in phases] != starts:
            raise ValueError("the cases' brakes engage at different times")
        key = model_key(scenario.robot.model)
        for k, (_, torque) in enumerate(phases):
            if (key, k) not in compiled:
                first = compiled.get((key, 0))
                model = brake_model(scenario, dt) if first is None else copy.copy(first)
                model.dof_frictionloss[:] = torque
                compiled[key, k] = model
            elif not np.array_equal(compiled[key, k].dof_frictionloss, torque):
                raise ValueError("cases of one model have different brakes")
            per_phase[k].append(compiled[key, k])
    return [int(np.ceil(t / dt - 1e-9)) for t in starts], per_phase


def initial_states(model: mujoco.MjModel, scenarios: Sequence[vp.Scenario]) -> np.ndarray:
    """MuJoCo's full physics state of each case at t = 0, shape (cases, state size)."""
    data = mujoco.MjData(model)
    kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    states = np.empty((len(scenarios), mujoco.mj_stateSize(model, kind)))
    for row, scenario in zip(states, scenarios, strict=True):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = scenario.q0
        data.qvel[:] = scenario.v0
        mujoco.mj_getState(model, data, row, kind)
    return states


def run_mujoco(
    scenarios: Sequence[vp.Scenario],
    tested: Sequence[int],
    dt: float,
    runner: mujoco.rollout.Rollout,
    until_rest: bool = True,
) -> MujocoStops:
    """Replay every case in MuJoCo at step dt, all cases in each ``rollout`` call.

    ``wall`` times the rollout calls alone; ``total`` the whole call (compiling the models,
    the initial states and the figures too).

    Args:
        scenarios: The cases (same duration, rest speed and brake delays).
        tested: Each case's tested joint.
        dt: Step [s].
        runner: A ``mujoco.rollout.Rollout`` (its thread count is the run's).
        until_rest: End once every joint of every case stayed at rest for a whole chunk
            (else run to the scenarios' duration).
    """
    began = time.perf_counter()
    firsts, models = phase_models(scenarios, dt)
    total = round(scenarios[0].duration / dt)
    chunk = max(1, round(CHUNK_TIME / dt))
    rest = scenarios[0].stop.rest_speed  # type: ignore[union-attr]
    data = mujoco.MjData(models[0][0])
    state = initial_states(models[0][0], scenarios)
    nq, rows, joint = models[0][0].nq, np.arange(len(scenarios)), np.asarray(tested)
    q0 = state[:, 1 : 1 + nq].copy()
    speeds = [np.abs(state[None, :, 1 + nq : 1 + 2 * nq])]  # (steps, cases, joints)
    step, wall = 0, 0.0
    while step < total:
        phase = max(k for k, first in enumerate(firsts) if first <= step)
        nstep = min([step + chunk, total, *(f for f in firsts if f > step)]) - step
        begin = time.perf_counter()
        states, _ = runner.rollout(models[phase], data, state, nstep=nstep)
        wall += time.perf_counter() - begin
        speeds.append(np.abs(states[:, :, 1 + nq : 1 + 2 * nq]).transpose(1, 0, 2))
        state = states[:, -1].copy()
        step += nstep
        resting = phase == len(firsts) - 1 and nstep == chunk and speeds[-1].max() <= rest
        if until_rest and resting:
            break
    t = dt * np.arange(step + 1)
    v = np.concatenate(speeds)
    test, arm = v[:, rows, joint], v.max(axis=2)
    figures = {
        "test_stop_time": rest_times(t, test, rest),
        "stop_angle": np.abs(state[rows, 1 + joint] - q0[rows, joint]),
        "robot_stop_time": rest_times(t, arm, rest),
    }
    return MujocoStops(dt, figures, wall, time.perf_counter() - began, float(t[-1]), step)


def relative_errors(
    figures: dict[str, np.ndarray], reference: dict[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """|figure - reference| / |reference| per case; an angle's denominator >= ANGLE_FLOOR."""
    errors = {}
    for name, ref in reference.items():
        floor = ANGLE_FLOOR if name == "stop_angle" else 0.0
        errors[name] = np.abs(figures[name] - ref) / np.maximum(np.abs(ref), floor)
    return errors


def equal_accuracy_dt(rows: Sequence[dict], tolerance: float) -> float | None:
    """The largest dt whose every figure of every case is within ``tolerance``, if any."""
    ok = [r["dt"] for r in rows if max(r["max_error"].values()) <= tolerance]
    return max(ok) if ok else None


def holding_over_sliding(scenario: vp.Scenario) -> float:
    """Largest holding torque of a stuck brake over its sliding torque, in vtm_pin's run [-].

    Above 1 a brake holds its joint only thanks to its static torque: MuJoCo's single friction
    level (the sliding torque) lets that joint slip, so the case is beyond what MuJoCo's
    model can reproduce. One untimed scalar run of the case.
    """
    robot = scenario.robot
    result = simulate(scenario.problem, scenario.integrator, transition=scenario.transition)
    report = compute_stopping_report(robot, result, scenario.brakes, scenario.tool_frame)
    ratios = [0.0]
    for brake in scenario.brakes:
        j = robot.joint_index(brake.joint)
        hold = report.joints[j].peak_holding_torque
        if np.isfinite(hold):
            ratios.append(hold / brake.sliding(0.0, 1.0, float(robot.gear_ratio[j])))
    return max(ratios)


def vtm_pin_times(records: Sequence[dict], wall: float) -> dict[str, float]:
    """Per-case times [s]: ``simulate`` (the engine's share) and ``whole`` (the call / cases)."""
    simulate = sum(r["timing"]["simulate"] for r in records) / len(records)
    return {"simulate": simulate, "whole": wall / len(records)}


def measure(cases: PeerCases, ladder: Sequence[float], repeats: int) -> dict:
    """Run both sides: one round for the figures, then ``repeats`` timed rounds (medians).

    Returns:
        ``reference`` (vtm_pin's scalar figures), ``one_level`` (per case: no brake of
        vtm_pin's run held more than its sliding torque, :func:`holding_over_sliding`; the
        errors of ``rows`` are over these cases, ``beyond_one_level`` over the others),
        ``engines_agree`` (largest relative
        difference of the batched engine's figures), ``batched_cases`` (cases the batched
        engine took), ``vtm_pin`` (engine -> per-case times [s]) and ``rows`` (one per dt:
        largest error per figure, MuJoCo's per-case times [s], end time, steps).
    """
    n = len(cases.scenarios)
    timings: dict[str, list[dict[str, float]]] = {"batched": [], "scalar": []}
    mujoco_times: dict[float, list[tuple[float, float]]] = {dt: [] for dt in ladder}
    with mujoco.rollout.Rollout(nthread=0) as runner:
        for round_ in range(repeats + 1):
            records = {}
            for engine in timings:
                records[engine], wall = run_vtm_pin(cases, engine)
                timings[engine].append(vtm_pin_times(records[engine], wall))
            replays = {dt: run_mujoco(cases.scenarios, cases.tested, dt, runner) for dt in ladder}
            for dt, replay in replays.items():
                mujoco_times[dt].append((replay.wall / n, replay.total / n))
            if round_ == 0:  # the figures, and a warm-up: not timed
                reference = vtm_pin_figures(records["scalar"])
                batched = vtm_pin_figures(records["batched"])
                first = replays
                for times in [*timings.values(), *mujoco_times.values()]:
                    times.clear()
    one_level = np.array([holding_over_sliding(s) <= 1.0 for s in cases.scenarios])
    rows = []
    for dt, replay in first.items():
        errors = relative_errors(replay.figures, reference)
        beyond = {k: float(e[~one_level].max(initial=0.0)) for k, e in errors.items()}
        errors = {k: np.where(one_level, e, 0.0) for k, e in errors.items()}
        rollout, whole = (statistics.median(t) for t in zip(*mujoco_times[dt], strict=True))
        rows.append(
            {
                "dt": dt,
                "max_error": {k: float(e.max()) for k, e in errors.items()},
                "worst_case": {k: int(e.argmax()) for k, e in errors.items()},
                "beyond_one_level": beyond,
                "mujoco_rollout": rollout,
                "mujoco_whole": whole,
                "end_time": replay.end_time,
                "steps": replay.steps,
            }
        )
    agree = max(float(e.max()) for e in relative_errors(batched, reference).values())
    return {
        "reference": {k: v.tolist() for k, v in reference.items()},
        "engines_agree": agree,
        "batched_cases": sum(r.get("engine") == "batched" for r in records["batched"]),
        "vtm_pin": {
            engine: {k: statistics.median(t[k] for t in times) for k in times[0]}
            for engine, times in timings.items()
        },
        "one_level": one_level.tolist(),
        "rows": rows,
    }


def ratio_line(label: str, theirs: float, ours: float) -> str:
    """One line of the equal-accuracy ratio, saying which side is faster."""
    ratio = theirs / ours
    faster = f"MuJoCo {1 / ratio:.2f} x faster" if ratio < 1 else f"vtm_pin {ratio:.2f} x faster"
    return f"  {label:<44} {1e3 * theirs:8.3f} / {1e3 * ours:8.3f} ms = {ratio:6.2f} ({faster})"


def format_report(result: dict, cases: int, tolerance: float) -> str:
    """The table (error and MuJoCo time per dt) and the ratios at equal accuracy."""
    one_level = sum(result["one_level"])
    lines = [
        f"{cases} cases; error = max over the {one_level} cases whose brakes never held more "
        f"than their sliding torque in vtm_pin of |MuJoCo - vtm_pin| / vtm_pin (angle "
        f"denominator >= {ANGLE_FLOOR} rad); 'beyond': the same over the other "
        f"{cases - one_level} (MuJoCo's one friction level lets a joint slip there); MuJoCo "
        "Euler, one thread, all cases per rollout call",
        f"{'dt [s]':>8} {'test_stop_time':>14} {'stop_angle':>10} {'robot_stop_time':>15} "
        f"{'MuJoCo ms/case':>14} {'(whole)':>8} {'end [s]':>7} {'beyond: time, angle':>19}",
    ]
    for row in result["rows"]:
        err, beyond = row["max_error"], row["beyond_one_level"]
        lines.append(
            f"{row['dt']:>8.1e} {err['test_stop_time']:>14.2e} {err['stop_angle']:>10.2e} "
            f"{err['robot_stop_time']:>15.2e} {1e3 * row['mujoco_rollout']:>14.3f} "
            f"{1e3 * row['mujoco_whole']:>8.3f} {row['end_time']:>7.2f} "
            f"{beyond['test_stop_time']:>9.2e} {beyond['stop_angle']:>9.2e}"
        )
    ours = result["vtm_pin"]
    lines.append(
        f"vtm_pin per case [ms]: batched {1e3 * ours['batched']['simulate']:.3f} simulation, "
        f"{1e3 * ours['batched']['whole']:.3f} with build and report "
        f"({result['batched_cases']} of {cases} cases on the batched engine); scalar "
        f"{1e3 * ours['scalar']['simulate']:.3f}, {1e3 * ours['scalar']['whole']:.3f}; "
        f"engines' figures agree within {result['engines_agree']:.1e} (relative)"
    )
    dt = equal_accuracy_dt(result["rows"], tolerance)
    if dt is None:
        lines.append(f"no dt of the ladder gets every case within {100 * tolerance:g} %")
        return "\n".join(lines)
    row = next(r for r in result["rows"] if r["dt"] == dt)
    lines.append(
        f"equal accuracy ({100 * tolerance:g} % on every figure of those {one_level} cases): "
        f"MuJoCo dt = "
        f"{dt:g} s; MuJoCo / vtm_pin time per case (> 1: vtm_pin is faster):"
    )
    for engine in ("batched", "scalar"):
        lines.append(
            ratio_line(
                f"rollout / {engine} simulation",
                row["mujoco_rollout"],
                ours[engine]["simulate"],
            )
        )
        lines.append(
            ratio_line(
                f"whole replay / {engine} build+simulate+report",
                row["mujoco_whole"],
                ours[engine]["whole"],
            )
        )
    return "\n".join(lines)


def plot(result: dict, tolerance: float) -> Figure:
    """Largest error against dt, and time per case against dt (vtm_pin's as lines)."""
    figure = Figure(figsize=(10, 4))
    left, right = figure.subplots(1, 2)
    dts = [r["dt"] for r in result["rows"]]
    for name in FIGURES:
        left.loglog(dts, [r["max_error"][name] for r in result["rows"]], "o-", label=name)
    left.axhline(tolerance, color="grey", ls="--", label=f"{100 * tolerance:g} %")
    left.set(xlabel="MuJoCo dt [s]", ylabel="largest relative error, one-level cases [-]")
    left.legend(fontsize=8)
    right.loglog(dts, [1e3 * r["mujoco_rollout"] for r in result["rows"]], "o-", label="MuJoCo")
    for engine, style in (("batched", "-"), ("scalar", ":")):
        right.axhline(
            1e3 * result["vtm_pin"][engine]["simulate"],
            color="k",
            ls=style,
            label=f"vtm_pin {engine}",
        )
    right.set(xlabel="MuJoCo dt [s]", ylabel="simulation time per case [ms]")
    right.legend(fontsize=8)
    figure.suptitle("UR10 brake stops: MuJoCo against vtm_pin")
    figure.tight_layout()
    return figure


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", type=Path, default=STUDY)
    parser.add_argument("--cases", type=int, default=1250, help="first N samples")
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds (median)")
    parser.add_argument("--dt", type=float, nargs="+", default=list(DT), help="MuJoCo steps [s]")
    parser.add_argument("--tol", type=float, default=TOLERANCE, help="relative error [-]")
    parser.add_argument("--out", type=Path, default=None, help="folder (default: a temp one)")
    args = parser.parse_args(argv)
    if args.cases < 1 or args.repeats < 1:
        parser.error("--cases and --repeats: at least 1")
    out = args.out or Path(tempfile.mkdtemp(prefix="mujoco_brake_peer_"))
    out.mkdir(parents=True, exist_ok=True)
    cases = load_cases(args.study, args.cases)
    print(
        f"{len(cases.scenarios)} cases of {args.study.name}, {args.repeats} timed rounds",
        file=sys.stderr,
    )
    result = measure(cases, sorted(args.dt, reverse=True), args.repeats)
    print(format_report(result, len(cases.scenarios), args.tol))
    plot(result, args.tol).savefig(out / "mujoco_brake_peer.png", dpi=120)
    (out / "mujoco_brake_peer.json").write_text(json.dumps(result, indent=2))
    print(f"wrote {out}/mujoco_brake_peer.png and mujoco_brake_peer.json")


if __name__ == "__main__":
    main()
