"""A kinematic topology: which joints are locked, and the reduced model of the free ones.

Between events only the free coordinates are integrated (model only what the scene requires):
Pinocchio's ``buildReducedModel`` fixes the locked joints at their event configuration, and
ABA on the reduced model gives the free accelerations in O(n_free).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from .robot import Robot


class Topology:
    """The lock set of one phase of motion and the reduced dynamics of its free coordinates.

    Args:
        robot: The full robot.
        locked: Indices of the locked coordinates.
        q: Configuration at which the locks were applied [rad], shape (nv,).
    """

    def __init__(self, robot: Robot, locked: Sequence[int], q: np.ndarray) -> None:
        self.nv = robot.nv
        self.locked = tuple(sorted(int(i) for i in locked))
        self.free = np.setdiff1d(np.arange(self.nv), self.locked)
        self.q_locked = np.asarray(q, dtype=float)[list(self.locked)].copy()
        model = robot.model
        if self.locked and self.free.size:
            joint_ids = [model.getJointId(robot.joints[i]) for i in self.locked]
            self.model = pin.buildReducedModel(model, joint_ids, np.asarray(q, dtype=float))
        else:
            self.model = model
        self.data = self.model.createData()
        self._tau = np.zeros(self.free.size)
        self._k = int(self.free.size)

    @property
    def n_free(self) -> int:
        """Number of free coordinates."""
        return int(self.free.size)

    def split(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Free state y = (q_f, v_f) of the full (q, v)."""
        return np.concatenate([q[self.free], v[self.free]])

    def merge(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full (q, v) of a free state y; locked q at their lock values, locked v exactly 0."""
        k = self.n_free
        q = np.empty(self.nv)
        v = np.zeros(self.nv)
        q[list(self.locked)] = self.q_locked
        q[self.free] = y[:k]
        v[self.free] = y[k:]
        return q, v

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """Time derivative of the free state, (v_f, a_f) from ABA on the reduced model."""
        k = self._k
        out = np.empty(2 * k)
        if k == 0:
            return out
        out[:k] = y[k:]
        out[k:] = pin.aba(self.model, self.data, y[:k], y[k:], self._tau)
        return out
