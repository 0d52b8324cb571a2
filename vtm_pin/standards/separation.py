"""The whole stopping chain and the separation distances the standards build from it.

vtm_pin simulates the robot's own stop, from the moment the stop signal reaches it until every
joint is at rest: **T_robot**. What a safeguard needs is longer. ISO 13855:2024's **T** is the
overall system stopping performance: the protective device's detection time, the safety
controller's response time, the signal's latency to the robot, and the robot's stop:

    T = t_detection + t_response + t_latency + T_robot

and the minimum distance of a protective device from the hazard is

    S = K T + D_DS + Z                                                   (ISO 13855:2024)

with K the approach speed of the body part [m/s], D_DS the intrusion distance of the
detection zone [m] and Z a supplemental distance [m]; none is defaulted. Speed and separation
monitoring (ISO/TS 15066, now in ISO 10218-2:2025) needs the protective separation distance

    S_p = S_h + S_r + S_s + C + Z_d + Z_r,
    S_h = v_h (T_r + T_s),  S_r = v_r T_r                                (ISO/TS 15066)

with T_r = t_detection + t_response + t_latency the robot system's reaction time, T_s =
T_robot its stopping time, v_h the human's speed (1.6 m/s unless the user gives another), v_r
the robot's speed toward the human during T_r (taken as the largest speed of any sampled point of
the arm at the signal, ``arm_speed_at_signal``: the drives hold the joint rates until then), S_s the
distance the robot travels while it stops (the largest displacement of any sampled point of the arm,
tool included, from where it was at the signal: ``arm_max_displacement``), C the
intrusion distance, Z_d and Z_r the position uncertainties of the human and the robot [m].
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: ISO/TS 15066's human walking speed when the user gives none [m/s].
DEFAULT_HUMAN_SPEED = 1.6


@dataclass(frozen=True)
class Safeguard:
    """The stopping chain before the robot's own stop [s].

    Attributes:
        detection_time: The protective device's detection (response) time.
        response_time: The safety controller's response time.
        latency: The signal's latency from the controller to the robot's drives and brakes.
    """

    detection_time: float
    response_time: float
    latency: float

    @property
    def reaction_time(self) -> float:
        """T_r: from detection to the stop signal reaching the robot [s]."""
        return self.detection_time + self.response_time + self.latency

    def overall(self, robot_time: float) -> float:
        """ISO 13855's T: the reaction time plus the robot's own stopping time [s]."""
        return self.reaction_time + robot_time


@dataclass(frozen=True)
class Iso13855:
    """ISO 13855:2024's inputs: S = K T + D_DS + Z.

    Attributes:
        approach_speed: K, the approach speed of the body part [m/s].
        intrusion_distance: D_DS, the intrusion distance of the detection zone [m].
        supplement: Z, a supplemental distance [m].
    """

    approach_speed: float
    intrusion_distance: float
    supplement: float

    def distance(self, overall_time: float) -> float:
        """S [m] for the overall stopping performance T [s]."""
        return self.approach_speed * overall_time + self.intrusion_distance + self.supplement


@dataclass(frozen=True)
class Ssm:
    """ISO/TS 15066 speed and separation monitoring: S_p = S_h + S_r + S_s + C + Z_d + Z_r.

    Attributes:
        intrusion_distance: C [m].
        human_uncertainty: Z_d, the position uncertainty of the human's sensing [m].
        robot_uncertainty: Z_r, the position uncertainty of the robot [m].
        human_speed: v_h [m/s].
    """

    intrusion_distance: float
    human_uncertainty: float
    robot_uncertainty: float
    human_speed: float = DEFAULT_HUMAN_SPEED

    def terms(
        self, reaction_time: float, stop_time: float, robot_speed: float, stop_distance: float
    ) -> dict[str, float]:
        """S_h, S_r, S_s, C, Z_d, Z_r and their sum S_p [m].

        Args:
            reaction_time: T_r [s].
            stop_time: T_s, the robot's stopping time [s].
            robot_speed: v_r during T_r [m/s].
            stop_distance: S_s [m].
        """
        terms = {
            "S_h": self.human_speed * (reaction_time + stop_time),
            "S_r": robot_speed * reaction_time,
            "S_s": stop_distance,
            "C": self.intrusion_distance,
            "Z_d": self.human_uncertainty,
            "Z_r": self.robot_uncertainty,
        }
        return {**terms, "S_p": math.fsum(terms.values())}


@dataclass(frozen=True)
class Separation:
    """What a scenario asks for beyond the robot's stop; each part None when not given.

    Attributes:
        safeguard: The stopping chain before the robot (needed for T, S and S_p).
        iso13855: ISO 13855:2024's K, D_DS, Z.
        ssm: ISO/TS 15066's C, Z_d, Z_r and v_h.
    """

    safeguard: Safeguard | None = None
    iso13855: Iso13855 | None = None
    ssm: Ssm | None = None

    def figures(
        self, robot_time: float, robot_speed: float, stop_distance: float
    ) -> dict[str, float | None]:
        """T_robot, T, S and S_p (None where an input is missing or the robot still moves).

        Args:
            robot_time: T_robot [s] (NaN if some joint still moves).
            robot_speed: v_r, the fastest arm point's speed at the signal [m/s].
            stop_distance: S_s [m].
        """
        out: dict[str, float | None] = {"T_robot": _finite(robot_time)}
        guard = self.safeguard
        overall = guard.overall(robot_time) if guard is not None else math.nan
        out["T"] = _finite(overall)
        out["S"] = _finite(self.iso13855.distance(overall)) if self.iso13855 else None
        if self.ssm is not None and guard is not None:
            terms = self.ssm.terms(guard.reaction_time, robot_time, robot_speed, stop_distance)
            out["S_p"] = _finite(terms["S_p"])
        else:
            out["S_p"] = None
        return out

    def describe(
        self, robot_time: float, robot_speed: float, stop_distance: float
    ) -> dict[str, Any]:
        """The chain, each formula with its inputs and result (SI units), for summary.json."""
        guard = self.safeguard
        out: dict[str, Any] = {
            "T_robot": _finite(robot_time),
            "definition": "T_robot: from the stop signal reaching the robot until every joint's "
            "speed stays below stop.rest_speed (the robot's own stopping time, NOT ISO 13855's T). "
            "T = t_detection + t_response + t_latency + T_robot (ISO 13855:2024).",
            "safeguard": None if guard is None else vars(guard),
            "T": _finite(guard.overall(robot_time)) if guard is not None else None,
        }
        if self.iso13855 is not None:
            out["iso13855"] = {
                "formula": "S = K T + D_DS + Z",
                **vars(self.iso13855),
                "S": self.figures(robot_time, robot_speed, stop_distance)["S"],
            }
        if self.ssm is not None:
            terms = (
                self.ssm.terms(guard.reaction_time, robot_time, robot_speed, stop_distance)
                if guard is not None
                else None
            )
            out["iso_ts_15066"] = {
                "formula": "S_p = S_h + S_r + S_s + C + Z_d + Z_r; S_h = v_h (T_r + T_s), "
                "S_r = v_r T_r",
                **vars(self.ssm),
                "T_r": None if guard is None else guard.reaction_time,
                "T_s": _finite(robot_time),
                "v_r": robot_speed,
                "terms": None if terms is None else {k: _finite(v) for k, v in terms.items()},
            }
        return out


def parse_separation(raw: Mapping[str, Any]) -> Separation:
    """The :class:`Separation` of a scenario's ``safeguard`` and ``separation`` keys.

    The keys are schema checked: every number given is finite and >= 0.
    """
    guard = raw.get("safeguard")
    spec = raw.get("separation", {})
    iso = spec.get("iso13855")
    ssm = spec.get("iso_ts_15066")
    return Separation(
        safeguard=None
        if guard is None
        else Safeguard(
            float(guard["detection_time"]), float(guard["response_time"]), float(guard["latency"])
        ),
        iso13855=None
        if iso is None
        else Iso13855(
            float(iso["approach_speed"]), float(iso["intrusion_distance"]), float(iso["supplement"])
        ),
        ssm=None
        if ssm is None
        else Ssm(
            float(ssm["intrusion_distance"]),
            float(ssm["human_uncertainty"]),
            float(ssm["robot_uncertainty"]),
            float(ssm.get("human_speed", DEFAULT_HUMAN_SPEED)),
        ),
    )


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
