"""Finite brakes converge to the ideal (momentum-consistent) lock as their torque grows.

A brake with delay 0 engages on one joint at the stop signal and slides until the joint
sticks; the state a little later is compared with the run in which the same brake is ideal
(the paper's instantaneous lock). Prints the error per torque level and the observed order.
Brake torques are motor side; the robot's gear ratio (the only copy, in the robot) makes them
joint torques.

    python benchmarks/brake_convergence.py
"""

from __future__ import annotations

import numpy as np

import vtm_pin as vp
from vtm_pin.physics.brakes import Brake
from vtm_pin.physics.friction import Coulomb
from vtm_pin.physics.stop import Stop

CASES = {
    # name: (robot, joint, q0 [rad], v0 [rad/s] held until the signal, t_signal, t_compare [s])
    "planar_3r joint2": ("planar_3r", "joint2", [0.0, 1.2, 0.0], [1.0, -2.0, 1.5], 0.8, 1.0),
    "rx160l joint_2": (
        "rx160l",
        "joint_2",
        [0.0, 0.5, 1.2, 0.0, 0.5, 0.0],
        [1.5, -1.2, 1.8, 0.0, 0.0, 0.0],
        0.05,
        0.15,
    ),
}
LEVELS = [1e1, 1e2, 1e3, 1e4, 1e5, 1e6]  # sliding torque, motor side [N m]


def run(robot: vp.Robot, case: tuple, brake: Brake) -> vp.SimulationResult:
    _, _, q0, v0, t_signal, t_end = case
    problem = vp.Problem(
        robot, np.array(q0), np.array(v0), t_end, brakes=(brake,), stop=Stop(t_signal)
    )
    return vp.simulate(problem, vp.RK4(1e-5))


def main() -> None:
    for name, case in CASES.items():
        robot = vp.load_robot(case[0])
        joint = case[1]
        ideal = run(robot, case, Brake(joint))
        ratio = robot.gear_ratio[robot.joint_index(joint)]
        print(
            f"\n{name}: state at t = {case[5]} s vs the ideal lock at {case[4]} s "
            f"(gear ratio {ratio:g}, RK4 dt = 1e-5 s)"
        )
        print(
            f"{'sliding torque [N m] motor / joint':>36} {'stick after [s]':>16} "
            f"{'max |dv| [rad/s]':>17} {'max |dq| [rad]':>15} {'order':>6}"
        )
        previous = None
        for torque in LEVELS:
            result = run(robot, case, Brake(joint, friction=Coulomb(torque, 1e9)))
            stick = [e.t for e in result.brake_events if e.kind == "stick"]
            dv = np.max(np.abs(result.v[-1] - ideal.v[-1]))
            dq = np.max(np.abs(result.q[-1] - ideal.q[-1]))
            order = "" if previous is None else f"{np.log10(previous / max(dv, dq)):6.2f}"
            slide = f"{stick[0] - case[4]:.3e}" if stick else "no stick"
            print(
                f"{torque:>17.0e} / {torque * ratio:<16.0e} {slide:>16} {dv:17.3e} {dq:15.3e} "
                f"{order:>6}"
            )
            previous = max(dv, dq)


if __name__ == "__main__":
    main()
