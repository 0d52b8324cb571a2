"""Brake friction laws, motor side: the kinetic torque while sliding and the breakaway torque.

A law is one small class: :meth:`FrictionLaw.kinetic` (sliding torque at full normal force as a
function of the motor speed) and :attr:`FrictionLaw.breakaway_torque` (the static limit). The
base class applies the normal-force ramp after engagement to both. Three laws are built in:

* :class:`Coulomb`: constant kinetic torque, static torque >= kinetic;
* :class:`Stribeck`: the kinetic torque falls from the static torque at rest to the Coulomb
  torque at speed, tau(w) = tau_c + (tau_s - tau_c) exp(-(w / w_s)^2); it equals Coulomb at
  large speeds and tends to it as the Stribeck speed w_s goes to 0;
* :class:`Viscous`: the kinetic torque grows with the slip speed, tau(w) = tau_c (1 + w / w_v),
  so that a stop decelerates hardest at its start.

Every law's kinetic torque is >= 0 and opposes the slip, so a brake only ever removes energy.

An ideal brake is not a law with infinite torque but :class:`IdealLock`: the joint locks at
engagement with the paper's momentum-consistent jump. Torques are motor side [N m]; the robot's
gear ratio (stored once, in :class:`~vtm_pin.physics.robot.Robot`) turns them into joint torques.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

from ..exceptions import BrakeError


@dataclass(frozen=True)
class FrictionLaw(ABC):
    """Friction of a brake, motor side, with a linear normal-force ramp after engagement.

    Attributes:
        ramp: Time for the normal force to rise linearly to its full value [s], >= 0
            (keyword only).
    """

    ramp: float = field(default=0.0, kw_only=True)

    def __post_init__(self) -> None:
        if not (self.ramp >= 0.0) or not math.isfinite(self.ramp):
            raise BrakeError(f"ramp {self.ramp} s is not a finite number >= 0")

    @property
    @abstractmethod
    def name(self) -> str:
        """Name of the law in scenario files and reports."""

    @abstractmethod
    def kinetic(self, speed: float) -> float:
        """Kinetic torque at full normal force [N m], at motor slip speed ``speed`` [rad/s].

        ``speed`` is >= 0 while the brake slides; just past the instant the joint reaches rest
        an integrator's trial states give it slightly below 0, where a law must stay >= 0
        (dissipative) and continue as smoothly as it can, so that the step's error estimate is
        not misled.
        """

    @property
    @abstractmethod
    def breakaway_torque(self) -> float:
        """Static (breakaway) torque at full normal force [N m]; >= the kinetic torque at rest."""

    @property
    def least_kinetic(self) -> float:
        """The smallest kinetic torque at full normal force over all slip speeds [N m].

        It is what is left to stop a slowly moving joint.
        """
        return self.kinetic(0.0)

    def factor(self, elapsed: float) -> float:
        """Normal-force factor in [0, 1], ``elapsed`` seconds after engagement."""
        if self.ramp == 0.0:
            return 1.0
        return min(1.0, max(0.0, elapsed / self.ramp))

    def sliding(self, elapsed: float, speed: float) -> float:
        """Kinetic torque [N m] ``elapsed`` s after engagement at motor speed [rad/s]."""
        return self.factor(elapsed) * self.kinetic(speed)

    def breakaway(self, elapsed: float) -> float:
        """Static torque limit [N m] ``elapsed`` s after engagement."""
        return self.factor(elapsed) * self.breakaway_torque

    def describe(self) -> dict[str, Any]:
        """The law and its figures, for summary.json (SI units, motor side)."""
        return {"law": self.name, "ramp": self.ramp}


@dataclass(frozen=True)
class Coulomb(FrictionLaw):
    """Constant kinetic torque, and a static torque at least as large.

    Attributes:
        sliding_torque: Kinetic torque [N m], > 0 and finite.
        static_torque: Static holding torque [N m], >= the kinetic torque; defaults to it.

    Raises:
        BrakeError: A torque out of range.
    """

    sliding_torque: float
    static_torque: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_torques(self.sliding_torque, self.static_torque)

    @property
    def name(self) -> str:
        """``coulomb``."""
        return "coulomb"

    def kinetic(self, speed: float) -> float:
        """The constant kinetic torque [N m]."""
        return self.sliding_torque

    @property
    def breakaway_torque(self) -> float:
        """The static torque [N m]."""
        return self.sliding_torque if self.static_torque is None else self.static_torque

    @property
    def least_kinetic(self) -> float:
        """tau_c: Coulomb's at every speed, Stribeck's far from rest, the viscous law's at rest."""
        return self.sliding_torque

    def describe(self) -> dict[str, Any]:
        """The law and its figures, for summary.json (SI units, motor side)."""
        return {
            **super().describe(),
            "sliding_torque": self.sliding_torque,
            "static_torque": self.breakaway_torque,
        }


