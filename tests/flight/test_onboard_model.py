"""Onboard model (seed 003 eq. 9, seed 000 eq. 2): lags, boundary-crossing pulses, free terms."""

from __future__ import annotations

import numpy as np
import pytest

from flight.onboard_model import BurnTimeline, OnboardModel
from hil.config import load_vehicle

H = 0.2


def _tl(lat_s: float = 0.0) -> BurnTimeline:
    return BurnTimeline(1, H, lat_s, 0.030, 0.027)


def test_pulse_inside_tick_is_worth_tau_minus_3ms() -> None:
    burn, _ = _tl().advance(np.array([0.100]))
    assert burn[0] == pytest.approx(0.097)  # seed 004: tau_E = tau - 3 ms


def test_continuous_firing_has_one_rise_and_the_tail_crosses_the_boundary() -> None:
    tl = _tl()
    b1, _ = tl.advance(np.array([0.2]))
    b2, _ = tl.advance(np.array([0.2]))
    b3, _ = tl.advance(np.array([0.0]))
    assert b1[0] == pytest.approx(0.2 - 0.030)
    assert b2[0] == pytest.approx(0.2)  # stays lit: no new on-lag
    assert b3[0] == pytest.approx(0.027)  # the off-lag tail belongs to the next interval
    assert b1[0] + b2[0] + b3[0] == pytest.approx(0.4 - 0.003)


def test_latency_moves_the_end_of_a_long_pulse_into_the_next_tick() -> None:
    tl = _tl(lat_s=0.020)
    b1, a1 = tl.advance(np.array([0.170]))
    b2, _ = tl.advance(np.array([0.0]))
    assert b1[0] == pytest.approx(0.2 - 0.050)
    assert b2[0] == pytest.approx(0.020 + 0.170 + 0.027 - 0.2)
    # Angle weight: int (h - t) dt over [0.05, 0.2].
    assert a1[0] == pytest.approx(0.5 * 0.15**2)


def test_prediction_from_measured_is_mu_tau_e_for_a_rigid_vehicle_at_rest() -> None:
    v = load_vehicle("generic")
    m = OnboardModel(v, predict_from="measured")
    tau = np.array([0.1, 0, 0, 0, 0, 0])
    p = m.predict(np.zeros(3), tau)
    np.testing.assert_allclose(p.omega_calc_B_rad_s, m.mu_B_rad_s2[0] * 0.097, atol=1e-15)
    assert p.active.tolist() == [True, False, False, False, False, False]


def test_model_variant_integrates_its_own_state() -> None:
    v = load_vehicle("generic")
    m = OnboardModel(v, predict_from="model")
    m.resync(np.zeros(3))
    tau = np.array([0.1, 0, 0, 0, 0, 0])
    m.predict(np.ones(3), tau)  # the argument is ignored: the model's own state is used
    p = m.predict(np.ones(3), np.zeros(6))
    np.testing.assert_allclose(p.omega_calc_B_rad_s, m.mu_B_rad_s2[0] * 0.097, atol=1e-12)


def test_gyroscopic_term_is_euler_closed_form() -> None:
    v = load_vehicle("generic")
    m = OnboardModel(v)
    w = np.array([0.01, 0.02, 0.0])
    J = np.diag([1000.0, 1200.0, 1400.0])
    expected = -np.linalg.inv(J) @ np.cross(w, J @ w) * H
    np.testing.assert_allclose(m.free_increment(w), expected, rtol=1e-12)
