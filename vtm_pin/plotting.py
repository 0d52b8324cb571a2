"""Matplotlib figures of a simulation (the paper's figs. 3-5); no numerics, no file reading."""

from __future__ import annotations

from collections.abc import Mapping

from matplotlib.figure import Figure

from .analysis import EnergyMomentum
from .simulation import SimulationResult

Runs = Mapping[str, tuple[SimulationResult, EnergyMomentum]]

_STYLES = ["-", "--", ":", "-."]


def plot_joint_angles(runs: Runs) -> Figure:
    """Joint angles q(t) [rad] of every joint, one line style per run."""
    return _plot(runs, lambda r, e: r.q, "joint angle q [rad]", "Joint angles")


def plot_joint_rates(runs: Runs) -> Figure:
    """Joint rates v(t) [rad/s]; the jumps at the locks are the transitions."""
    return _plot(runs, lambda r, e: r.v, "joint rate v [rad/s]", "Joint rates")


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


def _plot(runs: Runs, values, ylabel: str, title: str) -> Figure:  # type: ignore[no-untyped-def]
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


def _mark_events(ax, runs: Runs) -> None:  # type: ignore[no-untyped-def]
    first = next(iter(runs.values()))[0]
    for event in first.events:
        ax.axvline(event.t, color="0.5", lw=0.8, ls=":")
        ax.annotate(
            "lock " + ",".join(event.lock),
            (event.t, 1.0),
            xycoords=("data", "axes fraction"),
            textcoords="offset points",
            xytext=(2, -10),
            fontsize="x-small",
            color="0.3",
        )


__all__ = ["plot_energy", "plot_joint_angles", "plot_joint_rates", "plot_momenta"]
