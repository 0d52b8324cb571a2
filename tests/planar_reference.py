"""Closed-form planar 3R pendulum dynamics, independent of Pinocchio (Kane's equations).

Conventions of robots/planar_3r.urdf: joint axes along world y, z up, q = 0 hangs down, q_i
relative. Link i's absolute angle is theta_i = q_1 + ... + q_i and its unit vector from joint i
to joint i+1 in the (x, z) plane is u(theta) = (-sin theta, -cos theta).
"""

from __future__ import annotations

import numpy as np

LENGTH = 1.0  # [m]
COM = 0.5  # [m] from the joint
MASS = 108.0  # [kg]
INERTIA = 9.36  # [kg m^2] about the COM, about the joint axis
GRAVITY = np.array([0.0, -9.81])  # (x, z) [m/s^2]
N = 3


def _u(theta: float) -> np.ndarray:
    return np.array([-np.sin(theta), -np.cos(theta)])


def _du(theta: float) -> np.ndarray:
    return np.array([-np.cos(theta), np.sin(theta)])


def inverse_dynamics(q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Joint torques tau = M a + C v + g for the 3R pendulum [N m]."""
    theta = np.cumsum(q)
    omega = np.cumsum(v)
    alpha = np.cumsum(a)
    tau = np.zeros(N)
    for i in range(N):
        # COM acceleration and the partial velocities d r_i / d q_j.
        acc = np.zeros(2)
        partial = np.zeros((N, 2))
        for link in range(i + 1):
            arm = COM if link == i else LENGTH
            acc += arm * (_du(theta[link]) * alpha[link] - _u(theta[link]) * omega[link] ** 2)
            for j in range(link + 1):
                partial[j] += arm * _du(theta[link])
        force = MASS * (acc - GRAVITY)
        for j in range(i + 1):
            tau[j] += partial[j] @ force + INERTIA * alpha[i]
    return tau


def mass_matrix(q: np.ndarray) -> np.ndarray:
    """M(q) [kg m^2] from inverse dynamics with zero velocity and gravity removed."""
    g = inverse_dynamics(q, np.zeros(N), np.zeros(N))
    return np.column_stack([inverse_dynamics(q, np.zeros(N), e) - g for e in np.eye(N)])


def bias(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C(q, v) v + g(q) [N m]."""
    return inverse_dynamics(q, v, np.zeros(N))


def potential_energy(q: np.ndarray) -> float:
    """Gravitational potential energy [J], zero at the height of joint 1."""
    theta = np.cumsum(q)
    height = 0.0
    energy = 0.0
    for i in range(N):
        energy += MASS * 9.81 * (height - COM * np.cos(theta[i]))
        height -= LENGTH * np.cos(theta[i])
    return energy
