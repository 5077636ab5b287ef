"""Elastic modes of the structure (seed 003 eq. 2) and their rate at the gyro (seed 003 eq. 3).

For each mode i (seed 003 eq. 2)::

    q_i'' + 2 delta lambda_i q_i' + W_i^2 q_i = sum_j (f_i(r_j) . F_j + phi_i(r_j) . M_j)

with ``lambda_i`` the natural frequency in Hz (``freq_hz``), ``W_i = 2 pi lambda_i`` and
``delta`` the logarithmic decrement (``log_decrement``). In this parametrisation the envelope
is ``exp(-delta lambda_i t)``: over one undamped period ``1 / lambda_i`` the amplitude falls by
``exp(-delta)``, so delta is the decrement per undamped period; the damping ratio is
``zeta = delta / (2 pi)`` and the ringing frequency ``W_d = W sqrt(1 - zeta^2)``. (Measured over
one *damped* period the decrement is ``delta / sqrt(1 - zeta^2)``, a hair larger.)

``F_j = P_j d_j`` is the thruster's force and ``M_j = r_j x F_j`` its moment about the centre
of mass, as in the seed's onboard model (``m_j = J^-1 M_j``). The right-hand side is linear in
the scalar thrusts, so it is ``u_i = sum_j b_ij P_j(t)`` with ``b_ij = f_ij . d_j +
phi_ij . (r_j x d_j)`` per newton (``influence``, shape (N, n_modes)).

Integration is exact for a forcing constant over the step (the exact mean thrust of the step):
``x(t+h) = Phi(h) x(t) + Gamma(h) u`` with the closed-form state-transition matrix of the damped
oscillator (checked against ``scipy.linalg.expm`` in the tests). This is the plant's own
discretisation; the onboard model's ``A_i, B_i`` recursion (seed 003 eq. 6) is the flight's.

The gyro sees ``w + sum_i phi_i(r_gyro) q_i'`` (seed 003 eq. 3; ``gyro_phi``).
"""

from __future__ import annotations

import math

import numpy as np

from common.vehicle import FlexModeCfg


def influence_matrix(modes: list[FlexModeCfg], names: tuple[str, ...], r_B_m: np.ndarray,
                     d_B: np.ndarray) -> np.ndarray:
    """``b_ij`` (N, n_modes): generalised force of mode i per newton of thruster j."""
    out = np.zeros((len(names), len(modes)))
    moment_arm = np.cross(r_B_m, d_B)  # M_j / P_j
    for i, m in enumerate(modes):
        for j, name in enumerate(names):
            shape = m.thrusters.get(name, m.default)
            out[j, i] = float(np.dot(shape.f, d_B[j]) + np.dot(shape.phi, moment_arm[j]))
    return out


def transition(freq_hz: float, log_decrement: float, h_s: float
               ) -> tuple[tuple[float, float, float, float], tuple[float, float]]:
    """Exact ``Phi(h)`` (row-major 2x2) and ``Gamma(h)`` (2,) of one mode, constant forcing.

    With ``sigma = delta lambda``, ``W_d = sqrt(W^2 - sigma^2)``, ``e = exp(-sigma h)``::

        Phi = e [[cos + sigma/W_d sin, sin/W_d], [-W^2/W_d sin, cos - sigma/W_d sin]]
        Gamma = [(1 - Phi_11) / W^2, Phi_12]        (x_p = [u / W^2, 0] is the rest point)
    """
    w = 2.0 * math.pi * freq_hz
    sigma = log_decrement * freq_hz
    if sigma >= w:
        raise ValueError(f"mode at {freq_hz} Hz with decrement {log_decrement} is not oscillatory")
    wd = math.sqrt(w * w - sigma * sigma)
    e = math.exp(-sigma * h_s)
    c, s = math.cos(wd * h_s), math.sin(wd * h_s)
    p11 = e * (c + sigma / wd * s)
    p12 = e * s / wd
    p21 = -e * w * w / wd * s
    p22 = e * (c - sigma / wd * s)
    return (p11, p12, p21, p22), ((1.0 - p11) / (w * w), p12)


class FlexModes:
    """Modal state ``q`` (n,), ``q_dot`` (n,) with exact stepping (module doc)."""

    def __init__(self, modes: list[FlexModeCfg], influence: np.ndarray) -> None:
        self.modes = list(modes)
        self.n = len(self.modes)
        self.influence = np.asarray(influence, dtype=float)
        self.gyro_phi = np.array([m.gyro_phi for m in self.modes], dtype=float).reshape(self.n, 3)
        self.q = [0.0] * self.n
        self.qd = [0.0] * self.n
        # Step length -> (per mode ``(Phi, Gamma)``, the same flattened to 6-tuples).
        self._cache: dict[float, tuple[list, tuple]] = {}

    def _mats(self, h_s: float) -> list[tuple[tuple[float, ...], tuple[float, float]]]:
        return self._entry(h_s)[0]

    def flat_mats(self, h_s: float) -> tuple[tuple[float, float, float, float, float, float], ...]:
        """``_mats(h_s)`` flattened per mode: ``(p11, p12, p21, p22, g1, g2)``."""
        return self._entry(h_s)[1]

    def _entry(self, h_s: float) -> tuple[list, tuple]:
        """Both forms of the transitions for a step of ``h_s`` (cached by step length)."""
        key = round(h_s, 12)
        m = self._cache.get(key)
        if m is None:
            mats = [transition(md.freq_hz, md.log_decrement, h_s) for md in self.modes]
            m = (mats, tuple((*phi, *gam) for phi, gam in mats))
            if len(self._cache) > 64:  # odd step lengths (sample times): keep the cache small
                self._cache.clear()
            self._cache[key] = m
        return m

    def step(self, h_s: float, u: list[float] | np.ndarray) -> None:
        """Advance by ``h_s`` with the generalised forces ``u`` (n,) held constant."""
        mats = self._mats(h_s)
        q, qd = self.q, self.qd
        for i in range(self.n):
            (p11, p12, p21, p22), (g1, g2) = mats[i]
            ui = u[i]
            a, b = q[i], qd[i]
            q[i] = p11 * a + p12 * b + g1 * ui
            qd[i] = p21 * a + p22 * b + g2 * ui

    def gyro_rate_B(self) -> np.ndarray:
        """``sum_i phi_i(r_gyro) q_i'`` (3,) rad/s (seed 003 eq. 3)."""
        if self.n == 0:
            return np.zeros(3)
        return np.asarray(self.qd) @ self.gyro_phi

    def gyro_angle_B(self) -> np.ndarray:
        """``sum_i phi_i(r_gyro) q_i`` (3,) rad: the flex part of an integrating gyro's angle."""
        if self.n == 0:
            return np.zeros(3)
        return np.asarray(self.q) @ self.gyro_phi
