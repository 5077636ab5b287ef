"""Strapdown attitude estimate relative to the orbit frame, and quaternion helpers.

Frames (seed 004 section 2; docs/design.md 5.1): the orbit frame O has y' along the radius vector
from the Earth's centre, z' against the orbital angular velocity and x' completing the right-handed
set (towards the velocity), so the orbit frame turns about its own axes at ``-w0 z'``. B is the
body frame. T is the target frame, fixed in O: ``R`` is the quaternion of T relative to O.

Quaternions are scalar-first ``[q0, q1, q2, q3]`` (Hamilton product). ``Lambda`` is the attitude
of B relative to O: a vector ``v_B`` in body axes has orbit-frame components
``v_O = Lambda (x) v_B (x) Lambda~``, and ``dLambda/dt = 1/2 Lambda (x) [0, w_BO_B]``. The error
quaternion of seed 004 section 2 is ``N = R~ (x) Lambda`` (B relative to T); its small-angle
vector is ``nu ~ 2 N_vec`` (with ``N0 >= 0``).

Everything here is pure: the rate and the step length are arguments.
"""

from __future__ import annotations

import math

import numpy as np

from common.quaternion import q_conj, q_mul

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
Z_AXIS = np.array([0.0, 0.0, 1.0])


def q_normalise(q: np.ndarray) -> np.ndarray:
    """Unit quaternion with a non-negative scalar part (the shorter of the two rotations)."""
    q = np.asarray(q, dtype=float)
    n = math.sqrt(float(q @ q))
    if n == 0.0:
        raise ValueError("q_normalise: expected a non-zero quaternion, got [0, 0, 0, 0]")
    q = q / n
    return -q if q[0] < 0.0 else q


def q_from_axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about the unit vector ``axis`` (3,), shape (4,)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    h = 0.5 * angle_rad
    return np.concatenate(([math.cos(h)], math.sin(h) * a))


def q_from_rotation_vector(phi_rad: np.ndarray) -> np.ndarray:
    """Exact quaternion of the rotation vector ``phi`` (3,) (angle = norm, axis = direction)."""
    phi = np.asarray(phi_rad, dtype=float)
    ang = math.sqrt(float(phi @ phi))
    if ang < 1e-12:
        return q_normalise(np.concatenate(([1.0], 0.5 * phi)))
    return q_from_axis_angle(phi / ang, ang)


def q_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``q (x) [0, v] (x) q~``: outer-frame components of an inner-frame vector ``v`` (3,)."""
    return q_mul(q_mul(q, np.concatenate(([0.0], v))), q_conj(q))[1:]


def q_rotate_inv(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``q~ (x) [0, v] (x) q``: inner-frame components of an outer-frame vector ``v`` (3,)."""
    return q_mul(q_mul(q_conj(q), np.concatenate(([0.0], v))), q)[1:]


def small_angle_vector(q: np.ndarray) -> np.ndarray:
    """Seed 004 section 2: ``nu ~ 2 N_vec`` for ``N0 >= 0``, rad, shape (3,)."""
    qn = q_normalise(q)
    return 2.0 * qn[1:]


def rotation_angle(q: np.ndarray) -> float:
    """Angle of the shortest rotation that ``q`` describes, rad in [0, pi]."""
    qn = q_normalise(q)
    return 2.0 * math.atan2(math.sqrt(float(qn[1:] @ qn[1:])), qn[0])


def error_quaternion(R_TO: np.ndarray, Lambda_BO: np.ndarray) -> np.ndarray:
    """Seed 004 section 2: ``N = R~ (x) Lambda``, attitude of B relative to T, with ``N0 >= 0``."""
    return q_normalise(q_mul(q_conj(R_TO), Lambda_BO))


def orbit_rate_B_rad_s(Lambda_BO: np.ndarray, w0_rad_s: float) -> np.ndarray:
    """Inertial angular velocity of the orbit frame (``-w0 z'``) in body axes, rad/s (3,).

    A target frame fixed in O turns at the same rate: this is the programme rate ``w_b`` of the
    phase-plane ordinate ``w - w_b`` (seed 004 section 2).
    """
    return q_rotate_inv(Lambda_BO, -w0_rad_s * Z_AXIS)


def propagate(
    Lambda_BO: np.ndarray, omega_BI_B_rad_s: np.ndarray, dt_s: float, w0_rad_s: float
) -> np.ndarray:
    """Attitude of B relative to O after ``dt_s`` with constant inertial body rate (3,).

    Exact for constant rates: ``Lambda+ = exp(w_OI_O dt / 2)~ (x) Lambda (x) exp(w_BI_B dt / 2)``
    with ``w_OI_O = -w0 z'`` the orbit frame's rate in its own axes.
    """
    q_body = q_from_rotation_vector(np.asarray(omega_BI_B_rad_s, dtype=float) * dt_s)
    return propagate_increment(Lambda_BO, q_body, dt_s, w0_rad_s)


def propagate_increment(
    Lambda_BO: np.ndarray, dq_BI: np.ndarray, dt_s: float, w0_rad_s: float
) -> np.ndarray:
    """As :func:`propagate` with the body's inertial rotation increment ``dq_BI`` (4,) given.

    ``dq_BI`` comes from an integrating gyro (seed 002: angle increments, use
    :func:`q_from_rotation_vector`) or from a rate sample held over the step.
    """
    q_orbit = q_from_rotation_vector(-w0_rad_s * dt_s * Z_AXIS)
    return q_normalise(q_mul(q_mul(q_conj(q_orbit), Lambda_BO), dq_BI))


class AttitudeEstimate:
    """Strapdown estimate of ``Lambda`` (B relative to O) from the measured inertial body rate.

    Holds only the quaternion; each :meth:`update` integrates one step with the rate held
    constant (zero-order hold of the gyro sample), see :func:`propagate`.
    """

    def __init__(self, w0_rad_s: float, Lambda0_BO: np.ndarray | None = None) -> None:
        self.w0_rad_s = float(w0_rad_s)
        self.Lambda_BO = q_normalise(IDENTITY if Lambda0_BO is None else Lambda0_BO)

    def update(self, omega_BI_B_rad_s: np.ndarray, dt_s: float) -> np.ndarray:
        """Integrate the rate (3,) over ``dt_s``; returns the new ``Lambda`` (4,)."""
        self.Lambda_BO = propagate(self.Lambda_BO, omega_BI_B_rad_s, dt_s, self.w0_rad_s)
        return self.Lambda_BO

    def update_increment(self, dtheta_B_rad: np.ndarray, dt_s: float) -> np.ndarray:
        """Integrate an angle increment (3,) from an integrating gyro over ``dt_s``."""
        dq = q_from_rotation_vector(np.asarray(dtheta_B_rad, dtype=float))
        self.Lambda_BO = propagate_increment(self.Lambda_BO, dq, dt_s, self.w0_rad_s)
        return self.Lambda_BO

    def reset(self, Lambda_BO: np.ndarray) -> None:
        """Replace the estimate (e.g. from an absolute attitude sensor)."""
        self.Lambda_BO = q_normalise(Lambda_BO)

    def rate_relative_B_rad_s(self, omega_BI_B_rad_s: np.ndarray) -> np.ndarray:
        """Body rate relative to O (and to any target fixed in O), rad/s (3,)."""
        return np.asarray(omega_BI_B_rad_s, dtype=float) - orbit_rate_B_rad_s(
            self.Lambda_BO, self.w0_rad_s
        )
