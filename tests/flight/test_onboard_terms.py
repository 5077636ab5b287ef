"""Onboard model (seed 003 eq. 9): gravity-gradient and CMG terms against closed forms.

Euler's equation with internal (CMG) momentum ``H`` and the gravity-gradient torque of a circular
orbit (seed 003 eq. 9; docs/design.md 6.3)::

    J dw/dt = -w x (J w + H) - dH/dt + 3 w0^2 (j x J j)

``j`` is the local vertical (orbit y', seed 004 section 2) in body axes. With a diagonal inertia
``diag(A, B, C)``, ``j x J j = ((C - B) j2 j3, (A - C) j3 j1, (B - A) j1 j2)``, and for a body
turned by ``theta`` about x from the orbit frame ``j = (0, cos theta, -sin theta)``, so the
torque is the textbook ``-3/2 w0^2 (C - B) sin(2 theta)`` about x. These forms are written here
component by component; the plant's implementation is not used.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flight.attitude import q_rotate_inv
from flight.onboard_model import OnboardModel
from hil.config import VehicleCfg, load_vehicle

A_, B_, C_ = 900.0, 1500.0, 2100.0  # principal inertia, kg m^2
W0 = 1.1e-3  # orbit rate, rad/s
H0 = np.array([40.0, -25.0, 60.0])  # CMG momentum, N m s
HDOT = np.array([0.5, 0.2, -0.3])  # its rate of change, N m
Y_O = np.array([0.0, 1.0, 0.0])  # local vertical in the orbit frame


def vehicle(gg: bool = True, cmg: bool = True) -> VehicleCfg:
    data = {
        "name": "terms", "mass_kg": 500.0,
        "inertia_B_kg_m2": [[A_, 0, 0], [0, B_, 0], [0, 0, C_]],
        "orbit": {"rate_rad_s": W0, "gravity_gradient": gg},
        "manifolds": ["m"],
        "thrusters": [{"name": "T", "position_m": [0, 1, 0], "direction": [0, 0, 1],
                       "thrust_n": 5.0, "manifold": "m"}],
    }
    if cmg:
        data["cmg"] = {"h_B_Nms": H0.tolist(), "h_dot_B_Nm": HDOT.tolist()}
    return VehicleCfg.model_validate(data)


def quat(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate(([math.cos(angle / 2)], math.sin(angle / 2) * a))


def gg_accel(j: np.ndarray) -> np.ndarray:
    """3 w0^2 J^-1 (j x J j) for diag(A, B, C), component by component, rad/s^2."""
    j1, j2, j3 = j
    k = 3.0 * W0**2
    return k * np.array([(C_ - B_) * j2 * j3 / A_, (A_ - C_) * j3 * j1 / B_,
                         (B_ - A_) * j1 * j2 / C_])


# --------------------------------------------------------------------------- gravity gradient


@pytest.mark.parametrize("theta_deg", [0.0, 10.0, 30.0, 45.0, 60.0, 90.0, 135.0, -20.0])
def test_gravity_gradient_roll_is_textbook_sin_2theta(theta_deg: float) -> None:
    """Body turned by theta about x: torque -3/2 w0^2 (C - B) sin 2 theta about x only."""
    m = OnboardModel(vehicle(cmg=False))
    th = math.radians(theta_deg)
    j_B = q_rotate_inv(quat([1, 0, 0], th), Y_O)  # as flight/software.py forms it
    np.testing.assert_allclose(j_B, [0.0, math.cos(th), -math.sin(th)], atol=1e-15)
    dw = m.free_increment(np.zeros(3), j_B)
    h = m.h
    expect_x = -1.5 * W0**2 * (C_ - B_) * math.sin(2 * th) / A_ * h
    np.testing.assert_allclose(dw, [expect_x, 0.0, 0.0], rtol=1e-12, atol=1e-22)


def test_gravity_gradient_at_random_attitudes_matches_the_component_form() -> None:
    m = OnboardModel(vehicle(cmg=False))
    rng = np.random.default_rng(11)
    for _ in range(200):
        L = rng.normal(size=4)
        L /= np.linalg.norm(L)
        j_B = q_rotate_inv(L, Y_O)
        dw = m.free_increment(np.zeros(3), j_B)
        np.testing.assert_allclose(dw, gg_accel(j_B) * m.h, rtol=1e-10, atol=1e-20)


def test_gravity_gradient_vanishes_on_principal_axes_and_when_disabled() -> None:
    m = OnboardModel(vehicle(cmg=False))
    for j in np.eye(3):
        assert not np.any(m.free_increment(np.zeros(3), j))
    j = np.array([0.0, math.cos(0.3), -math.sin(0.3)])
    off = OnboardModel(vehicle(gg=False, cmg=False))
    assert not np.any(off.free_increment(np.zeros(3), j))
    assert not np.any(m.free_increment(np.zeros(3), None))  # no vertical given: term left out


def test_gravity_gradient_on_orel_with_products_of_inertia() -> None:
    """orel: full inertia with products; J^-1 3 w0^2 (j x J j) with J from the YAML."""
    v = load_vehicle("orel")
    J = np.array(v.inertia_B_kg_m2)
    w0 = v.orbit.rate_rad_s
    m = OnboardModel(v)
    rng = np.random.default_rng(5)
    for _ in range(50):
        j = rng.normal(size=3)
        j /= np.linalg.norm(j)
        torque = 3 * w0**2 * np.cross(j, J @ j)
        np.testing.assert_allclose(m.free_increment(np.zeros(3), j),
                                   np.linalg.solve(J, torque) * v.timing.tick_s,
                                   rtol=1e-10, atol=1e-22)


# --------------------------------------------------------------------------- CMG momentum


def cmg_accel(w: np.ndarray, t_s: float) -> np.ndarray:
    """-J^-1 (w x H(t) + dH/dt), H(t) = H0 + Hdot t, component by component, rad/s^2."""
    H = H0 + HDOT * t_s
    w1, w2, w3 = w
    wxH = np.array([w2 * H[2] - w3 * H[1], w3 * H[0] - w1 * H[2], w1 * H[1] - w2 * H[0]])
    return -(wxH + HDOT) / np.array([A_, B_, C_])


def euler_accel(w: np.ndarray) -> np.ndarray:
    """-J^-1 (w x J w) for diag(A, B, C): Euler's equations."""
    w1, w2, w3 = w
    return np.array([(B_ - C_) * w2 * w3 / A_, (C_ - A_) * w3 * w1 / B_,
                     (A_ - B_) * w1 * w2 / C_])


