"""Seed 002 Kalman filter: disturbance estimate converges; the leak test names the thruster."""

from __future__ import annotations

import numpy as np
import pytest

from flight.kalman import DisturbanceKalman
from hil.config import KalmanCfg

H = 0.2
E = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])


def _simulate(d_true: np.ndarray, cfg: KalmanCfg, n: int = 300, noise: float = 1e-5):
    rng = np.random.default_rng(3)
    kf = DisturbanceKalman(cfg, H, E)
    phi, w = np.zeros(3), np.zeros(3)
    hist = []
    for _ in range(n):
        phi = phi + w * H + 0.5 * d_true * H * H
        w = w + d_true * H
        kf.update(phi + noise * rng.standard_normal(3), np.zeros(3), np.zeros(3),
                  np.ones(3, bool))
        hist.append(kf.disturbance_B_rad_s2)
    return kf, np.array(hist)


def test_disturbance_estimate_converges_to_a_constant_disturbance() -> None:
    d_true = np.array([0.2 / 1500, -0.2 / 1500, 0.2 / 1500])  # seed 002: 0.2 N m / 1500 kg m^2
    cfg = KalmanCfg(enabled=True, process_noise_accel=1e-6, measurement_noise_rad=1e-5)
    _, hist = _simulate(d_true, cfg)
    np.testing.assert_allclose(hist[-50:].mean(axis=0), d_true, atol=1e-5)


def test_known_control_input_is_not_taken_as_a_disturbance() -> None:
    cfg = KalmanCfg(enabled=True, process_noise_accel=1e-6)
    kf = DisturbanceKalman(cfg, H, E)
    phi, w = np.zeros(3), np.zeros(3)
    for n in range(100):
        dw = np.array([1e-3, 0, 0]) if n % 10 == 0 else np.zeros(3)
        dphi = dw * H / 2
        phi = phi + w * H + dphi
        w = w + dw
        kf.update(phi, dw, dphi, dw == 0)
    assert np.abs(kf.disturbance_B_rad_s2).max() < 1e-6


def test_leak_test_names_the_thruster_by_direction() -> None:
    leak = 0.15 * 50.0 / 1500.0  # seed 002: 15 % residual thrust of a 50 N m thruster
    cfg = KalmanCfg(enabled=True, process_noise_accel=1e-5, leak_threshold_rad_s2=1e-3,
                    window_ticks=5)
    kf, _ = _simulate(np.array([0.0, -leak, 0.0]), cfg, n=60)
    rep = kf.leak_test()
    assert rep is not None and rep.thruster == 3
    assert rep.projection_rad_s2 == pytest.approx(leak, rel=0.1)
