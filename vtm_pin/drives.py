"""Drive laws: the joint torques of the drives on the free joints during one phase.

A law is one small class with :meth:`DriveLaw.torques`. Three are built in: drives off, drives
holding the joint rates constant (before a stop signal: tau = RNEA(q, v, 0)), and the
category-1 ramp (a computed-torque law taking the rates from their value at the signal
linearly to zero over ``ramp_time``, with velocity feedback, clipped at ``torque_limit``).
Which joints' drives act is decided by the stop's timeline (a drive goes off when its brake
engages), not by the law.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .stop import Stop


class DriveLaw(ABC):
    """Drive torques on the free joints of one phase."""

    @abstractmethod
    def torques(
        self,
        model: pin.Model,
        data: pin.Data,
        t: float,
        q_f: np.ndarray,
        v_f: np.ndarray,
    ) -> np.ndarray:
        """Drive torques [N m] on the free joints, shape (k,).

        Args:
            model: The reduced model of the free joints.
            data: Its data.
            t: Time [s].
            q_f: Free joint positions [rad].
            v_f: Free joint rates [rad/s].
        """

    def bind(self, free: np.ndarray) -> DriveLaw:
        """The law bound to one phase's free joints (indices in the full model).

        Bound once per phase, so that :meth:`torques`, called at every right-hand side,
        indexes nothing.
        """
        return self

    @property
    def acts(self) -> bool:
        """Whether the law can give a non-zero torque."""
        return True


@dataclass(frozen=True)
class DriveOff(DriveLaw):
    """Drives switched off: no torque."""

    def torques(
        self,
        model: pin.Model,
        data: pin.Data,
        t: float,
        q_f: np.ndarray,
        v_f: np.ndarray,
    ) -> np.ndarray:
        """Zero torques [N m]."""
        return np.zeros(q_f.size)

    @property
    def acts(self) -> bool:
        """False: no torque."""
        return False


@dataclass(frozen=True)
class DriveHold(DriveLaw):
    """Before the stop signal: hold the joint rates constant, tau = RNEA(q, v, 0)."""

    def torques(
        self,
        model: pin.Model,
        data: pin.Data,
        t: float,
        q_f: np.ndarray,
        v_f: np.ndarray,
    ) -> np.ndarray:
        """The inverse-dynamics torques of zero acceleration [N m]."""
        return np.asarray(pin.rnea(model, data, q_f, v_f, np.zeros(q_f.size)))


@dataclass(frozen=True, eq=False)
class DriveRamp(DriveLaw):
    """Category-1 stop: ramp the rates to zero, computed torque clipped at the torque limit.

    Attributes:
        stop: The category-1 stop (ramp time, torque limit, feedback gain).
        v_signal: Joint rates at the stop signal [rad/s], shape (n,); after :meth:`bind`,
            those of the free joints.
        limit: Torque limits of the free joints [N m], set by :meth:`bind`.
    """

    stop: Stop
    v_signal: np.ndarray
    limit: np.ndarray | None = None

    def bind(self, free: np.ndarray) -> DriveRamp:
        """The ramp for the free joints ``free``."""
        assert self.stop.torque_limit is not None
        limit = np.asarray(self.stop.torque_limit, dtype=float)[free]
        return DriveRamp(self.stop, np.asarray(self.v_signal)[free], limit)

    def torques(
        self,
        model: pin.Model,
        data: pin.Data,
        t: float,
        q_f: np.ndarray,
        v_f: np.ndarray,
    ) -> np.ndarray:
        """RNEA of a_ref + gain (v_ref - v), v_ref falling linearly to 0, clipped [N m]."""
        stop = self.stop
        assert stop.ramp_time is not None and self.limit is not None
        s = (t - stop.t) / stop.ramp_time
        v_ref = self.v_signal * max(0.0, 1.0 - s)
        a_ref = -self.v_signal / stop.ramp_time if s < 1.0 else 0.0 * v_f
        tau = pin.rnea(model, data, q_f, v_f, a_ref + stop.gain * (v_ref - v_f))
        return np.asarray(np.clip(tau, -self.limit, self.limit))
