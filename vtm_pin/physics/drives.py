"""Drive laws: the joint torques of the drives on the free joints during one phase.

A law is one small class with :meth:`DriveLaw.torques`. Four are built in: drives off, drives
holding the joint rates constant (before a stop signal: tau = RNEA(q, v, 0)), the category-1
and -2 ramp (a computed-torque law taking the rates from their value at the signal linearly to
zero over ``ramp_time``, with velocity feedback, clipped at ``torque_limit``; once the ramp has
ended the same law holds the rates at zero, which is category 2's hold), and the motors'
short-circuit (dynamic) braking once a drive has dropped out (:class:`ShortCircuit`). Which
joints' drives act is decided by the stop's timeline (a drive goes off when its brake engages,
and every drive at a category-0 signal; in category 2 none goes off), not by the law.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..exceptions import BrakeError
from .robot import Robot
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
    """Category-1 or -2 stop: ramp the rates to zero, computed torque clipped at the limit.

    After the ramp (t >= t_signal + ramp_time) the reference is v_ref = 0, a_ref = 0: tau =
    RNEA(q, v, -gain v), clipped, a rate hold that compensates gravity. It holds the arm at rest
    wherever the gravity torques are within the limit; it does not pull the joints back to
    where the ramp ended (no position term), so a joint whose limit is exceeded sags.

    Attributes:
        stop: The category-1 or -2 stop (ramp time, torque limit, feedback gain).
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


def short_circuit_torque(
    ratio: np.ndarray, peak_torque: np.ndarray, peak_speed: np.ndarray, v: np.ndarray
) -> np.ndarray:
    """Joint-side short-circuit braking torques -N T(N v) [N m] (see :class:`ShortCircuit`).

    Args:
        ratio: Gear ratios N [-].
        peak_torque: T_pk, motor side [N m] (0: none).
        peak_speed: omega_pk, motor side [rad/s], > 0.
        v: Joint rates [rad/s]; the arrays broadcast.
    """
    x = ratio * v / peak_speed
    return np.asarray(-ratio * peak_torque * (2.0 * x / (1.0 + x * x)))


@dataclass(frozen=True, eq=False)
class ShortCircuit:
    r"""Motor short-circuit (dynamic) braking: the windings shorted once the drive drops out.

    A permanent-magnet synchronous motor whose terminals are shorted brakes with the torque of
    its own back-EMF driving current through the winding resistance. Its steady-state
    equivalent circuit (back-EMF constant psi, resistance R, inductance L, p pole pairs; the
    torque-speed curve drive vendors publish for "armature short-circuit" or "dynamic"
    braking) gives, motor side,

    .. math:: T(\omega) = T_{pk} \frac{2\, \omega / \omega_{pk}}{1 + (\omega / \omega_{pk})^2},
              \qquad \omega_{pk} = \frac{R}{p L},\quad T_{pk} = \frac{3 p \psi^2}{4 L},

    proportional to the speed at low speed, largest (T_pk) at the characteristic speed
    omega_pk, falling as 1/omega above it. It always opposes the motion, and its power T omega
    is dissipated in the winding resistance: the law only ever removes energy. On the joint
    side, through the gear ratio N: tau = -N T(N v). It acts from the moment the joint's drive
    drops out (the category-0 signal; in category 1, when its brake engages) until the joint
    is at rest, and is zero at rest, so it needs no events.

    Attributes:
        peak_torque: T_pk per joint, motor side [N m], >= 0 (0: no short-circuit braking).
        peak_speed: omega_pk per joint, motor side [rad/s], > 0.
        ratio: Gear ratio per joint [-].

    Raises:
        BrakeError: A figure out of range, or arrays of different lengths.
    """

    peak_torque: np.ndarray
    peak_speed: np.ndarray
    ratio: np.ndarray

    def __post_init__(self) -> None:
        arrays = [
            np.array(getattr(self, k), dtype=float) for k in ("peak_torque", "peak_speed", "ratio")
        ]
        if len({a.shape for a in arrays}) != 1 or arrays[0].ndim != 1:
            raise BrakeError("short-circuit braking needs one figure of each kind per joint")
        torque, speed, ratio = arrays
        if not (np.all(np.isfinite(torque)) and np.all(torque >= 0.0)):
            raise BrakeError("short-circuit peak torques must be finite numbers >= 0 N m")
        if not (np.all(np.isfinite(speed)) and np.all(speed > 0.0)):
            raise BrakeError("short-circuit peak speeds must be finite numbers > 0 rad/s")
        if not (np.all(np.isfinite(ratio)) and np.all(ratio > 0.0)):
            raise BrakeError("gear ratios must be finite numbers > 0")
        for name, array in zip(("peak_torque", "peak_speed", "ratio"), arrays, strict=True):
            array.flags.writeable = False
            object.__setattr__(self, name, array)

    @property
    def present(self) -> np.ndarray:
        """Per joint, whether its motor brakes when shorted (peak torque > 0)."""
        return np.asarray(self.peak_torque > 0.0)

    def bind(self, free: np.ndarray) -> ShortCircuit:
        """The law for the free joints ``free``."""
        return ShortCircuit(self.peak_torque[free], self.peak_speed[free], self.ratio[free])

    def joint_torque(self, v: np.ndarray) -> np.ndarray:
        """Joint-side torques -N T(N v) [N m] at joint rates ``v`` [rad/s] (any shape (..., k))."""
        return short_circuit_torque(self.ratio, self.peak_torque, self.peak_speed, v)

    def describe(self, joints: tuple[str, ...]) -> dict[str, dict[str, float]]:
        """Figures of the joints whose motors brake, for summary.json (motor side, SI)."""
        return {
            name: {
                "peak_torque": float(self.peak_torque[i]),
                "peak_speed": float(self.peak_speed[i]),
            }
            for i, name in enumerate(joints)
            if self.peak_torque[i] > 0.0
        }


def short_circuit(robot: Robot) -> ShortCircuit | None:
    """The short-circuit braking of the robot's motors (its drives' figures); None if none."""
    n = robot.nv
    torque, speed = np.zeros(n), np.ones(n)
    for joint, drive in robot.drives.items():
        if drive.short_circuit_torque > 0.0:
            i = robot.joint_index(joint)
            torque[i], speed[i] = drive.short_circuit_torque, drive.short_circuit_speed
    if not torque.any():
        return None
    return ShortCircuit(torque, speed, np.asarray(robot.gear_ratio, dtype=float))
