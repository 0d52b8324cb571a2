"""Matplotlib figures of a simulation (the paper's figs. 3-9, brake states, tool path).

Figures are built with :class:`matplotlib.figure.Figure` (no pyplot state), so they render
headless and show in notebooks alike. No numerics happen here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from ..core.results import SimulationResult
from ..physics.brakes import BrakeMode
from .analysis import EnergyMomentum
from .drawing import plot_poses
from .stopping import StoppingReport

if TYPE_CHECKING:
    from .run_output import RunOutput

Runs = Mapping[str, tuple[SimulationResult, EnergyMomentum]]
Values = Callable[[SimulationResult, EnergyMomentum], np.ndarray]

_STYLES = ["-", "--", ":", "-."]
_SHADES = {
    BrakeMode.FORWARD: ("tab:orange", "sliding"),
    BrakeMode.BACKWARD: ("tab:orange", "sliding"),
    BrakeMode.STUCK: ("0.6", "stuck"),
    BrakeMode.LOCKED: ("0.35", "locked"),
}


def plot_joint_angles(runs: Runs, gear_ratio: np.ndarray | None = None) -> Figure:
    """Joint angles q(t) [rad], or motor angles ratio x q if ``gear_ratio`` is given."""
    if gear_ratio is None:
        return _plot(runs, lambda r, e: r.q, "joint angle q [rad]", "Joint angles")
    return _plot(runs, lambda r, e: r.q * gear_ratio, "motor angle ratio x q [rad]", "Motor angles")


def plot_joint_rates(runs: Runs, gear_ratio: np.ndarray | None = None) -> Figure:
    """Joint rates v(t) [rad/s] (motor rates with ``gear_ratio``); jumps are transitions."""
    if gear_ratio is None:
        return _plot(runs, lambda r, e: r.v, "joint rate v [rad/s]", "Joint rates")
    return _plot(runs, lambda r, e: r.v * gear_ratio, "motor rate ratio x v [rad/s]", "Motor rates")


def plot_momenta(runs: Runs) -> Figure:
    """Generalized momenta (M v)_i [N m s] of the joints while they are free.

    With a consistent rule these are continuous across every lock; the naive rule makes them
    jump.
    """
    return _plot(
        runs,
        lambda r, e: e.p_free,
        "momentum (M v)_i [N m s]",
        "Generalized momenta of free joints",
    )


def plot_energy(runs: Runs) -> Figure:
    """Total mechanical energy T + V [J]: constant between events, dropping at each lock."""
    fig = Figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for k, (name, (result, energy)) in enumerate(runs.items()):
        ax.plot(result.t, energy.total, _STYLES[k % len(_STYLES)], color="k", label=name)
    _mark_events(ax, runs)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("total energy T + V [J]")
    ax.set_title("Total energy")
    ax.grid(alpha=0.3)
    ax.legend()
    return fig


def plot_brake_states(result: SimulationResult) -> Figure:
    """Joint angle and rate of every joint, with the brake state shaded behind them."""
    n = len(result.joints)
    fig = Figure(figsize=(10, 1.6 * n + 1), layout="constrained")
    axes = fig.subplots(n, 2, sharex=True, squeeze=False)
    for j, joint in enumerate(result.joints):
        for col, (values, label) in enumerate([(result.q, "q [rad]"), (result.v, "v [rad/s]")]):
            ax = axes[j, col]
            _shade_modes(ax, result.t, result.modes[:, j])
            ax.plot(result.t, values[:, j], color="C0", lw=1.2)
            ax.set_ylabel(f"{joint}\n{label}", fontsize="small")
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time t [s]")
    handles = [
        Patch(color=color, alpha=0.3, label=label)
        for color, label in {v[1]: v for v in _SHADES.values()}.values()
    ]
    fig.legend(handles=handles, loc="outside upper center", ncol=3, fontsize="small")
    fig.suptitle("Joint motion and brake states", y=1.02)
    return fig


def plot_tcp_path(reports: Mapping[str, StoppingReport]) -> Figure:
    """Tool-frame path after the stop signal in 3D, start and end marked, one line per rule."""
    fig = Figure(figsize=(7, 6), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    for k, (name, report) in enumerate(reports.items()):
        p = report.tcp_path
        ax.plot(p[:, 0], p[:, 1], p[:, 2], _STYLES[k % len(_STYLES)], color=f"C{k}", label=name)
        ax.scatter(*p[-1], color=f"C{k}", marker="x", s=40)
    first = next(iter(reports.values()))
    ax.scatter(*first.tcp_path[0], color="k", marker="o", s=30, label="at stop signal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(f"Path of '{first.tool_frame}' after the stop signal (x = final)")
    ax.legend(fontsize="small")
    return fig


def plot_constraint_drift(result: SimulationResult) -> Figure:
    """Constraint drift max |h| [m, rad] and max |J v| [m/s, rad/s] of the frame constraints."""
    fig = Figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    floor = np.finfo(float).tiny
    ax.semilogy(result.t, np.maximum(result.drift[:, 0], floor), label="max |h| (position)")
    ax.semilogy(result.t, np.maximum(result.drift[:, 1], floor), label="max |J v| (velocity)")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("constraint residual [m, rad | m/s, rad/s]")
    ax.set_title("Drift of the loop closures and dockings")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    return fig


def plot_run(output: RunOutput) -> dict[str, Figure]:
    """The figures ``vtm-pin run`` saves for a run, by PNG file name.

    Joint angles, rates, momenta, energy and poses always; motor angles and rates when a gear
    ratio is set; the constraint drift with frame constraints; brake states and the tool path
    with a stop. Compared rules are overlaid (dashed).
    """
    runs, result, scenario = output.runs, output.result, output.scenario
    figures = {
        "joint_angles.png": plot_joint_angles(runs),
        "joint_rates.png": plot_joint_rates(runs),
        "momenta.png": plot_momenta(runs),
        "energy.png": plot_energy(runs),
        "poses.png": plot_poses(scenario.robot, output.results, scenario.tool_frame),
    }
    ratio = scenario.robot.gear_ratio
    if np.any(ratio != 1.0):
        figures["motor_angles.png"] = plot_joint_angles(runs, ratio)
        figures["motor_rates.png"] = plot_joint_rates(runs, ratio)
    if np.any(np.isfinite(result.drift)):
        figures["constraint_drift.png"] = plot_constraint_drift(result)
    if output.stopping:
        figures["brakes.png"] = plot_brake_states(result)
        figures["tcp_path.png"] = plot_tcp_path(output.stopping)
    return figures


def _shade_modes(ax: Axes, t: np.ndarray, modes: np.ndarray) -> None:
    start = 0
    for i in range(1, t.size + 1):
        if i == t.size or modes[i] != modes[start]:
            mode = BrakeMode(int(modes[start]))
            if mode in _SHADES:
                ax.axvspan(t[start], t[i - 1], color=_SHADES[mode][0], alpha=0.3, lw=0)
            start = i


def _plot(runs: Runs, values: Values, ylabel: str, title: str) -> Figure:
    fig = Figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    colors = [f"C{i}" for i in range(10)]
    for k, (name, (result, energy)) in enumerate(runs.items()):
        y = values(result, energy)
        for j, joint in enumerate(result.joints):
            label = f"{joint} ({name})" if len(runs) > 1 else joint
            ax.plot(
                result.t,
                y[:, j],
                _STYLES[k % len(_STYLES)],
                color=colors[j % len(colors)],
                label=label,
            )
    _mark_events(ax, runs)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", ncol=max(1, len(runs)))
    return fig


def _mark_events(ax: Axes, runs: Runs) -> None:
    first = next(iter(runs.values()))[0]
    for event in first.events:
        ax.axvline(event.t, color="0.5", lw=0.8, ls=":")
        ax.annotate(
            f"{event.kind} " + ",".join(event.lock),
            (event.t, 1.0),
            xycoords=("data", "axes fraction"),
            textcoords="offset points",
            xytext=(2, -10),
            fontsize="x-small",
            color="0.3",
            rotation=90 if len(first.events) > 3 else 0,
            va="top",
        )
