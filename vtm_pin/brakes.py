"""Joint brakes: the Modelica ``Rotational.Components.Brake`` state machine, per joint.

A brake is ``free`` until it engages (stop signal + delay). It then ``slides`` (``forward`` for
v > 0, ``backward`` for v < 0) with the kinetic torque -tau_slide sign(v), which only ever
opposes the motion. A braked joint at rest, whether it engaged at rest, slid to rest or is
stuck, goes through one decision (Modelica's start-forward / start-backward conditions): it
is ``stuck`` (a joint lock) while the torque needed to hold it is within the static torque,
else it starts sliding in the direction the load drives it (:func:`mode_of_load`). A stuck
joint whose holding torque exceeds the static torque ``slips`` back to sliding. The normal
force, and with it both torques, may rise linearly over ``ramp`` seconds after engagement. A
brake with infinite torque is ideal: it locks its joint at engagement with the paper's
momentum-consistent jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from .exceptions import BrakeError

#: Rate below which a braked joint counts as at rest [rad/s, m/s for prismatic joints]: well
#: above the integrator's round-off and event-location residuals (<= 1e-12 rad/s measured),
#: far below any rate that moves a joint measurably (1e-9 rad in a second).
REST_RATE = 1e-9


class BrakeMode(IntEnum):
    """State of a joint's brake (codes stored per sample in simulation results)."""

    FREE = 0
    FORWARD = 1
    BACKWARD = 2
    STUCK = 3
    LOCKED = 4  # ideal lock: a prescribed lock or an ideal brake

    @property
    def sliding(self) -> bool:
        """Whether the brake is sliding (kinetic friction acts)."""
        return self in (BrakeMode.FORWARD, BrakeMode.BACKWARD)

    @property
    def sign(self) -> float:
        """+1 when sliding forward, -1 backward, 0 otherwise."""
        return {BrakeMode.FORWARD: 1.0, BrakeMode.BACKWARD: -1.0}.get(self, 0.0)


@dataclass(frozen=True)
class Brake:
    """One joint's brake; torques are given on the motor side and multiplied by the gear ratio.

    Attributes:
        joint: Joint name.
        delay: Engagement delay after the brake signal [s], >= 0.
        ramp: Time for the normal force to rise linearly to its full value [s], >= 0.
        sliding_torque: Kinetic (sliding) torque, motor side [N m], > 0; ``inf`` = ideal.
        static_torque: Static holding torque, motor side [N m], >= sliding torque; defaults to
            the sliding torque.
        gear_ratio: Motor angle per joint angle [-]; joint-side torque = ratio x motor torque.

    Raises:
        BrakeError: A figure is out of range (one line naming the joint and the value).
    """

    joint: str
    delay: float = 0.0
    ramp: float = 0.0
    sliding_torque: float = math.inf
    static_torque: float | None = None
    gear_ratio: float = 1.0

    def __post_init__(self) -> None:
        name = f"Brake on '{self.joint}'"
        if not (self.sliding_torque > 0.0):
            raise BrakeError(f"{name}: sliding torque {self.sliding_torque} N m is not > 0")
        if self.static_torque is not None and not (self.static_torque >= self.sliding_torque):
            raise BrakeError(
                f"{name}: static torque {self.static_torque} N m is below the sliding torque "
                f"{self.sliding_torque} N m"
            )
        if not (self.delay >= 0.0) or not math.isfinite(self.delay):
            raise BrakeError(f"{name}: delay {self.delay} s is not a finite number >= 0")
        if not (self.ramp >= 0.0) or not math.isfinite(self.ramp):
            raise BrakeError(f"{name}: ramp {self.ramp} s is not a finite number >= 0")
        if not (self.gear_ratio > 0.0):
            raise BrakeError(f"{name}: gear ratio {self.gear_ratio} is not > 0")

    @property
    def ideal(self) -> bool:
        """Infinite torque: the joint locks at engagement."""
        return math.isinf(self.sliding_torque)

    def factor(self, elapsed: float) -> float:
        """Normal-force factor in [0, 1], ``elapsed`` seconds after engagement."""
        if self.ramp == 0.0:
            return 1.0
        return min(1.0, max(0.0, elapsed / self.ramp))

    def sliding(self, elapsed: float) -> float:
        """Joint-side kinetic torque magnitude [N m] ``elapsed`` s after engagement."""
        return self.gear_ratio * self.sliding_torque * self.factor(elapsed)

    def static(self, elapsed: float) -> float:
        """Joint-side static (holding) torque limit [N m] ``elapsed`` s after engagement."""
        limit = self.sliding_torque if self.static_torque is None else self.static_torque
        return self.gear_ratio * limit * self.factor(elapsed)


def mode_of_motion(v: float) -> BrakeMode | None:
    """The sliding mode of a braked joint moving at rate ``v``; None if it is at rest.

    Args:
        v: The joint's rate [rad/s]; |v| <= :data:`REST_RATE` counts as rest.
    """
    if v > REST_RATE:
        return BrakeMode.FORWARD
    if v < -REST_RATE:
        return BrakeMode.BACKWARD
    return None


def mode_of_load(hold: float) -> BrakeMode:
    """The direction a joint at rest starts sliding in when released: that of its load.

    Args:
        hold: Torque needed to hold the joint at rest [N m]; the load acts against it.
    """
    return BrakeMode.BACKWARD if hold > 0.0 else BrakeMode.FORWARD
