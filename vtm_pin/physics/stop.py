"""Emergency-stop categories (IEC 60204-1): when drives switch off and brakes get the signal.

Category 0: the drives are switched off at the stop signal and every brake engages after its
own delay. Category 1: the drives first ramp each joint's rate linearly to zero over
``ramp_time`` with a computed-torque law clipped at ``torque_limit``; the brake signal follows
when the ramp ends or at ``time_limit``, whichever is first, and each drive switches off when
its brake engages. Category 2 (a controlled stop that leaves the drives powered, as ISO
10218-1:2025 lists among its stopping data): the same ramp, after which the drives hold the
joints at rest with the same law (zero rate reference, velocity feedback, gravity and Coriolis
torques computed, clipped at ``torque_limit``); no brake is ever signalled. Before the
signal the drives hold the joint rates constant (tau = RNEA(q, v, 0)), so a scenario's initial
velocity is the speed of the arm when the button is pressed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..exceptions import BrakeError

#: Velocity-feedback gain of the category-1 ramp [1/s].
DEFAULT_GAIN = 50.0
#: Speed below which a joint counts as stopped in the stopping report [rad/s, m/s for
#: prismatic joints]: 1e-3 rad/s moves a point 1 m from the axis by 1 mm/s.
DEFAULT_REST_SPEED = 1.0e-3


@dataclass(frozen=True)
class Stop:
    """An emergency stop.

    Attributes:
        t: Time the stop button is pressed [s].
        category: 0, 1 or 2.
        ramp_time: Categories 1 and 2: time to ramp the rates to zero [s].
        torque_limit: Categories 1 and 2: joint-side drive torque limit per joint [N m],
            shape (n,).
        time_limit: Category 1 only: latest brake signal after ``t`` [s]; defaults to
            ``ramp_time``.
        gain: Categories 1 and 2: velocity-feedback gain [1/s].
        rest_speed: A joint has stopped once its speed stays below this [rad/s], > 0; the
            stopping time runs from the signal until then.

    Raises:
        BrakeError: A category-1 or -2 stop without ramp time or torque limit, a category-2
            stop with a time limit, or a bad figure.
    """

    t: float = 0.0
    category: int = 0
    ramp_time: float | None = None
    torque_limit: np.ndarray | None = None
    time_limit: float | None = None
    gain: float = DEFAULT_GAIN
    rest_speed: float = DEFAULT_REST_SPEED

    def __post_init__(self) -> None:
        if self.category not in (0, 1, 2):
            raise BrakeError(f"Stop category {self.category} is not 0, 1 or 2")
        if not (self.t >= 0.0) or not math.isfinite(self.t):
            raise BrakeError(f"Stop time {self.t} s is not a finite number >= 0")
        if not (self.rest_speed > 0.0) or not math.isfinite(self.rest_speed):
            raise BrakeError(f"Rest speed {self.rest_speed} rad/s is not a finite number > 0")
        if self.category in (1, 2):
            c = self.category
            if self.ramp_time is None or not (self.ramp_time > 0.0):
                raise BrakeError(f"Category-{c} stop needs a ramp time > 0 s, got {self.ramp_time}")
            if self.torque_limit is None:
                raise BrakeError(f"Category-{c} stop needs a drive torque limit for every joint")
            if not np.all(np.asarray(self.torque_limit) > 0.0):
                raise BrakeError(f"Category-{c} drive torque limits must all be > 0 N m")
            if self.time_limit is not None and not (self.time_limit > 0.0):
                raise BrakeError(f"Category-1 time limit {self.time_limit} s is not > 0")
        if self.category == 2 and self.time_limit is not None:
            raise BrakeError(
                "a category-2 stop signals no brake: time_limit (the latest brake signal) "
                "belongs to category 1"
            )

    @property
    def brake_signal(self) -> float:
        """Time the brakes are told to engage [s]; +inf in category 2 (never)."""
        if self.category == 0:
            return self.t
        if self.category == 2:
            return math.inf
        assert self.ramp_time is not None
        limit = self.ramp_time if self.time_limit is None else self.time_limit
        return self.t + min(self.ramp_time, limit)
