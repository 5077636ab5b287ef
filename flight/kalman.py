"""Per-axis Kalman filter with a disturbance state and the leak test (seed 002).

Seed 002 model per channel j (small angles, principal axes): state ``x = (phi, w, m_d)``, the
angle (rad), the rate (rad/s) and the disturbance acceleration ``m_d = M_d / J`` (rad/s^2),
constant between ticks; the control input is known from the commands. Discrete form over one
tick h (``F`` the transition of a double integrator driven by a constant ``m_d``)::

    phi[n+1] = phi[n] + h w[n] + h^2/2 m_d[n] + dphi_u[n]
    w[n+1]   = w[n]   + h m_d[n]               + dw_u[n]
    m_d[n+1] = m_d[n] + process noise

``dw_u`` and ``dphi_u`` are the thrusters' rate and angle increments over the tick from the
onboard model (equivalent burns, seed 004 lags). The measurement is the integrated gyro angle
``z = phi + noise`` (seed 002: "the sensor measures integrals of the rate"). Seed 002 proves the
pair (F, H) observable (rank 3).

Leak test (seed 002, fig. 1): the mean of ``m_d`` over the last ``window_ticks`` ticks in which
the channel had no command (seed 002: "on a time base where the control is zero") is compared
with ``leak_threshold_rad_s2``; above it, a thruster is stuck on with partial thrust. The culprit
is the thruster whose unit angular acceleration ``e_i`` has the largest projection of the mean
disturbance vector (all its channels), so a leak is named by direction and sign, not by axis.
Set the threshold above the known external disturbance (kalman_cube: 0.2 N m / 1500 kg m^2 =
1.3e-4 rad/s^2) and below the smallest leak to detect.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from common.vehicle import KalmanCfg


@dataclass(frozen=True)
class LeakReport:
    """A leak found by the test: thruster index, mean disturbance (3,) rad/s^2, its projection."""

    thruster: int
    mean_disturbance_B_rad_s2: np.ndarray
    projection_rad_s2: float


class DisturbanceKalman:
    """Three independent seed-002 filters (x, y, z), vectorised.

    ``update(phi_meas_B_rad, dw_u_B_rad_s, dphi_u_B_rad, quiet)`` advances one tick: prediction
    with the last tick's control increments (3,), then the correction with the integrated gyro
    angle (3,). ``quiet`` (3,) bool says the channel had no command over the tick (leak test).
    Estimates: ``x`` (3 channels, 3 states).
    """

    def __init__(self, cfg: KalmanCfg, tick_s: float, e_B: np.ndarray | None = None) -> None:
        self.cfg = cfg
        h = float(tick_s)
        self.h = h
        self.F = np.array([[1.0, h, 0.5 * h * h], [0.0, 1.0, h], [0.0, 0.0, 1.0]])
        self.H = np.array([[1.0, 0.0, 0.0]])
        q = float(cfg.process_noise_accel) ** 2
        # Disturbance as a random walk; its effect on angle and rate through F.
        G = np.array([[0.5 * h * h], [h], [1.0]])
        self.Q = q * (G @ G.T)
        self.R = float(cfg.measurement_noise_rad) ** 2
        self.e_B = None if e_B is None else np.asarray(e_B, dtype=float)  # (N, 3) unit vectors
        self.reset()

    def reset(self, phi0_B_rad: np.ndarray | None = None,
              w0_B_rad_s: np.ndarray | None = None) -> None:
        self.x = np.zeros((3, 3))
        if phi0_B_rad is not None:
            self.x[:, 0] = phi0_B_rad
        if w0_B_rad_s is not None:
            self.x[:, 1] = w0_B_rad_s
        self.P = np.stack([np.diag([self.R, 1e-6, 1e-6]) for _ in range(3)])
        self._quiet: list[deque[float]] = [deque(maxlen=self.cfg.window_ticks) for _ in range(3)]

    @property
    def disturbance_B_rad_s2(self) -> np.ndarray:
        return self.x[:, 2].copy()

    def update(self, phi_meas_B_rad: np.ndarray, dw_u_B_rad_s: np.ndarray,
               dphi_u_B_rad: np.ndarray, quiet: np.ndarray) -> np.ndarray:
        z = np.asarray(phi_meas_B_rad, dtype=float)
        for k in range(3):
            x = self.F @ self.x[k]
            x[0] += dphi_u_B_rad[k]
            x[1] += dw_u_B_rad_s[k]
            P = self.F @ self.P[k] @ self.F.T + self.Q
            S = float(P[0, 0]) + self.R
            K = (P @ self.H.T / S).ravel()
            x = x + K * (z[k] - x[0])
            P = (np.eye(3) - np.outer(K, self.H)) @ P
            self.x[k] = x
            self.P[k] = 0.5 * (P + P.T)
            if quiet[k]:
                self._quiet[k].append(x[2])
        return self.disturbance_B_rad_s2

    def quiet_mean_B_rad_s2(self) -> np.ndarray | None:
        """Mean disturbance estimate over the quiet window of each channel, or None until full."""
        if any(len(q) < self.cfg.window_ticks for q in self._quiet):
            full = [len(q) == self.cfg.window_ticks for q in self._quiet]
            if not any(full):
                return None
        n = self.cfg.window_ticks
        return np.array([np.mean(q) if len(q) == n else 0.0 for q in self._quiet])

    def leak_test(self, candidates: np.ndarray | None = None) -> LeakReport | None:
        """Seed 002's decision: mean quiet disturbance above the threshold names a thruster.

        ``candidates`` (N,) bool restricts the thrusters that may be named (available ones).
        """
        m = self.quiet_mean_B_rad_s2()
        if m is None or self.e_B is None:
            return None
        if np.max(np.abs(m)) <= self.cfg.leak_threshold_rad_s2:
            return None
        proj = self.e_B @ m
        if candidates is not None:
            proj = np.where(candidates, proj, -np.inf)
        i = int(np.argmax(proj))
        if not np.isfinite(proj[i]) or proj[i] <= 0.0:
            return None
        return LeakReport(thruster=i, mean_disturbance_B_rad_s2=m, projection_rad_s2=float(proj[i]))
