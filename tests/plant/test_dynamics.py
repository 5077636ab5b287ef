"""Rigid body (docs/design.md 5.1): conservation laws, closed forms, gravity gradient, orbit
frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import make_vehicle

from hil.config import AttitudeCfg, InitialCfg
from plant.core import Plant
from plant.dynamics import (
    RigidBody,
    gravity_gradient_B,
    quat_conj,
    quat_mul,
    quat_to_dcm,
)


def test_torque_free_conserves_momentum_and_energy_1000_s() -> None:
    """Inertial angular momentum and kinetic energy: relative drift < 1e-9 over 1000 s."""
    J = np.array([[120.0, 3.0, -2.0], [3.0, 200.0, 5.0], [-2.0, 5.0, 310.0]])
    q0 = np.array([0.9, 0.1, -0.3, 0.2])
    w0 = np.radians([3.0, -1.5, 2.0])  # a tumbling body, rates up to the 3.5 deg/s of seed 004
    body = RigidBody(J, q0, w0)
    H0, T0 = body.angular_momentum_I(0.0), body.kinetic_energy_J()
    h = 0.01  # the plant's benchmark step
    for k in range(100_000):
        body.step(k * h, h, [0.0, 0.0, 0.0])
    H1, T1 = body.angular_momentum_I(1000.0), body.kinetic_energy_J()
    assert np.linalg.norm(H1 - H0) / np.linalg.norm(H0) < 1e-9
    assert abs(T1 - T0) / T0 < 1e-9


def test_torque_free_with_cmg_momentum_conserves_total_momentum() -> None:
    J = np.diag([100.0, 150.0, 180.0])
    body = RigidBody(J, np.array([1.0, 0, 0, 0]), np.radians([1.0, 2.0, -1.0]),
                     h_cmg_B_Nms=np.array([5.0, -3.0, 2.0]))
    H0 = body.angular_momentum_I(0.0)
    for k in range(20_000):
        body.step(k * 0.01, 0.01, [0.0, 0.0, 0.0])
    assert np.linalg.norm(body.angular_momentum_I(200.0) - H0) / np.linalg.norm(H0) < 1e-9


def test_axisymmetric_precession_rate() -> None:
    """I1 = I2: w3 constant, (w1, w2) turns at Omega = (I3 - I1) / I1 * w3 in body axes."""
    I1, I3 = 100.0, 160.0
    w3 = 0.05
    body = RigidBody(np.diag([I1, I1, I3]), np.array([1.0, 0, 0, 0]), np.array([0.01, 0.0, w3]))
    omega = (I3 - I1) / I1 * w3
    h, t_end = 0.01, 300.0
    for k in range(int(round(t_end / h))):
        body.step(k * h, h, [0.0, 0.0, 0.0])
    w = body.w_B_rad_s
    # Closed form: d(w1 + i w2)/dt = i Omega (w1 + i w2), so w1 + i w2 = 0.01 exp(i Omega t).
    expected = 0.01 * np.exp(1j * omega * t_end)
    assert w[0] == pytest.approx(expected.real, abs=1e-12)
    assert w[1] == pytest.approx(expected.imag, abs=1e-12)
    assert w[2] == pytest.approx(w3, abs=1e-15)


def test_constant_torque_spin_up_closed_form() -> None:
    """Thruster torque about a principal axis: w(t) = M t / I (no gyroscopic term)."""
    plant = Plant(make_vehicle(), step_s=0.01)
    for n in range(10):
        plant.apply_command(n, n * 0.2, np.array([200, 0, 0, 0, 0, 0]))
    plant.apply_command(10, 2.0, np.zeros(6))
    plant.advance_to(3.0)
    impulse = plant.truth.impulse_Ns[0]
    assert plant.truth.omega_B_rad_s[0] == pytest.approx(impulse * 1.0 / 100.0, rel=1e-12)
    assert plant.truth.dv_B_m_s[2] == pytest.approx(impulse / 500.0, rel=1e-12)
    # Attitude angle = int w dt: compare with the rotation angle of q_BO.
    ang = 2 * math.atan2(np.linalg.norm(plant.truth.q_BO[1:]), plant.truth.q_BO[0])
    assert ang > 0


def _gg_independent(q_BO: np.ndarray, J: np.ndarray, w0: float) -> np.ndarray:
    """3 w0^2 (j x J j), j the radius direction (y' of the orbit frame) in body axes, written
    with an explicit rotation matrix built from the axis-angle."""
    angle = 2 * math.acos(max(-1.0, min(1.0, q_BO[0])))
    axis = q_BO[1:] / (np.linalg.norm(q_BO[1:]) or 1.0)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R_OB = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K  # body -> orbit
    j = R_OB.T @ np.array([0.0, 1.0, 0.0])
    Jj = J @ j
    return 3 * w0**2 * np.array([j[1] * Jj[2] - j[2] * Jj[1], j[2] * Jj[0] - j[0] * Jj[2],
                                 j[0] * Jj[1] - j[1] * Jj[0]])


@pytest.mark.parametrize("axis, angle_deg", [((1, 0, 0), 0.0), ((1, 0, 0), 30.0),
                                             ((0, 0, 1), 20.0), ((1, 2, -1), 45.0)])
def test_gravity_gradient_torque(axis, angle_deg) -> None:
    J = np.array([[1.0e5, 0, 0], [0, 4.0e5, 0], [0, 0, 4.5e5]])
    w0 = 0.001162
    q = AttitudeCfg(axis=axis, angle_deg=angle_deg).quaternion()
    body = RigidBody(J, q, np.zeros(3), w0_rad_s=w0, gravity_gradient=True)
    j_B = body.local_vertical_B(0.0)
    m = gravity_gradient_B(j_B, J, w0)
    assert m == pytest.approx(_gg_independent(q, J, w0), abs=1e-15)
    # And the integrator applies it: initial angular acceleration = J^-1 M_gg.
    wd = np.array(body._deriv(0.0, *q, 0.0, 0.0, 0.0, [0.0, 0.0, 0.0])[:3])
    assert wd == pytest.approx(np.linalg.solve(J, m), abs=1e-18)


def test_orbit_frame_hold_and_gravity_gradient_equilibrium() -> None:
    """Principal axes on the orbit axes, rate = orbit rate: q_BO stays identity (an equilibrium
    of the gravity gradient), and the orbit frame itself is exact."""
    v = make_vehicle(orbit={"rate_rad_s": 0.001162, "gravity_gradient": True})
    plant = Plant(v, step_s=0.05)
    plant.advance_to(2000.0)
    tr = plant.truth
    assert tr.q_BO == pytest.approx([1, 0, 0, 0], abs=1e-9)
    assert tr.omega_BO_B_rad_s == pytest.approx(np.zeros(3), abs=1e-12)
    assert tr.omega_B_rad_s == pytest.approx([0, 0, -0.001162], abs=1e-12)


def test_initial_attitude_and_rate_relative_to_orbit() -> None:
    v = make_vehicle(orbit={"rate_rad_s": 0.001, "gravity_gradient": False})
    init = InitialCfg(attitude=AttitudeCfg(axis=(0, 1, 0), angle_deg=10.0),
                      rate_B_deg_s=(0.5, 0.0, 0.0))
    plant = Plant(v, initial=init)
    tr = plant.truth
    assert tr.q_BO == pytest.approx(init.attitude.quaternion(), abs=1e-15)
    assert tr.omega_BO_B_rad_s == pytest.approx(np.radians([0.5, 0, 0]), abs=1e-15)
    # Consistency of the quaternion helpers: q_BI = q_OI (x) q_BO at t = 0 (q_OI = 1).
    assert quat_mul(quat_conj(tr.q_BI), tr.q_BI) == pytest.approx([1, 0, 0, 0])
    assert quat_to_dcm(tr.q_BO) @ quat_to_dcm(tr.q_BO).T == pytest.approx(np.eye(3))
