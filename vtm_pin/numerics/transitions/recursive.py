r"""Joint locks in O(n): the momentum-consistent jump from Pinocchio's recursive algorithms.

When only joints lock (no frame constraints), the paper's transition keeps the momentum of the
joints still free: with f the free and l the locked coordinates after the event,

.. math::
    M_{ff} \dot q_f^+ = (M \dot q^-)_f, \qquad \dot q_l^+ = 0,

computed as the jump of the free rates, M_ff dv_f = M_fl v-_l, so that locking joints at rest
leaves v exactly unchanged (as the kkt solve does: the brake state machine reads exact zeros).
No dense M is needed. ``M v`` is one RNEA pass without gravity at zero velocity with the
acceleration v, and ``M_ff^{-1} x`` one ABA pass on the model with the locked joints fixed
(Pinocchio's ``buildReducedModel``), without gravity, at zero velocity, with the torque x. The
impulses follow from the same product: M dv + J+^T Lambda = 0 gives Lambda_i = -(M dv)_i at
each locked joint i. Every step is O(n); the kkt rule forms M and solves (n + m1 + m2)
equations.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ...exceptions import TransitionError
from .base import TransitionResult


def weightless(model: pin.Model) -> pin.Model:
    """A copy of ``model`` without gravity (for the products M v and M^-1 tau)."""
    copy = pin.Model(model)
    copy.gravity = pin.Motion.Zero()
    return copy


def compute_joint_lock_transition(
    model: pin.Model,
    q: np.ndarray,
    v_minus: np.ndarray,
    locked_before: Sequence[int],
    joints: Sequence[int],
    reduced: pin.Model | None = None,
    data: pin.Data | None = None,
    reduced_data: pin.Data | None = None,
) -> TransitionResult:
    """Velocity jump when ``joints`` lock and ``locked_before`` stay locked, in O(n).

    Args:
        model: The robot's model without gravity (see :func:`weightless`), armature included.
        q: Configuration at the event [rad], shape (nv,).
        v_minus: Velocity just before the event [rad/s], zero at ``locked_before``.
        locked_before: Velocity indices locked before the event (the rows of J1, in order).
        joints: Velocity indices locking at the event (the rows of J2, in order).
        reduced: ``model`` with every locked joint fixed at ``q``, gravity zero; built here if
            not given.
        data: ``model.createData()``, to pass in a loop: Pinocchio's ``createData`` is not
            O(n) (266 ms at n = 200, against microseconds for the passes themselves).
        reduced_data: ``reduced.createData()``, likewise (``buildReducedModel`` is not O(n)
            either).

    Returns:
        The same transition as the kkt rule gives for unit-row J1 and J2: v+, Lambda (J1 rows
        first), energy loss, the free joints' momenta before and after, residual 0.
    """
    locked, free = _split(model.nv, locked_before, joints)
    data = model.createData() if data is None else data
    zero = np.zeros(model.nv)
    p_minus = pin.rnea(model, data, q, zero, v_minus)  # M v- (a new array)
    v_plus = np.array(v_minus, dtype=float)
    v_plus[locked] = 0.0
    if free.size:
        if reduced is None:
            ids = [model.joints[j].id for j in range(1, model.njoints)]
            held = set(locked.tolist())
            fixed = [ids[i] for i in range(len(ids)) if model.joints[ids[i]].idx_v in held]
            reduced = pin.buildReducedModel(model, fixed, q)
            reduced_data = None
        reduced_data = reduced.createData() if reduced_data is None else reduced_data
        v_locked = np.array(v_minus, dtype=float)
        v_locked[free] = 0.0
        tau = pin.rnea(model, data, q, zero, v_locked)[free]  # M_fl v-_l
        v_plus[free] += pin.aba(reduced, reduced_data, q[free], np.zeros(free.size), tau)
    require_finite(v_plus)
    M_dv = pin.rnea(model, data, q, zero, v_plus - v_minus)  # M (v+ - v-)
    return _result(v_minus, v_plus, p_minus, M_dv, locked, free, len(locked_before))


def compute_joint_lock_transition_dense(
    M: np.ndarray, v_minus: np.ndarray, locked_before: Sequence[int], joints: Sequence[int]
) -> TransitionResult:
    """The same jump as :func:`compute_joint_lock_transition`, from the dense M.

    M_ff dv_f = M_fl v-_l by a dense solve: for a small n, where forming M costs less than
    a reduced model (the batched engine's hybrid loops). Joints locking at rest leave v
    exactly unchanged, as in the recursive form.

    Args:
        M: Mass matrix at the event [kg m^2], shape (n, n).
        v_minus: Velocity just before the event [rad/s], zero at ``locked_before``.
        locked_before: Velocity indices locked before the event.
        joints: Velocity indices locking at the event.
    """
    if at_rest(v_minus, locked_before, joints):
        return joint_lock_at_rest(M @ v_minus, v_minus, locked_before, joints)
    rows, free = _split(len(v_minus), locked_before, joints)
    p_minus = M @ v_minus
    v_plus = np.array(v_minus, dtype=float)
    v_l = v_plus[rows]
    v_plus[rows] = 0.0
    if free.size and v_l.any():  # joints locking at rest: no jump, no solve
        tau = M[free][:, rows] @ v_l  # M_fl v-_l
        v_plus[free] += np.linalg.solve(M[free][:, free], tau)
    require_finite(v_plus)
    M_dv = M @ (v_plus - v_minus)
    return _result(v_minus, v_plus, p_minus, M_dv, rows, free, len(locked_before))


def require_finite(v_plus: np.ndarray) -> None:
    """Raise :class:`~vtm_pin.exceptions.TransitionError` unless every rate of v+ is finite."""
    if not np.isfinite(v_plus).all():
        raise TransitionError(
            "Joint-lock transition is numerically unreliable: v+ is not finite; the mass "
            "matrix is singular or too ill-conditioned for this lock"
        )


def at_rest(v_minus: np.ndarray, locked_before: Sequence[int], joints: Sequence[int]) -> bool:
    """Whether every locked rate is exactly 0: the lock is :func:`joint_lock_at_rest`."""
    return not any(v_minus[i] for i in (*locked_before, *joints))


def joint_lock_at_rest(
    p_minus: np.ndarray, v_minus: np.ndarray, locked_before: Sequence[int], joints: Sequence[int]
) -> TransitionResult:
    """The joint-lock transition where every locked rate is exactly 0 (:func:`at_rest`).

    No jump: v+ = v-, no impulse, no energy lost, the free momentum (M v)_f kept. The general
    steps give exactly these (M times a zero dv); a brake that sticks at rest takes this path
    (six times a study case), without their products, and needs M v only (one RNEA pass on
    the weightless model, not M).

    Args:
        p_minus: The momentum M v- [N m s], shape (n,).
        v_minus: Velocity just before the event [rad/s], 0 at the locked joints.
        locked_before: Velocity indices locked before the event.
        joints: Velocity indices locking at the event.
    """
    v_plus = np.array(v_minus, dtype=float)
    require_finite(v_plus)
    _, free = _split(len(v_plus), locked_before, joints)
    p_free = p_minus[free]
    return TransitionResult(
        v_plus=v_plus,
        Lambda=np.zeros(len(locked_before) + len(joints)),
        m1=len(locked_before),
        energy_loss=0.0,
        p_free_minus=p_free,
        p_free_plus=p_free.copy(),
        residual=0.0,
    )


def _split(
    n: int, locked_before: Sequence[int], joints: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the locked coordinates (J1 rows, then J2) and of the free ones, in order."""
    return _split_cached(n, (*locked_before,), (*joints,))


@functools.lru_cache(maxsize=1024)
def _split_cached(
    n: int, locked_before: tuple[int, ...], joints: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_split` of a lock set, kept (read only): a study's runs lock the same few sets."""
    locked = np.array([*locked_before, *joints], dtype=np.intp)
    free = np.ones(n, dtype=bool)
    free[locked] = False
    out = (locked, np.flatnonzero(free))
    for array in out:
        array.flags.writeable = False
    return out


def _result(
    v_minus: np.ndarray,
    v_plus: np.ndarray,
    p_minus: np.ndarray,
    M_dv: np.ndarray,
    locked: np.ndarray,
    free: np.ndarray,
    m1: int,
) -> TransitionResult:
    """The transition from v+- and the momenta M v- and M (v+ - v-)."""
    p_plus = p_minus + M_dv
    return TransitionResult(
        v_plus=v_plus,
        Lambda=-M_dv[locked],
        m1=m1,
        energy_loss=0.5 * float(v_minus @ p_minus - v_plus @ p_plus),
        p_free_minus=p_minus[free],
        p_free_plus=p_plus[free],
        residual=0.0,
    )