@dataclass(frozen=True)
class Stribeck(Coulomb):
    """Coulomb friction with a Stribeck drop from the static to the kinetic torque.

    tau(w) = tau_c + (tau_s - tau_c) exp(-(w / w_s)^2) with tau_c the sliding torque, tau_s
    the static torque and w_s the Stribeck speed (motor side).

    Attributes:
        stribeck_velocity: Motor speed of the drop, w_s [rad/s], > 0.

    Raises:
        BrakeError: A figure out of range.
    """

    stribeck_velocity: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        w = self.stribeck_velocity
        if not (w > 0.0) or not math.isfinite(w):
            raise BrakeError(f"Stribeck velocity {w} rad/s is not a finite number > 0")

    @property
    def name(self) -> str:
        """``stribeck``."""
        return "stribeck"

    def kinetic(self, speed: float) -> float:
        """tau_c + (tau_s - tau_c) exp(-(w / w_s)^2) [N m]; past rest (w < 0) tau_s.

        The continuation past rest holds the law's value at rest, with its slope there (0),
        rather than mirroring the drop: a step that jumps from far above w_s to past rest
        then sees the peak at its stages past rest, and its error estimate rejects it until
        the drop is resolved. The mirrored drop is tau_c on both sides of a narrow peak that
        no stage need sample: such a step was accepted at every rtol, and its continuous
        extension, whose extra stages do fall on the peak, located the rest with a work
        that missed ~1e-5 of the energy (tests/test_properties.py,
        EXAMPLE_NARROW_STRIBECK_PEAK).
        """
        if speed < 0.0:
            return self.breakaway_torque
        x = speed / self.stribeck_velocity
        if not abs(x) < 30.0:  # exp(-900) is below every float: Coulomb (and no overflow)
            return self.sliding_torque
        drop = self.breakaway_torque - self.sliding_torque
        return self.sliding_torque + drop * math.exp(-(x**2))

    def describe(self) -> dict[str, Any]:
        """The law and its figures, for summary.json (SI units, motor side)."""
        return {**super().describe(), "stribeck_velocity": self.stribeck_velocity}


@dataclass(frozen=True)
class Viscous(Coulomb):
    """Coulomb friction whose kinetic torque grows with the slip speed.

    tau(w) = tau_c (1 + w / w_v) with tau_c the sliding torque and w_v the viscous speed (motor
    side): the friction coefficient of the brake's friction pair rising linearly with the slip
    speed, as a lubricated or wet pair's does (Coulomb plus viscous friction, the viscous part
    in proportion to the normal force, hence to tau_c: brakes of one type share w_v). Its
    deceleration is hardest at the start of a stop, when the speed is highest; at rest it is
    the Coulomb torque, and the static torque still bounds what a stuck brake holds.

    Attributes:
        viscous_velocity: Motor speed at which the kinetic torque is twice tau_c, w_v [rad/s],
            > 0.

    Raises:
        BrakeError: A figure out of range.
    """

    viscous_velocity: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        w = self.viscous_velocity
        if not (w > 0.0) or not math.isfinite(w):
            raise BrakeError(f"viscous velocity {w} rad/s is not a finite number > 0")

    @property
    def name(self) -> str:
        """``viscous``."""
        return "viscous"

    def kinetic(self, speed: float) -> float:
        """tau_c (1 + w / w_v) [N m]; past rest (w < 0) tau_c, Coulomb's.

        The continuation past rest stays tau_c rather than the line's (which would fall below
        tau_c and, for a stiff brake, reverse): it keeps a trial step past the instant of
        rest dissipative, at the price of a kink in the torque's slope there.
        """
        return self.sliding_torque * (1.0 + max(speed, 0.0) / self.viscous_velocity)

    def describe(self) -> dict[str, Any]:
        """The law and its figures, for summary.json (SI units, motor side)."""
        return {**super().describe(), "viscous_velocity": self.viscous_velocity}


@dataclass(frozen=True)
class IdealLock(FrictionLaw):
    """An ideal brake: the joint locks at engagement (momentum-consistent jump), never slips."""

    @property
    def name(self) -> str:
        """``ideal``."""
        return "ideal"

    def kinetic(self, speed: float) -> float:
        """Not used: an ideal lock never slides (infinite torque) [N m]."""
        return math.inf

    @property
    def breakaway_torque(self) -> float:
        """Infinite: an ideal lock never slips [N m]."""
        return math.inf


def _check_torques(sliding: float, static: float | None) -> None:
    """Raise unless 0 < sliding <= static, all finite."""
    if not (sliding > 0.0) or not math.isfinite(sliding):
        raise BrakeError(f"sliding torque {sliding} N m is not a finite number > 0")
    if static is not None and (not (static >= sliding) or not math.isfinite(static)):
        raise BrakeError(
            f"static torque {static} N m is not a finite number >= the sliding torque {sliding} N m"
        )
