"""Quantities derived from a simulated motion: energies and generalized momenta over time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..core.results import SimulationResult
from ..physics.robot import Robot


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
    """Momentum p = M(q) v, kinetic energy 1/2 v^T p and potential energy at every sample.

    p comes from RNEA without gravity at zero velocity with the acceleration v, which is
    M(q) v (armature included) in O(n), without forming M.
    """
    model = robot.model
    data = model.createData()
    weightless = pin.Model(model)
    weightless.gravity = pin.Motion.Zero()
    weightless_data = weightless.createData()
    zero = np.zeros(robot.nv)
    k = result.t.size
    potential = np.empty(k)
    p = np.empty((k, robot.nv))
    for i in range(k):
        q = result.q[i]
        p[i] = pin.rnea(weightless, weightless_data, q, zero, result.v[i])
        potential[i] = float(pin.computePotentialEnergy(model, data, q))
    kinetic = 0.5 * np.einsum("ij,ij->i", result.v, p)
    return EnergyMomentum(
        kinetic=kinetic, potential=potential, p=p, p_free=np.where(result.free, p, np.nan)
    )