@pytest.mark.parametrize("t_s", [0.0, 37.4, 600.0])
def test_cmg_term_is_minus_w_cross_h_minus_hdot(t_s: float) -> None:
    m = OnboardModel(vehicle(gg=False, cmg=True))
    rigid = OnboardModel(vehicle(gg=False, cmg=False))
    rng = np.random.default_rng(int(t_s * 10))
    for _ in range(50):
        w = rng.normal(size=3) * 0.01
        dw = m.free_increment(w, None, t_s)
        np.testing.assert_allclose(dw, (euler_accel(w) + cmg_accel(w, t_s)) * m.h,
                                   rtol=1e-10, atol=1e-20)
        # The CMG part alone (the vehicle without CMG gives the rest).
        np.testing.assert_allclose(dw - rigid.free_increment(w, None, t_s),
                                   cmg_accel(w, t_s) * m.h, rtol=1e-9, atol=1e-20)


def test_cmg_at_rest_leaves_only_minus_hdot() -> None:
    m = OnboardModel(vehicle(gg=False, cmg=True))
    np.testing.assert_allclose(m.free_increment(np.zeros(3), None, 12.0),
                               -HDOT / np.array([A_, B_, C_]) * m.h, rtol=1e-14)


def test_cmg_single_axis_closed_form() -> None:
    """w = w3 z, H = H0 + Hdot t: dw = -(w3 H_x... ) with each component written out."""
    m = OnboardModel(vehicle(gg=False, cmg=True))
    w3, t = 2e-3, 5.0
    H = H0 + HDOT * t
    dw = m.free_increment(np.array([0.0, 0.0, w3]), None, t)
    # w x H = (-w3 H_y, w3 H_x, 0); w x J w = 0 for a principal-axis rate.
    expect = -np.array([-w3 * H[1] + HDOT[0], w3 * H[0] + HDOT[1], HDOT[2]]) / [A_, B_, C_]
    np.testing.assert_allclose(dw, expect * m.h, rtol=1e-13)


def test_all_terms_enter_the_prediction() -> None:
    """predict = base + h (Euler + CMG + gravity gradient), no thrust commanded."""
    m = OnboardModel(vehicle(gg=True, cmg=True), predict_from="measured")
    w = np.array([3e-3, -1e-3, 2e-3])
    th = 0.4
    j = np.array([0.0, math.cos(th), -math.sin(th)])
    p = m.predict(w, np.zeros(1), j, t_s=20.0)
    expect = w + (euler_accel(w) + cmg_accel(w, 20.0) + gg_accel(j)) * m.h
    np.testing.assert_allclose(p.omega_calc_B_rad_s, expect, rtol=1e-12, atol=1e-20)
    assert not p.dw_thr_B_rad_s.any()


def test_iss_rs_cmg_momentum_from_yaml() -> None:
    """iss_rs: the configured H enters as -J^-1 (w x H) h."""
    v = load_vehicle("iss_rs")
    J = np.array(v.inertia_B_kg_m2)
    H = np.array(v.cmg.h_B_Nms)
    m = OnboardModel(v)
    w = np.array([1e-4, -2e-3, 5e-4])
    expect = -np.linalg.solve(J, np.cross(w, J @ w + H) + np.array(v.cmg.h_dot_B_Nm))
    np.testing.assert_allclose(m.free_increment(w, None, 0.0), expect * v.timing.tick_s,
                               rtol=1e-10)
