"""One smooth piece of a hybrid motion: topology, torques on the free joints, ending events.

The integrated state is y = (q_f, v_f, W_brake, W_drive, P_brake): free positions [rad] and
rates [rad/s], the work dissipated by sliding brakes and the work done by the drives [J], and
the angular impulse each brake's friction has delivered to its joint [N m s] (n entries).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
import pinocchio as pin

from .brakes import Brake, BrakeMode
from .dynamics import compute_M
from .holonomic import FrameConstraint, compute_kinematics, stack
from .integrators import StateEvent
from .robot import Robot
from .stop import Stop
from .topology import Topology


class DriveLaw(Enum):
    """What the joint drives do during a phase."""

    OFF = "off"
    HOLD = "hold"  # before the stop signal: hold the joint rates constant
    RAMP = "ramp"  # category-1 stop: ramp the rates to zero, torque-limited


@dataclass(frozen=True)
class PhaseEvent:
    """A state event of a phase and what it means.

    Attributes:
        kind: ``"zero_velocity"`` (a sliding joint reaches v = 0) or ``"slip"`` (a stuck
            joint's holding torque reaches its static limit).
        joint: Index of the joint concerned.
        event: The event function for the integrator.
    """

    kind: str
    joint: int
    event: StateEvent


class Phase:
    """Dynamics between two events.

    Args:
        robot: The robot.
        topology: Locked joints and the reduced model of the free ones.
        modes: Brake mode per joint.
        brakes: Brake per joint index (joints without a brake are absent).
        engaged: Engagement time per braked joint index [s].
        drive: Drive law.
        drive_on: Per joint, whether its drive acts.
        stop: The stop (for the category-1 ramp); None without a stop.
        v_signal: Joint rates at the stop signal (category-1 ramp reference) [rad/s].
    """

    def __init__(
        self,
        robot: Robot,
        topology: Topology,
        modes: Sequence[BrakeMode],
        brakes: Mapping[int, Brake],
        engaged: Mapping[int, float],
        drive: DriveLaw = DriveLaw.OFF,
        drive_on: np.ndarray | None = None,
        stop: Stop | None = None,
        v_signal: np.ndarray | None = None,
        constraints: tuple[FrameConstraint, ...] = (),
        baumgarte: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.robot = robot
        self.topology = topology
        self.modes = tuple(modes)
        self.brakes = dict(brakes)
        self.engaged = dict(engaged)
        n = robot.nv
        free = topology.free
        self.k = topology.n_free
        self.drive = drive
        on = np.zeros(n, dtype=bool) if drive_on is None else np.asarray(drive_on, dtype=bool)
        self._drive_f = on[free] if drive is not DriveLaw.OFF else np.zeros(self.k, dtype=bool)
        self._sliding = [
            (f, int(j), self.brakes[int(j)])
            for f, j in enumerate(free)
            if self.modes[int(j)].sliding
        ]
        self._signs = {int(j): self.modes[int(j)].sign for _, j, _ in self._sliding}
        self.stop = stop
        if drive is DriveLaw.RAMP:
            assert stop is not None and v_signal is not None and stop.torque_limit is not None
            assert stop.ramp_time is not None
            self._v_signal_f = np.asarray(v_signal)[free]
            self._limit_f = np.asarray(stop.torque_limit, dtype=float)[free]
        self._full_data = robot.model.createData()
        self.events = self._build_events()
        #: No torque acts: y is (q_f, v_f) only and the accumulators stay constant.
        self.constraints = tuple(constraints)
        self.baumgarte = baumgarte
        self.passive = not self._drive_f.any() and not self._sliding and not self.constraints
        self.rhs = self.topology.rhs if self.passive else self._rhs

    def pack(self, q: np.ndarray, v: np.ndarray, extras: np.ndarray) -> np.ndarray:
        """Y from full (q, v) and the work/impulse accumulators (omitted when passive)."""
        y = self.topology.split(q, v)
        return y if self.passive else np.concatenate([y, extras])

    def unpack_extras(self, y: np.ndarray, extras: np.ndarray) -> np.ndarray:
        """Accumulators at the states ``y`` (rows), given their value at the phase start."""
        if self.passive:
            return np.broadcast_to(extras, (*y.shape[:-1], extras.size))
        return y[..., 2 * self.k :]

    def torques(self, t: float, q_f: np.ndarray, v_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Drive and brake torques on the free joints [N m]."""
        k = self.k
        tau_drive = np.zeros(k)
        if self._drive_f.any():
            model, data = self.topology.model, self.topology.data
            if self.drive is DriveLaw.HOLD:
                tau = pin.rnea(model, data, q_f, v_f, np.zeros(k))
                tau_drive = np.where(self._drive_f, tau, 0.0)
            else:
                assert self.stop is not None and self.stop.ramp_time is not None
                s = (t - self.stop.t) / self.stop.ramp_time
                ramping = s < 1.0
                v_ref = self._v_signal_f * max(0.0, 1.0 - s)
                a_ref = -self._v_signal_f / self.stop.ramp_time if ramping else 0.0 * v_f
                a_des = a_ref + self.stop.gain * (v_ref - v_f)
                tau = pin.rnea(model, data, q_f, v_f, a_des)
                tau = np.clip(tau, -self._limit_f, self._limit_f)
                tau_drive = np.where(self._drive_f, tau, 0.0)
        tau_brake = np.zeros(k)
        for f, j, brake in self._sliding:
            tau_brake[f] = -self._signs[j] * brake.sliding(t - self.engaged[j])
        return tau_drive, tau_brake

    def _rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """dy/dt: (v_f, a_f, friction power, drive power, brake torques)."""
        k = self.k
        out = np.zeros_like(y)
        if k == 0:
            return out
        q_f, v_f = y[:k], y[k : 2 * k]
        tau_drive, tau_brake = self.torques(t, q_f, v_f)
        if self.constraints:
            a = self.constrained_acceleration(y, tau_drive + tau_brake)[0]
        else:
            a = pin.aba(self.topology.model, self.topology.data, q_f, v_f, tau_drive + tau_brake)
        out[:k] = v_f
        out[k : 2 * k] = a
        out[2 * k] = -float(tau_brake @ v_f)
        out[2 * k + 1] = float(tau_drive @ v_f)
        out[2 * k + 2 + self.topology.free] = tau_brake
        return out

    def constrained_acceleration(
        self, y: np.ndarray, tau_f: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        r"""Free accelerations and multipliers under the frame constraints (index-1 form).

        .. math:: \begin{pmatrix} M_{ff} & J_f^T \\ J_f & 0 \end{pmatrix}
                  \begin{pmatrix} a_f \\ \lambda \end{pmatrix} =
                  \begin{pmatrix} \tau_f - b_f \\ -\gamma - 2\alpha J_f v_f - \beta^2 h
                  \end{pmatrix}

        with Baumgarte gains (alpha, beta) [1/s] pulling drift back to the manifold.
        """
        k = self.k
        q, v = self.topology.merge(y[: 2 * k])
        model, data = self.robot.model, self._full_data
        M = compute_M(model, data, q)
        b = pin.nonLinearEffects(model, data, q, v)
        compute_kinematics(model, data, q, v)
        h, J, gamma = stack(self.constraints, model, data)
        free = self.topology.free
        Jf = J[:, free]
        alpha, beta = self.baumgarte
        m = Jf.shape[0]
        K = np.zeros((k + m, k + m))
        K[:k, :k] = M[np.ix_(free, free)]
        K[:k, k:] = Jf.T
        K[k:, :k] = Jf
        rhs = np.concatenate(
            [tau_f - b[free], -(gamma + 2.0 * alpha * (Jf @ y[k : 2 * k]) + beta**2 * h)]
        )
        x = np.linalg.solve(K, rhs)
        return x[:k], x[k:]

    def constraint_drift(self, y: np.ndarray) -> np.ndarray:
        """Max |h| [m, rad] and max |J v| [m/s, rad/s] of the frame constraints per row of y.

        NaN where the phase has no frame constraint.
        """
        out = np.full((len(y), 2), np.nan)
        if not self.constraints:
            return out
        model, data = self.robot.model, self._full_data
        for r, row in enumerate(y):
            q, v = self.topology.merge(row[: 2 * self.k])
            compute_kinematics(model, data, q, v)
            h, J, _ = stack(self.constraints, model, data)
            out[r] = np.max(np.abs(h)), np.max(np.abs(J @ v))
        return out

    def holding_torque(self, t: float, y: np.ndarray) -> np.ndarray:
        """Torque the locks must exert on every joint to keep the locked ones still [N m].

        This is the Lagrange multiplier of each lock (lambda = M a + b - tau at a locked
        joint, with a from the free dynamics); zero at free joints.
        """
        k = self.k
        q, v = self.topology.merge(y[: 2 * k])
        a = np.zeros(self.robot.nv)
        if k:
            tau_drive, tau_brake = self.torques(t, y[:k], y[k : 2 * k])
            a[self.topology.free] = pin.aba(
                self.topology.model,
                self.topology.data,
                y[:k],
                y[k : 2 * k],
                tau_drive + tau_brake,
            )
        tau = pin.rnea(self.robot.model, self._full_data, q, v, a)
        out = np.zeros(self.robot.nv)
        out[list(self.topology.locked)] = tau[list(self.topology.locked)]
        return out

    def _build_events(self) -> list[PhaseEvent]:
        events = []
        k = self.k
        for f, j, _ in self._sliding:
            # Sliding forward ends when v falls through 0; backward when it rises through 0.
            direction = -1 if self.modes[j] is BrakeMode.FORWARD else 1

            def rate(t: float, y: np.ndarray, i: int = k + f) -> float:
                return float(y[i])

            events.append(PhaseEvent("zero_velocity", j, StateEvent(rate, direction)))
        for j in self.topology.locked:
            brake = self.brakes.get(j)
            if self.modes[j] is BrakeMode.STUCK and brake is not None and not brake.ideal:

                def margin(t: float, y: np.ndarray, j: int = j, brake: Brake = brake) -> float:
                    hold = self.holding_torque(t, y)[j]
                    return brake.static(t - self.engaged[j]) - abs(hold)

                events.append(PhaseEvent("slip", j, StateEvent(margin, -1)))
        return events
