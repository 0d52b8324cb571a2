"""Quantities derived from a simulated motion: energies and generalized momenta over time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .dynamics import compute_M
from .results import SimulationResult
from .robot import Robot


@dataclass(frozen=True)
class EnergyMomentum:
    """Energy and momentum at every sample of a simulation.

    Attributes:
        kinetic: Kinetic energy 1/2 v^T M v [J], shape (k,).
        potential: Gravitational potential energy [J], shape (k,).
        p: Generalized momentum M v [N m s], shape (k, n).
        p_free: ``p`` where the joint is free, NaN where it is locked (the paper's F^T M v).
    """

    kinetic: np.ndarray
    potential: np.ndarray
    p: np.ndarray
    p_free: np.ndarray

    @property
    def total(self) -> np.ndarray:
        """Total mechanical energy [J], shape (k,)."""
        return self.kinetic + self.potential


def compute_energy_momentum(robot: Robot, result: SimulationResult) -> EnergyMomentum:
    """Evaluate M(q) at every sample and derive energies and momenta."""
    model = robot.model
    data = model.createData()
    k = result.t.size
    kinetic = np.empty(k)
    potential = np.empty(k)
    p = np.empty((k, robot.nv))
    for i in range(k):
        q, v = result.q[i], result.v[i]
        M = compute_M(model, data, q)
        p[i] = M @ v
        kinetic[i] = 0.5 * float(v @ p[i])
        potential[i] = float(pin.computePotentialEnergy(model, data, q))
    return EnergyMomentum(
        kinetic=kinetic, potential=potential, p=p, p_free=np.where(result.free, p, np.nan)
    )
