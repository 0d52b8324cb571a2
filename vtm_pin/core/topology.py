"""A kinematic topology: which joints are locked, and the reduced model of the free ones.

Between events only the free coordinates are integrated (model only what the scene requires):
Pinocchio's ``buildReducedModel`` fixes the locked joints at their event configuration, and
ABA on the reduced model gives the free accelerations in O(n_free). Reduced models and their
Pinocchio Data come from the robot's cache (:mod:`vtm_pin.files.model_cache`), keyed by the lock set
and the locked joints' angles, and are built only when a phase first needs them.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..numerics.transitions.recursive import weightless as without_gravity
from ..physics.robot import Robot


def full_data(robot: Robot) -> pin.Data:
    """The robot's shared Pinocchio Data of its full model (scratch space, see the cache)."""
    model = robot.model
    data: pin.Data = robot.cache.get("data", model.createData)
    return data


def weightless_model(robot: Robot) -> tuple[pin.Model, pin.Data]:
    """The robot's model without gravity, and its Data (for M v and M^-1 tau products)."""
    return robot.cache.get("weightless", lambda: _with_data(without_gravity(robot.model)))


def reduced_model(
    robot: Robot, locked: tuple[int, ...], q_locked: np.ndarray, weightless: bool = False
) -> tuple[pin.Model, pin.Data]:
    """The model with the coordinates ``locked`` fixed at ``q_locked`` [rad], and its Data.

    Pinocchio's ``buildReducedModel`` uses the angles of the locked joints only, so the
    model is cached under the lock set and those angles (their exact bytes).

    Args:
        robot: The full robot.
        locked: Sorted indices of the locked coordinates; empty: the full model.
        q_locked: Their angles [rad], shape (len(locked),).
        weightless: Without gravity (for the products of the joint-lock transition).
    """
    if not locked:
        return weightless_model(robot) if weightless else (robot.model, full_data(robot))
    key = ("reduced", locked, np.asarray(q_locked, dtype=float).tobytes(), weightless)
    if weightless:
        return robot.cache.get(
            key, lambda: _with_data(without_gravity(reduced_model(robot, locked, q_locked)[0]))
        )

    def build() -> tuple[pin.Model, pin.Data]:
        model = robot.model
        q = np.zeros(robot.nv)
        q[list(locked)] = q_locked
        ids = [model.getJointId(robot.joints[i]) for i in locked]
        return _with_data(pin.buildReducedModel(model, ids, q))

    return robot.cache.get(key, build)


@functools.lru_cache(maxsize=1024)
def lock_indices(nv: int, locked: tuple[int, ...]) -> tuple[np.ndarray, ...]:
    """A lock set's index arrays (read only), as :class:`Topology` keeps them.

    Args:
        nv: Number of coordinates.
        locked: The locked coordinates, sorted.

    Returns:
        The locked indices, the free mask, the free indices, and the flat indices of the free
        block of an (nv, nv) matrix.
    """
    locked_index = np.array(locked, dtype=np.intp)
    free_mask = np.ones(nv, dtype=bool)
    free_mask[locked_index] = False
    free = np.flatnonzero(free_mask)
    free_block = (free[:, None] * nv + free).ravel()
    out = (locked_index, free_mask, free, free_block)
    for array in out:
        array.flags.writeable = False
    return out


def _with_data(model: pin.Model) -> tuple[pin.Model, pin.Data]:
    return model, model.createData()


class Topology:
    """The lock set of one phase of motion and the reduced dynamics of its free coordinates.

    Args:
        robot: The full robot.
        locked: Indices of the locked coordinates.
        q: Configuration at which the locks were applied [rad], shape (nv,).
    """

    def __init__(self, robot: Robot, locked: Sequence[int], q: np.ndarray) -> None:
        self.robot = robot
        self.nv = nv = robot.nv
        self.locked = tuple(sorted(int(i) for i in locked))
        #: ``locked`` as an index array [-]; per coordinate, whether it is free; the free
        #: indices; the flat indices of the free block of an (nv, nv) matrix (``M.take(...)``
        #: is M_ff). Read only: shared by the topologies of one lock set.
        indices = lock_indices(nv, self.locked)
        self.locked_index, self.free_mask, self.free, self.free_block = indices
        self.q_locked = np.asarray(q, dtype=float)[self.locked_index]
        self._k = int(self.free.size)
        self._tau = np.zeros(self._k)
        self._model: pin.Model | None = None
        self._data: pin.Data | None = None

    def _build(self) -> tuple[pin.Model, pin.Data]:
        if self._k == 0:  # nothing moves: the full model (never evaluated)
            self._model, self._data = self.robot.model, full_data(self.robot)
        else:
            self._model, self._data = reduced_model(self.robot, self.locked, self.q_locked)
        return self._model, self._data

    @property
    def model(self) -> pin.Model:
        """Pinocchio model of the free coordinates (the full one if none or all are locked)."""
        return self._build()[0] if self._model is None else self._model

    @property
    def data(self) -> pin.Data:
        """Pinocchio Data of :attr:`model` (shared scratch space)."""
        return self._build()[1] if self._data is None else self._data

    @property
    def n_free(self) -> int:
        """Number of free coordinates."""
        return self._k

    def split(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Free state y = (q_f, v_f) of the full (q, v)."""
        return np.concatenate((q[self.free], v[self.free]))

    def merge(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full (q, v) of a free state y; locked q at their lock values, locked v exactly 0."""
        k = self._k
        q = np.empty(self.nv)
        v = np.zeros(self.nv)
        q[self.locked_index] = self.q_locked
        q[self.free] = y[:k]
        v[self.free] = y[k : 2 * k]
        return q, v

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """Time derivative of the free state, (v_f, a_f) from ABA on the reduced model."""
        out = np.empty(2 * self._k)
        self.into(t, y, out)
        return out

    __call__ = rhs

    def into(self, t: float, y: np.ndarray, out: np.ndarray) -> None:
        """:meth:`rhs` written into ``out`` (an integrator's stage buffer): no new array."""
        k = self._k
        if k == 0:
            return
        if self._model is None:
            self._build()
        v = y[k:]
        out[:k] = v
        out[k:] = pin.aba(self._model, self._data, y[:k], v, self._tau)
