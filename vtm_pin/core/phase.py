"""One smooth piece of a hybrid motion: topology, torques on the free joints, ending events.

The integrated state is y = (q_f, v_f, W_brake, W_drive, W_short, P_brake): free positions
[rad] and rates [rad/s], the work dissipated by sliding brakes, the work done by the drives and
the work dissipated by the motors' short-circuit braking [J], and the angular impulse each
brake's friction has delivered to its joint [N m s] (n entries).
"""

from __future__ import annotations

import functools
import weakref

import numpy as np
import pinocchio as pin

from ..numerics.dynamics import compute_M, solve_small
from ..numerics.integrators import Rhs
from ..numerics.transitions import solve_saddle_point
from ..physics.brakes import Brake, BrakeMachine, BrakeMode, BrakeStateEvent, EventSpec
from ..physics.drives import DriveLaw, DriveOff, ShortCircuit
from ..physics.robot import Robot
from .holonomic import FrameConstraint, compute_kinematics, stack
from .topology import Topology, full_data

#: The work accumulators after (q_f, v_f) in a phase state: brake friction, drives,
#: short-circuit braking [J]; the brakes' impulses follow them.
WORKS = 3


class Phase:
    """Dynamics between two events.

    Args:
        robot: The robot.
        topology: Locked joints and the reduced model of the free ones.
        brakes: The brake state machine, whose modes at this instant the phase keeps;
            None without brakes.
        drive: Drive law (:mod:`vtm_pin.physics.drives`); drives off by default.
        drive_on: Per joint, whether its drive acts.
        dynamic: The motors' short-circuit braking, if any motor brakes.
        dynamic_on: Per joint, whether its motor brakes (shorted: its drive has dropped out).
        constraints: Active frame constraints.
        baumgarte: Baumgarte gains (alpha, beta) [1/s] of the frame constraints.
        full: Holding torques and accelerations from the full model (CRBA and a dense solve
            of M_ff) instead of ABA on the reduced one, so that no reduced model is
            built: for an integrator that does not use :meth:`rhs` (the batched engine).
    """

    def __init__(
        self,
        robot: Robot,
        topology: Topology,
        brakes: BrakeMachine | None = None,
        drive: DriveLaw | None = None,
        drive_on: np.ndarray | None = None,
        constraints: tuple[FrameConstraint, ...] = (),
        baumgarte: tuple[float, float] = (0.0, 0.0),
        full: bool = False,
        dynamic: ShortCircuit | None = None,
        dynamic_on: np.ndarray | None = None,
    ) -> None:
        self.robot = robot
        self.full = full
        self.topology = topology
        self.machine = brakes
        self.modes = tuple(brakes.modes) if brakes else (BrakeMode.FREE,) * robot.nv
        self.engaged = dict(brakes.engaged) if brakes else {}
        n = topology.nv
        free = topology.free
        self.k = topology.n_free
        self.drive = (DriveOff() if drive is None else drive).bind(free)
        on = np.zeros(n, dtype=bool) if drive_on is None else np.asarray(drive_on, dtype=bool)
        self._drive_f = on[free] if self.drive.acts else np.zeros(self.k, dtype=bool)
        shorted = np.zeros(n, dtype=bool) if dynamic_on is None else np.asarray(dynamic_on)
        self._dynamic_f = shorted[free] & ~self._drive_f if dynamic is not None else shorted[:0]
        self.dynamic = dynamic.bind(free) if dynamic is not None and self._dynamic_f.any() else None
        self._sliding = (
            [(f, j, brakes.brakes[j]) for f, j in enumerate(free.tolist()) if self.modes[j].sliding]
            if brakes
            else []
        )
        #: The sliding free joints' directions (+1 forward, -1 backward), by joint index.
        self.sliding_signs = {j: self.modes[j].sign for _, j, _ in self._sliding}
        self._last_hold: tuple[float, bytes, np.ndarray] | None = None
        #: No torque acts: y is (q_f, v_f) only and the accumulators stay constant.
        self.constraints = tuple(constraints)
        self.baumgarte = baumgarte
        self._powered = bool(np.count_nonzero(self._drive_f))
        self._drives = self._powered or self.dynamic is not None
        self.passive = not self._drives and not self._sliding and not self.constraints

    # Per-call constants of the scalar right-hand side, made when first asked for (the batched
    # engine asks for none): no torque, and where the impulses go in dy/dt.

    @functools.cached_property
    def _no_torque(self) -> np.ndarray:
        zero = np.zeros(self.k)
        zero.flags.writeable = False
        return zero

    @functools.cached_property
    def _impulse_index(self) -> np.ndarray:
        return 2 * self.k + WORKS + self.topology.free

    @property
    def _full_data(self) -> pin.Data:
        """The full model's Data (the robot's, made when first asked for: seldom in a batch)."""
        return full_data(self.robot)

    @functools.cached_property
    def events(self) -> list[BrakeStateEvent]:
        """The brake state events that end this phase (built on first use)."""
        machine = self.machine
        if machine is None:
            return []
        holding = weakref.WeakMethod(self.holding_torque)  # no reference cycle through self
        return machine.state_events(
            self.topology.free.tolist(),
            self.topology.locked,
            lambda t, y: holding()(t, y),  # type: ignore[misc]
        )

    @property
    def rhs(self) -> Rhs:
        """The right-hand side f(t, y) of this phase's free state y.

        A passive phase's is the topology itself, which can also write into the integrator's
        buffers. (A property, not an attribute: a phase that held its own bound method would
        be a reference cycle, left to the garbage collector.)
        """
        return self.topology if self.passive else self._rhs

    @functools.cached_property
    def event_specs(self) -> list[EventSpec]:
        """What :attr:`events` watch, in their order, without their functions (first use)."""
        machine = self.machine
        if machine is None:
            return []
        return machine.event_specs(self.topology.free.tolist(), self.topology.locked)

    def shorted(self) -> tuple[np.ndarray, np.ndarray]:
        """Short-circuit figures per joint of the full model, motor side.

        Returns:
            The peak torque where the motor is shorted in this phase (0 elsewhere) [N m], and
            its peak speed (1 where none) [rad/s].
        """
        n = self.robot.nv
        torque, speed = np.zeros(n), np.ones(n)
        if self.dynamic is not None:
            free = self.topology.free[self._dynamic_f]
            torque[free] = self.dynamic.peak_torque[self._dynamic_f]
            speed[free] = self.dynamic.peak_speed[self._dynamic_f]
        return torque, speed

    def pack(self, q: np.ndarray, v: np.ndarray, extras: np.ndarray) -> np.ndarray:
        """Y from full (q, v) and the work/impulse accumulators (omitted when passive)."""
        y = self.topology.split(q, v)
        return y if self.passive else np.concatenate([y, extras])

    def unpack_extras(self, y: np.ndarray, extras: np.ndarray) -> np.ndarray:
        """Accumulators at the states ``y`` (rows), given their value at the phase start."""
        if self.passive:
            if y.ndim == 1:
                return extras.copy()
            return np.repeat(extras[None], len(y), axis=0)
        return y[..., 2 * self.k :]

    def torques(
        self, t: float, q_f: np.ndarray, v_f: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Drive, short-circuit braking and brake torques on the free joints [N m]."""
        tau_drive = tau_short = tau_brake = self._no_torque
        if self._powered:
            topology = self.topology
            tau = self.drive.torques(topology.model, topology.data, t, q_f, v_f)
            tau_drive = np.where(self._drive_f, tau, 0.0)
        if self.dynamic is not None:
            tau_short = np.where(self._dynamic_f, self.dynamic.joint_torque(v_f), 0.0)
        if self._sliding:
            tau_brake = np.zeros(self.k)
            ratio = self.robot.gear_ratio
            for f, j, brake in self._sliding:
                elapsed = t - self.engaged[j]
                tau_brake[f] = kinetic_torque(
                    brake, self.sliding_signs[j], elapsed, v_f[f], ratio[j]
                )
        return tau_drive, tau_short, tau_brake

    def _rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """dy/dt: (v_f, a_f, friction power, drive power, brake torques)."""
        k = self.k
        out = np.zeros_like(y)
        if k == 0:
            return out
        q_f, v_f = y[:k], y[k : 2 * k]
        tau_drive, tau_short, tau_brake = self.torques(t, q_f, v_f)
        tau = tau_drive + tau_short + tau_brake
        if self.constraints:
            a = self.constrained_acceleration(y, tau)[0]
        else:
            topology = self.topology
            a = pin.aba(topology.model, topology.data, q_f, v_f, tau)
        out[:k] = v_f
        out[k : 2 * k] = a
        out[2 * k] = -float(tau_brake.dot(v_f))
        out[2 * k + 1] = float(tau_drive.dot(v_f))
        out[2 * k + 2] = -float(tau_short.dot(v_f))
        out[self._impulse_index] = tau_brake
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
        c = -(gamma + 2.0 * alpha * (Jf @ y[k : 2 * k]) + beta**2 * h)
        return solve_saddle_point(
            M[np.ix_(free, free)], Jf, c, "Constrained dynamics", f=tau_f - b[free]
        )

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

    def accelerations(
        self, t: float, y: np.ndarray, qv: tuple[np.ndarray, np.ndarray] | None = None
    ) -> np.ndarray:
        """Joint accelerations at (t, y) [rad/s^2], zero at the locked joints.

        ABA on the reduced model, or with ``full`` M_ff a_f = tau_f - b_f from the full model
        (CRBA, RNEA, and a dense solve: n is small where this is used). ``qv`` is the full
        (q, v) of y if the caller has it already.
        """
        k = self.k
        a = np.zeros(self.robot.nv)
        if not k:
            return a
        tau: np.ndarray = sum(self.torques(t, y[:k], y[k : 2 * k]))  # type: ignore[assignment]
        if self.full:
            q, v = qv or self.topology.merge(y[: 2 * k])
            topology = self.topology
            return full_accelerations(self.robot, q, v, topology.free, topology.free_block, tau)
        free = self.topology.free
        a[free] = pin.aba(self.topology.model, self.topology.data, y[:k], y[k : 2 * k], tau)
        return a

    def holding_torque(self, t: float, y: np.ndarray) -> np.ndarray:
        """Torque the locks must exert on every joint to keep the locked ones still [N m].

        This is the Lagrange multiplier of each lock (lambda = M a + b - tau at a locked
        joint, with a from the free dynamics); zero at free joints. The last state's
        torques are kept: every stuck joint's slip event asks for them at the same state.
        """
        last = self._last_hold
        key = y.tobytes()
        if last is not None and last[0] == t and last[1] == key:
            return last[2].copy()
        q, v = self.topology.merge(y[: 2 * self.k])
        a = self.accelerations(t, y, (q, v))
        locked = self.topology.locked_index
        if self.full:  # M a + b at the locked joints, from the terms the accelerations used
            tau = locked_torques(self.robot, q, v, locked, a)
        else:
            tau = pin.rnea(self.robot.model, self._full_data, q, v, a)[locked]
        out = np.zeros(self.robot.nv)
        out[locked] = tau
        self._last_hold = (t, key, out.copy())
        return out


class _LastState:
    """The last (q and v bytes, M, b) of :func:`mass_and_bias` (replaced whole)."""

    def __init__(self) -> None:
        self.last: tuple[bytes, np.ndarray, np.ndarray] | None = None


def mass_and_bias(robot: Robot, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M and b of the full model at (q, v), read only; kept for the last state asked.

    The brakes' trial lock sets of one instant share the state, so each of their holding
    torques reuses the one CRBA and RNEA.
    """
    memo = robot.cache.get("mass_and_bias", _LastState)
    key = q.tobytes() + v.tobytes()  # exact: bytes compare faster than arrays this small
    hit = memo.last
    if hit is not None and hit[0] == key:
        return hit[1], hit[2]
    model, data = robot.model, full_data(robot)
    M = compute_M(model, data, q)
    b = np.array(pin.nonLinearEffects(model, data, q, v))
    M.flags.writeable = b.flags.writeable = False
    memo.last = (key, M, b)
    return M, b


def full_accelerations(
    robot: Robot,
    q: np.ndarray,
    v: np.ndarray,
    free: np.ndarray,
    free_block: np.ndarray,
    tau_f: np.ndarray,
) -> np.ndarray:
    """Joint accelerations [rad/s^2] from M_ff a_f = tau_f - b_f of the full model, 0 if locked.

    Args:
        robot: The robot.
        q: Configuration [rad], shape (n,).
        v: Rates [rad/s], exactly 0 at the locked joints.
        free: The free joints' indices, shape (k,), k >= 1.
        free_block: Flat indices of their block of an (n, n) matrix (:class:`Topology`'s).
        tau_f: Torques on the free joints [N m], shape (k,), k >= 1.
    """
    k = free.size
    M, b = mass_and_bias(robot, q, v)
    a = np.zeros(robot.nv)
    a[free] = solve_small(M.take(free_block).reshape(k, k), tau_f - b[free])
    return a


def locked_torques(
    robot: Robot, q: np.ndarray, v: np.ndarray, locked: np.ndarray, a: np.ndarray
) -> np.ndarray:
    """The locks' torques M_L a + b_L [N m] at the joints ``locked``, with ``a`` from the locks."""
    M, b = mass_and_bias(robot, q, v)
    return M[locked].dot(a) + b[locked]


def kinetic_torque(brake: Brake, sign: float, elapsed: float, v: float, ratio: float) -> float:
    """A sliding brake's torque on its joint [N m]: against ``sign`` (+1 forward, -1 back).

    Args:
        brake: The brake.
        sign: Its sliding direction.
        elapsed: Time since it engaged [s].
        v: The joint's rate [rad/s].
        ratio: The joint's gear ratio [-].
    """
    return -sign * brake.sliding(elapsed, sign * v, ratio)


def undriven_torques(
    t: float,
    v: np.ndarray,
    free: np.ndarray,
    machine: BrakeMachine | None,
    dynamic: ShortCircuit | None,
    dynamic_on: np.ndarray,
) -> np.ndarray:
    """Torques on the free joints [N m] with no drive acting: shorted motors, then sliding brakes.

    The sum :meth:`Phase.torques` gives such a phase (bit for bit), without building it: the
    brakes' trial lock sets of one instant ask for it (:class:`vtm_pin.core.simulation._Hybrid`).

    Args:
        t: Time [s].
        v: Rates of all joints [rad/s].
        free: The free joints' indices.
        machine: The brakes (their modes now), if any.
        dynamic: The motors' short-circuit braking, if any.
        dynamic_on: Per joint, whether its motor is shorted.
    """
    tau = np.zeros(free.size)
    if dynamic is not None and dynamic_on[free].any():
        tau = np.where(dynamic_on[free], dynamic.joint_torque(v)[free], 0.0)
    if machine is not None:
        modes, ratio = machine.modes, machine.ratio
        for f, j in enumerate(free.tolist()):
            mode = modes[j]
            if mode.sliding:
                elapsed = t - machine.engaged[j]
                tau[f] += kinetic_torque(machine.brakes[j], mode.sign, elapsed, v[j], ratio[j])
    return tau
