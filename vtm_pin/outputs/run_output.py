"""What one run of a scenario produced: results, energies, reports and summary.

Its own module, below both the pipeline that makes it and the plotting that draws it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..core.results import SimulationResult
from ..scene.scenario import Scenario
from .analysis import EnergyMomentum
from .figures import StopFigures
from .stopping import StoppingReport


@dataclass(frozen=True)
class RunOutput:
    """Everything one run of a scenario produced: results, energies, reports and summary.

    Attributes:
        scenario: The scenario that was run.
        results: Simulation per transition rule, the main rule first.
        energies: Energies and momenta at every sample, per rule.
        stopping: Stopping report per rule; empty if the scenario has no stop.
        summary: The JSON-ready summary of ``summary.json`` (keys documented in the README).
        figures: The main run's signed figures and flags (:mod:`vtm_pin.outputs.figures`); None
            without a stop.
    """

    scenario: Scenario
    results: Mapping[str, SimulationResult]
    energies: Mapping[str, EnergyMomentum]
    stopping: Mapping[str, StoppingReport]
    summary: Mapping[str, Any]
    figures: StopFigures | None = None

    @property
    def rule(self) -> str:
        """The main run's transition rule."""
        return next(iter(self.results))

    @property
    def result(self) -> SimulationResult:
        """The main run's simulation."""
        return self.results[self.rule]

    @property
    def runs(self) -> dict[str, tuple[SimulationResult, EnergyMomentum]]:
        """``{rule: (result, energy)}``, as :mod:`~vtm_pin.outputs.plotting` takes them."""
        return {rule: (result, self.energies[rule]) for rule, result in self.results.items()}
