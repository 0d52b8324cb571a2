"""The run pipeline: a scenario's runs, energies, stopping reports and summary, and its files.

:func:`run` is what ``vtm-pin run`` does without the command line: simulate a scenario with
one or more transition rules, then derive everything the tables and files need. The notebooks
and studies call it too. :func:`write_outputs` writes a run's files into a folder, all or
nothing. No figure is drawn and nothing is printed unless asked: :func:`write_outputs` draws
with :func:`vtm_pin.outputs.plotting.plot_run`.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.results import SimulationResult
from ..exceptions import OutputError, ScenarioError, VtmWarning
from ..files.inputs import find_shipped
from ..files.staging import write_staged
from ..scene.scenario import SCENARIOS_DIR, Scenario, load_scenario, run_scenario
from .analysis import compute_energy_momentum
from .figures import bound_variants, bounded, stop_figures
from .report import build_summary, write_trajectory
from .run_output import RunOutput
from .stopping import StoppingReport, compute_stopping_report

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Called with the transition rule being run and the simulated time reached [s].
Progress = Callable[[str, float], None]

#: Resolution of the saved PNG figures [dots per inch].
FIGURE_DPI = 120


def find_scenario(spec: str | Path) -> Path:
    """The scenario file ``spec`` names: an existing path, else a shipped scenario's name.

    A path that exists wins; otherwise a bare name (``pendulum3r``, or ``pendulum3r.yaml``)
    names a file of :data:`vtm_pin.scene.scenario.SCENARIOS_DIR`, the scenarios shipped with the
    package. Any other path is returned as it is, so that reading it reports what is wrong.

    Raises:
        ScenarioError: ``spec`` is a bare name that is neither a file nor a shipped scenario;
            the message lists the shipped ones.
    """
    return find_shipped(spec, SCENARIOS_DIR, "scenario", ScenarioError)


def run(
    scenario: Scenario | str | Path,
    *,
    transition: str | None = None,
    compare: Sequence[str] = (),
    progress: Progress | None = None,
) -> RunOutput:
    """Simulate a scenario and derive its energies, stopping reports and summary.

    Args:
        scenario: A loaded scenario, a scenario file, or a shipped scenario's name (see
            :func:`find_scenario`).
        transition: Transition rule of the main run; the scenario's by default.
        compare: Further rules to run the same scenario with (repeats and the main rule are
            dropped); they appear under ``compare`` in the summary.
        progress: Called with the rule and the simulated time [s] as each run advances.

    Each flag of the main run (:mod:`vtm_pin.outputs.flags`: a brake that cannot hold the load, a
    payload above its rating, ...) is also issued as a :class:`~vtm_pin.VtmWarning`.

    Returns:
        The results, energies, stopping reports (for a scenario with a stop) and summary.

    Raises:
        ScenarioError: The scenario is malformed, or its run broke one of its limits.
        SimulationError: A simulation diverged.
    """
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(find_scenario(scenario))
    main = transition or scenario.transition
    rules = list(dict.fromkeys([main, *compare]))
    results = {rule: _simulate(scenario, rule, progress) for rule in rules}
    energies = {rule: compute_energy_momentum(scenario.robot, r) for rule, r in results.items()}
    stopping: dict[str, StoppingReport] = {}
    if scenario.stop is not None:
        stopping = {
            rule: compute_stopping_report(scenario.robot, r, scenario.brakes, scenario.tool_frame)
            for rule, r in results.items()
        }
    others = {rule: results[rule] for rule in rules[1:]}
    figures = stop_figures(scenario, results[main], stopping[main]) if stopping else None
    if figures is not None and scenario.bounds is not None:
        with warnings.catch_warnings():  # the variants' own flags: bounded() says what counts
            warnings.simplefilter("ignore", VtmWarning)
            cases = bound_variants(scenario)
            figures = bounded(scenario, figures, [(c, run_scenario(c, main)) for c in cases])
    for flag in figures.flags if figures is not None else ():
        warnings.warn(flag.message, VtmWarning, stacklevel=2)
    summary = build_summary(scenario, results[main], energies[main], others, stopping, figures)
    return RunOutput(scenario, results, energies, stopping, summary, figures)


def _simulate(scenario: Scenario, rule: str, progress: Progress | None) -> SimulationResult:
    """One run of ``scenario`` with ``rule``, reporting its progress under the rule's name."""
    if progress is None:
        return run_scenario(scenario, rule)
    report = progress
    return run_scenario(scenario, rule, lambda t: report(rule, t))


def check_output_folder(out: str | Path) -> None:
    """Refuse, before any simulation, an output folder that cannot be created or written.

    Nothing is created: a probe folder is made (and removed) in the nearest existing folder
    on the way to ``out``.

    Raises:
        OutputError: ``out`` or a folder on its way is a file, or it cannot be written.
    """
    try:
        target = Path(os.path.abspath(out))
        existing = next(p for p in [target, *target.parents] if p.exists())
        if not existing.is_dir():
            problem = f"'{existing}' is a file, not a folder"
        else:
            os.rmdir(tempfile.mkdtemp(prefix=".vtm-pin-probe-", dir=existing))
            return
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        problem = f"cannot write in '{out}' ({reason})"
    raise OutputError(str(out), problem)


def write_outputs(
    output: RunOutput, out: str | Path, figures: Mapping[str, Figure] | None = None
) -> list[str]:
    """Write a run's files into ``out``: all of them, or none.

    The files (``summary.json``, ``trajectory.csv``, ``trajectory_<rule>.csv`` per compared
    rule, and the PNG figures) are written into a staging folder beside ``out``, then moved
    in; files of the same name already in ``out`` are replaced, others are kept.

    Args:
        output: The run, as :func:`run` returns it.
        out: The output folder; created if missing.
        figures: The figures to save, by file name; :func:`vtm_pin.outputs.plotting.plot_run`'s by
            default.

    Returns:
        The names of the files written, sorted.

    Raises:
        OutputError: A file could not be written; nothing was moved into ``out``.
    """
    if figures is None:
        from .plotting import plot_run  # Matplotlib only when figures are wanted

        figures = plot_run(output)
    shown = figures

    def write(staging: Path) -> None:
        (staging / "summary.json").write_text(
            json.dumps(output.summary, indent=2, allow_nan=False) + "\n"
        )
        for rule, result in output.results.items():
            suffix = "" if rule == output.rule else f"_{rule}"
            write_trajectory(staging / f"trajectory{suffix}.csv", result)
        for filename, figure in shown.items():
            figure.savefig(staging / filename, dpi=FIGURE_DPI)

    return write_staged(out, write)
