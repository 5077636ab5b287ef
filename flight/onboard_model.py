"""Onboard model: one-tick prediction of the rigid-body rate (seed 003 eq. 9; seed 000 eq. 2).

    w_calc[n+1] = w[n] - J^-1 (w[n] x (J w[n] + H[n])) h + sum_j mu_j tau_E,j[n]
                  - J^-1 dH[n] + J^-1 M_gg[n] h

``mu_j = J^-1 (r_j x F_j)`` (rad/s^2, ``VehicleArrays.mu_B_rad_s2``); ``tau_E,j[n]`` is the part
of thruster j's *equivalent rectangular burn* that falls inside the prediction interval
``[s_n, s_n+1]`` between two gyro samples. A pulse commanded in tick n opens the valve at
``t_n + latency`` for ``tau`` and, by seed 004's equal-area definition of the lags, is worth a
rectangle ``[t_n + latency + tau_on, t_n + latency + tau + tau_off]`` of full thrust
(``tau_E = tau - tau_on + tau_off = tau - 3 ms``). Whatever part of that rectangle lies after
the next sample belongs to the next tick's prediction (pulses that cross a tick boundary).
A thruster commanded the full tick (200 ms: continuous) and again in the next tick stays lit:
no second on-lag. The latency used is the nominal command latency plus the gyro latency
(a sample taken ``g`` before the tick start sees commands ``g`` later).

Two variants (``flight.onboard_model.predict_from``):

* ``measured`` (seed 000 eq. 2, the default): predict from the observer's rigid-rate estimate
  of the previous tick. The residual then holds only the mismatch of the last tick: a fault
  shows on exactly the ticks it acts (what seed 000 tables 1-2 assume: rho_off grows only on
  ticks without the command, rho_on only on ticks with it), and thrust-scale errors or an
  unmodelled constant torque never accumulate. This is why it is the default.
* ``model`` (seed 003 eq. 9): integrate the model's own state. The residual integrates every
  model error since the last re-synchronisation; after a one-tick fault it stays non-zero on
  all later ticks and is credited to whatever is (not) commanded then. ``resync`` sets the state
  (at start and after an FDIR reconfiguration).

Gyro samples: a ``rate`` gyro gives the instantaneous rate at the sample; an ``integrating`` gyro
(seed 002) gives the mean rate over the last tick (angle increment / h). For the latter the
model predicts the change of the mean rate (``sample_kind="mean"``).

Arrays: N thrusters; ``tau_cmd_s`` (N,) commanded on-times of one tick; ``burn_s`` (N,) the
equivalent burn inside the prediction interval; vectors (3,) in body axes B.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.quaternion import cross3
from common.vehicle import VehicleArrays, VehicleCfg

# Tolerance on "the command is the full tick" (continuous firing), s.
_FULL_TICK_TOL_S = 1e-6


@dataclass(frozen=True)
class Prediction:
    """One tick of the onboard model.

    ``omega_calc_B_rad_s`` (3,): predicted rate at the next sample; ``dw_thr_B_rad_s`` (3,): the
    thrusters' share of it; ``burn_s`` (N,): equivalent burn of each thruster inside the interval;
    ``active`` (N,) bool: the thruster was commanded in the tick that governs the interval
    (the "commanded" flag of seed 000 tables 1-2: tau[n-1] != 0). The tail of the previous
    tick's pulse that reaches into the interval does not make it "commanded": in such a tick a
    stuck-on thruster shows almost its whole effect, so the tick is evidence about "stuck on"
    and belongs to rho_off; ``burning`` (N,) bool: any thrust of the thruster expected inside
    the interval, tails included (the Kalman leak test uses only intervals with none);
    ``dw_thr_abs_rad_s``: sum of the thrusters' rate-change magnitudes ``sum_j |mu_j| eff_j``
    (the scale of the detector's relative dead zone); ``dangle_thr_B_rad`` (3,): the
    thrusters' share of the attitude increment over the interval (used by the Kalman filter,
    seed 002); ``eff_s`` (N,): the equivalent burn that multiplies ``mu_j`` in the sample's
    prediction (``burn_s`` for a rate gyro; the change of the mean burn for an integrating one),
    before the effectiveness scale; ``lead_s`` (3,): per channel, the time from the centroid of
    the thrusters' burns in the interval to its end, weighted by each one's share ``|mu_j,c|
    burn_j`` (the observer's input timing; 0 where nothing burns); ``deff_dlat`` (N,): the
    change of ``eff_s`` per second of extra command latency (only with ``learn_latency``).
    """

    omega_calc_B_rad_s: np.ndarray
    dw_thr_B_rad_s: np.ndarray
    burn_s: np.ndarray
    active: np.ndarray
    dangle_thr_B_rad: np.ndarray
    burning: np.ndarray
    dw_thr_abs_rad_s: float = 0.0
    eff_s: np.ndarray | None = None
    deff_dlat: np.ndarray | None = None
    lead_s: np.ndarray | None = None


# Latency step of the shadow timeline (finite difference of the burns), s.
_LATENCY_STEP_S = 0.002


class BurnTimeline:
    """Equivalent rectangular burns of every thruster, carried across tick boundaries.

    Times are seconds from the current prediction interval's start (the sample ``s_n``).
    ``advance(tau_cmd_s)`` takes the commands of tick n and returns, for the interval
    ``[0, h]``, the burn (N,) and the angle weight ``int (h - t) dt`` over the burn (N,);
    the parts after ``h`` are kept for the next call (seed 004 lags, docs/design.md section 3).
    """

    def __init__(self, n: int, tick_s: float, latency_s: float, on_lag_s: float,
                 off_lag_s: float) -> None:
        self.n = n
        self.h = float(tick_s)
        self.latency_s = float(latency_s)
        self.on_lag_s = float(on_lag_s)
        self.off_lag_s = float(off_lag_s)
        self.reset()

    def reset(self) -> None:
        # Per thruster, list of [start, end] burns not yet consumed, in the current frame.
        self._burns: list[list[list[float]]] = [[] for _ in range(self.n)]
        self._lit = np.zeros(self.n, dtype=bool)  # valve open at the end of the last command

    def carried_burn(self, t0_s: float, t1_s: float) -> np.ndarray:
        """(N,) equivalent burn, s, of the commands already given that falls in
        ``[t0_s, t1_s]`` of the current tick (times from its start)."""
        out = np.zeros(self.n)
        for j, burns in enumerate(self._burns):
            for a, b in burns:
                out[j] += max(0.0, min(b, t1_s) - max(a, t0_s))
        return out

    def advance(self, tau_cmd_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, lat = self.h, self.latency_s
        tau = np.clip(np.asarray(tau_cmd_s, dtype=float), 0.0, h)
        burn = np.zeros(self.n)
        angle = np.zeros(self.n)
        for j in range(self.n):
            burns = self._burns[j]
            if tau[j] > 0.0:
                if self._lit[j] and burns:
                    # Still lit from a full-tick command: extend the running burn (no new rise).
                    burns[-1][1] = lat + tau[j] + self.off_lag_s
                else:
                    burns.append([lat + self.on_lag_s, lat + tau[j] + self.off_lag_s])
            self._lit[j] = tau[j] >= h - _FULL_TICK_TOL_S
            keep: list[list[float]] = []
            for a, b in burns:
                lo, hi = max(a, 0.0), min(b, h)
                if hi > lo:
                    burn[j] += hi - lo
                    angle[j] += 0.5 * ((h - lo) ** 2 - (h - hi) ** 2)
                if b > h:
                    keep.append([max(a, h) - h, b - h])
            self._burns[j] = keep
        return burn, angle


class OnboardModel:
    """One-tick rate prediction (seed 003 eq. 9, seed 000 eq. 2) for one vehicle.

    ``predict(omega_B_rad_s, tau_cmd_s, vertical_B=None, t_s=0.0)`` is called once per tick with
    the commands of that tick (in force until the next sample) and returns a ``Prediction`` for
    the next sample. ``omega_B_rad_s`` is the observer's rigid estimate at this sample (used when
    ``predict_from == "measured"``; the ``model`` variant uses its own state instead).
    ``vertical_B`` (3,) is the local vertical in body axes for the gravity-gradient torque
    ``M_gg = 3 w0^2 (j x J j)``; without it the term is left out.
    """

    def __init__(self, vehicle: VehicleCfg, predict_from: str | None = None,
                 command_latency_ms: float | None = None, sample_kind: str | None = None) -> None:
        cfg = vehicle.flight.onboard_model
        arr = VehicleArrays.from_vehicle(vehicle)
        self.arrays = arr
        self.h = float(vehicle.timing.tick_s)
        self.predict_from = predict_from or cfg.predict_from
        if self.predict_from not in ("measured", "model"):
            raise ValueError(
                f"predict_from: expected 'measured' or 'model', got {self.predict_from!r}")
        lat_ms = cfg.command_latency_ms if command_latency_ms is None else command_latency_ms
        self.latency_s = (lat_ms + vehicle.gyro.latency_ms) / 1000.0
        default_kind = "mean" if vehicle.gyro.kind == "integrating" else "instant"
        self.sample_kind = sample_kind or default_kind
        prof = vehicle.thrust_profile
        self.timeline = BurnTimeline(len(arr.names), self.h, self.latency_s,
                                     prof.on_lag_ms / 1000.0, prof.off_lag_ms / 1000.0)
        self.nominal_latency_s = self.latency_s
        # Shadow timeline _LATENCY_STEP_S later (``learn_latency``): the sensitivity of each
        # thruster's equivalent burn to the command latency, for the effectiveness learning.
        self.shadow: BurnTimeline | None = None
        self._prev_shadow = (np.zeros(len(arr.names)), np.zeros(len(arr.names)))
        self.mu_B_rad_s2 = arr.mu_B_rad_s2          # (N, 3)
        self.J = arr.J_B_kg_m2
        self.J_inv = arr.J_inv_B
        self.w0_rad_s = vehicle.orbit.rate_rad_s if vehicle.orbit.gravity_gradient else 0.0
        cmg = vehicle.cmg
        self.H0_B_Nms = np.array(cmg.h_B_Nms if cmg else (0.0, 0.0, 0.0), dtype=float)
        self.Hdot_B_Nm = np.array(cmg.h_dot_B_Nm if cmg else (0.0, 0.0, 0.0), dtype=float)
        self.omega_model_B_rad_s: np.ndarray | None = None
        self._prev_burn = np.zeros(len(arr.names))
        self._prev_angle = np.zeros(len(arr.names))

    def learn_latency(self) -> None:
        """Keep a shadow timeline so that every prediction carries ``deff_dlat``."""
        t = self.timeline
        self.shadow = BurnTimeline(t.n, t.h, t.latency_s + _LATENCY_STEP_S, t.on_lag_s,
                                   t.off_lag_s)

    def set_latency_offset(self, offset_s: float) -> None:
        """Commands from now on land ``nominal + offset_s`` after the sample (learnt)."""
        self.latency_s = max(0.0, self.nominal_latency_s + float(offset_s))
        self.timeline.latency_s = self.latency_s
        if self.shadow is not None:
            self.shadow.latency_s = self.latency_s + _LATENCY_STEP_S

    def reset(self) -> None:
        self.timeline.reset()
        if self.shadow is not None:
            self.shadow.reset()
            self._prev_shadow = (np.zeros(self.timeline.n), np.zeros(self.timeline.n))
        self.omega_model_B_rad_s = None
        self._prev_burn[:] = 0.0
        self._prev_angle[:] = 0.0

    def resync(self, omega_B_rad_s: np.ndarray) -> None:
        """Set the ``model`` variant's own state (start, FDIR reconfiguration)."""
        self.omega_model_B_rad_s = np.array(omega_B_rad_s, dtype=float)

    def cmg_momentum(self, t_s: float) -> np.ndarray:
        """CMG momentum H(t) = H0 + Hdot t in body axes, N m s."""
        return self.H0_B_Nms + self.Hdot_B_Nm * t_s

    def free_increment(self, omega_B_rad_s: np.ndarray, vertical_B: np.ndarray | None = None,
                       t_s: float = 0.0) -> np.ndarray:
        """Non-thruster part of eq. 9 over one tick (3,): gyroscopic, CMG, gravity gradient."""
        w = np.asarray(omega_B_rad_s, dtype=float)
        H = self.cmg_momentum(t_s)
        dw = -self.J_inv @ cross3(w, self.J @ w + H) * self.h
        dw -= self.J_inv @ (self.Hdot_B_Nm * self.h)
        if vertical_B is not None and self.w0_rad_s > 0.0:
            j = np.asarray(vertical_B, dtype=float)
            M_gg = 3.0 * self.w0_rad_s**2 * cross3(j, self.J @ j)
            dw += self.J_inv @ M_gg * self.h
        return dw

    def predict(self, omega_B_rad_s: np.ndarray, tau_cmd_s: np.ndarray,
                vertical_B: np.ndarray | None = None, t_s: float = 0.0,
                scale: np.ndarray | None = None) -> Prediction:
        """``scale`` (N,), optional: the learnt effectiveness of each thruster (its thrust over
        nominal, ``flight.detector.Effectiveness``); the thrusters' share is
        ``sum_j scale_j mu_j eff_j``."""
        burn, angle = self.timeline.advance(tau_cmd_s)
        deff = None
        if self.shadow is not None:
            sb, sa = self.shadow.advance(tau_cmd_s)
            if self.sample_kind == "mean":
                s_eff = self._prev_shadow[0] + (sa - self._prev_shadow[1]) / self.h
                p_eff = self._prev_burn + (angle - self._prev_angle) / self.h
            else:
                s_eff, p_eff = sb, burn
            deff = (s_eff - p_eff) / _LATENCY_STEP_S
            self._prev_shadow = (sb, sa)
        if self.predict_from == "model":
            if self.omega_model_B_rad_s is None:
                self.omega_model_B_rad_s = np.array(omega_B_rad_s, dtype=float)
            base = self.omega_model_B_rad_s
        else:
            base = np.asarray(omega_B_rad_s, dtype=float)
        if self.sample_kind == "mean":
            # Mean rate over [s_n, s_n+1] minus mean over [s_n-1, s_n]:
            # burn(n-1) + (angle(n) - angle(n-1)) / h per thruster (times mu_j).
            eff = self._prev_burn + (angle - self._prev_angle) / self.h
        else:
            eff = burn
        k = np.ones(len(eff)) if scale is None else np.asarray(scale, dtype=float)
        dw_thr = self.mu_B_rad_s2.T @ (k * eff)
        # angle_j = int (h - t) dt over the burn, so angle_j / burn_j is its lead to the sample.
        w_abs = np.abs(self.mu_B_rad_s2).T
        den = w_abs @ (k * burn)
        lead = np.where(den > 0.0, (w_abs @ (k * angle)) / np.where(den > 0.0, den, 1.0), 0.0)
        omega_calc = base + self.free_increment(base, vertical_B, t_s) + dw_thr
        if self.predict_from == "model":
            self.omega_model_B_rad_s = omega_calc.copy()
        self._prev_burn, self._prev_angle = burn, angle
        return Prediction(
            omega_calc_B_rad_s=omega_calc,
            dw_thr_B_rad_s=dw_thr,
            burn_s=burn,
            active=np.asarray(tau_cmd_s, dtype=float) > 0.0,
            dangle_thr_B_rad=self.mu_B_rad_s2.T @ (k * angle),
            burning=eff > 0.0,
            dw_thr_abs_rad_s=float(np.linalg.norm(self.mu_B_rad_s2, axis=1) @ np.abs(k * eff)),
            eff_s=eff,
            lead_s=lead,
            deff_dlat=deff,
        )
