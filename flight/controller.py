"""Required rate change per channel: seed 004 phase plane (and the seed 002 law ``s = phi + k w``).

Seed 004 section 2. Channels x, y, z = roll, yaw, pitch (body axes). Per channel the phase plane
has the angle error ``nu_i ~ 2 N_i`` (``N = R~ (x) Lambda``, ``N0 >= 0``) as abscissa and the rate
error ``e_i = w_i - w_b,i`` (body rate minus the target frame's rate, both inertial, in body
axes) as ordinate. The dead zone is the band ``|e - e_ref(nu)| <= dw_dz`` (``dw_dz`` = 0.12 deg/s)
around a switching centre line

    e_ref(nu) = -sign(nu) * min(s (|nu| - nu_dz)+, sqrt(2 eps |nu|), w_max)

with ``nu_dz`` the angle dead band and ``s = dw_dz / nu_dz`` (chosen: the upper edge of the band
reaches zero rate at ``2 nu_dz``); the seed draws the lines but gives no slope. Inside the band no
thruster is needed. The bounds given to the allocator are the vertical distances from the state
to the band (seed 004 section 3: ``dw_down <= dw <= dw_up``):

* inside the outer band: ``[e_ref - dw_dz - e, e_ref + dw_dz - e]`` (contains 0: nothing fires
  for this channel, but firings for other channels must not push it out);
* outside: the same towards the inner band of half-width ``dw_dz - hysteresis`` (seed 004's
  ``dw_cl / k_a``): the LP brings the state past the boundary, so that a state that lands just
  inside after a firing is not fired at again (hysteresis).

Large errors (seed 004 section 2):

* total rotation angle ``theta = 2 acos N0`` above ``large_angle_deg`` (15 deg): turn about the
  Euler axis ``n = N_vec / |N_vec|`` at
  ``w_turn = min(w_max, sqrt(2 eps_n theta), s (theta - nu_dz))`` (3.5 deg/s cap):
  ``e_ref = -w_turn * n`` in all channels. ``eps_n = min_i eps_i / |n_i|`` is the acceleration
  about the axis that no channel exceeds;
* total below 15 deg but ``|nu_i|`` above ``curve_angle_deg`` (6.1 deg): channel i follows the
  constant-acceleration switching curve ``w^2 = 2 eps_i |nu|`` (eq. 2.2), capped by the same
  ramp as below 6.1 deg: ``e_ref = -sign(nu) min(sqrt(2 eps_i |nu|), s (|nu| - nu_dz), w_max)``.

So ``e_ref`` is continuous across 6.1 deg and, for an error about one body axis, across 15 deg:
where the ramp is still below the curve at 6.1 deg (a vehicle with a small dead band for its
authority, e.g. ``iss_rs``), the state follows the ramp until it meets the curve, instead of a
jump of the commanded rate of several dead bands; and the turn about a body axis uses that
channel's acceleration, as the curve does (the weakest channel would make the craft speed up as
the error falls through 15 deg).

``eps_i`` is :data:`CURVE_ACCEL_FRACTION` of channel i's weaker-sign authority (sum of the
thrusters' angular accelerations of one sign on that axis), so the curve can be followed with
margin.

Seed 002 law (``law: s_law``, the kalman_cube vehicle): ``s_i = phi_i + k w_i`` with a dead zone
``|s| <= s_dz``; beyond it the channel's thrusters fire for the whole tick: ``dw_up = -a_i``
(``s > s_dz``) or ``dw_down = +a_i`` (``s < -s_dz``), ``a_i`` the full-tick rate change of that
sign, the other side unbounded; a channel inside keeps ``|dw| <= dw_dz``.

Pure: the attitude, rates and configuration are arguments; no state between ticks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.vehicle import ControllerCfg, VehicleArrays, VehicleCfg
from flight.attitude import error_quaternion, orbit_rate_B_rad_s, rotation_angle

CURVE_ACCEL_FRACTION = 0.5  # chosen: the seed gives no eps; half the weaker-sign authority

INSIDE, ABOVE, BELOW = "inside", "above", "below"


@dataclass(frozen=True)
class RateDemand:
    """Controller output for one tick.

    ``dw_down_B_rad_s``, ``dw_up_B_rad_s`` (3,) bounds on the rate change (may be infinite for
    the s-law); ``mode``: ``phase_plane``, ``curve`` (some channel on the switching curve),
    ``euler_turn`` or ``s_law``; ``region`` (3,) per channel ``inside``, ``above`` (rate too high:
    fire negative) or ``below``; ``nu_B_rad`` (3,) angle errors; ``rate_err_B_rad_s`` (3,) rate
    errors; ``e_ref_B_rad_s`` (3,) the switching centre line; ``total_angle_rad``.
    """

    dw_down_B_rad_s: np.ndarray
    dw_up_B_rad_s: np.ndarray
    mode: str
    region: tuple[str, str, str]
    nu_B_rad: np.ndarray
    rate_err_B_rad_s: np.ndarray
    e_ref_B_rad_s: np.ndarray
    total_angle_rad: float

    @property
    def fire(self) -> bool:
        """True when some channel needs a firing (zero rate change is outside the bounds)."""
        return bool(np.any(self.dw_down_B_rad_s > 0.0) or np.any(self.dw_up_B_rad_s < 0.0))


def channel_authority_rad_s2(mu_B_rad_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel authority (3,) for positive and negative acceleration, rad/s^2.

    Sum over thrusters of the positive (resp. negative) parts of ``mu`` (N, 3) on each axis.
    """
    mu = np.asarray(mu_B_rad_s2, dtype=float)
    return np.clip(mu, 0.0, None).sum(axis=0), np.clip(-mu, 0.0, None).sum(axis=0)


class Controller:
    """Seed 004 phase-plane controller (or the seed 002 s-law) for one vehicle.

    ``Controller(vehicle)`` or ``Controller(vehicle, eps_B_rad_s2=...)`` to override the curve
    accelerations (3,). :meth:`demand` is pure.
    """

    def __init__(
        self,
        vehicle: VehicleCfg,
        arrays: VehicleArrays | None = None,
        eps_B_rad_s2: np.ndarray | None = None,
    ) -> None:
        self.cfg: ControllerCfg = vehicle.flight.controller
        ar = arrays if arrays is not None else VehicleArrays.from_vehicle(vehicle)
        pos, neg = channel_authority_rad_s2(ar.mu_B_rad_s2)
        self.authority_pos_rad_s2 = pos
        self.authority_neg_rad_s2 = neg
        if eps_B_rad_s2 is None:
            eps_B_rad_s2 = CURVE_ACCEL_FRACTION * np.minimum(pos, neg)
        self.eps_B_rad_s2 = np.asarray(eps_B_rad_s2, dtype=float)
        self.w0_rad_s = float(vehicle.orbit.rate_rad_s)
        self.tick_s = float(vehicle.timing.tick_s)
        lag_ms = vehicle.thrust_profile.on_lag_ms - vehicle.thrust_profile.off_lag_ms
        self.full_tick_s = self.tick_s - lag_ms / 1000.0
        c = self.cfg
        self.dw_dz = math.radians(c.rate_deadband_deg_s)
        self.dw_in = max(self.dw_dz - math.radians(c.hysteresis_deg_s), 0.0)
        self.nu_dz = math.radians(c.angle_deadband_deg)
        self.slope_1_s = self.dw_dz / self.nu_dz
        self.large_rad = math.radians(c.large_angle_deg)
        self.curve_rad = math.radians(c.curve_angle_deg)
        self.w_max = math.radians(c.max_rate_deg_s)
        self.s_gain_s = float(c.s_gain_s)
        self.s_dz = math.radians(c.s_deadband_deg)

    # ------------------------------------------------------------------ shared pieces

    def errors(
        self, Lambda_BO: np.ndarray, omega_BI_B_rad_s: np.ndarray, R_TO: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """``(nu (3,), e (3,), theta, N (4,))``: seed 004 angle errors, rate errors, total angle.

        ``Lambda_BO`` (4,) body relative to the orbit frame; ``omega_BI_B_rad_s`` (3,) the
        estimated inertial body rate; ``R_TO`` (4,) target relative to the orbit frame
        (identity if None). The target turns with the orbit frame, so ``w_b = -w0 z'`` in body axes.
        """
        R = np.array([1.0, 0.0, 0.0, 0.0]) if R_TO is None else np.asarray(R_TO, dtype=float)
        N = error_quaternion(R, np.asarray(Lambda_BO, dtype=float))
        nu = 2.0 * N[1:]
        w_b = orbit_rate_B_rad_s(Lambda_BO, self.w0_rad_s)
        e = np.asarray(omega_BI_B_rad_s, dtype=float) - w_b
        return nu, e, rotation_angle(N), N

    def centre_line(self, nu_rad: float, eps_rad_s2: float) -> float:
        """Small-angle switching centre line ``e_ref(nu)`` (module docstring), rad/s."""
        a = abs(nu_rad)
        ramp = self.slope_1_s * max(a - self.nu_dz, 0.0)
        curve = math.sqrt(2.0 * eps_rad_s2 * a)
        return -math.copysign(min(ramp, curve, self.w_max), nu_rad)

    def axis_accel(self, axis_B: np.ndarray) -> float:
        """``eps_n = min_i eps_i / |n_i|``: the angular acceleration about unit axis ``n`` (3,)
        that keeps every channel within its curve acceleration, rad/s^2."""
        n = np.abs(np.asarray(axis_B, dtype=float))
        used = n > 1e-12
        return float((self.eps_B_rad_s2[used] / n[used]).min())

    def _bounds(self, e: np.ndarray, e_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple]:
        dev = e - e_ref
        out_above = dev > self.dw_dz
        out_below = dev < -self.dw_dz
        outside = out_above | out_below
        half = np.where(outside, self.dw_in, self.dw_dz)
        lo = e_ref - half - e
        hi = e_ref + half - e
        region = tuple(
            ABOVE if a else (BELOW if b else INSIDE)
            for a, b in zip(out_above, out_below, strict=True)
        )
        return lo, hi, region

    # ------------------------------------------------------------------ laws

    def demand(
        self, Lambda_BO: np.ndarray, omega_BI_B_rad_s: np.ndarray, R_TO: np.ndarray | None = None
    ) -> RateDemand:
        """One tick of the configured law (``phase_plane`` or ``s_law``)."""
        if self.cfg.law == "s_law":
            return self.demand_s_law(Lambda_BO, omega_BI_B_rad_s, R_TO)
        return self.demand_phase_plane(Lambda_BO, omega_BI_B_rad_s, R_TO)

    def demand_phase_plane(
        self, Lambda_BO: np.ndarray, omega_BI_B_rad_s: np.ndarray, R_TO: np.ndarray | None = None
    ) -> RateDemand:
        """Seed 004 section 2: phase plane, switching curve and Euler-axis turn."""
        nu, e, theta, N = self.errors(Lambda_BO, omega_BI_B_rad_s, R_TO)
        return self.demand_from_errors(nu, e, theta, N[1:])

    def demand_from_errors(
        self,
        nu_B_rad: np.ndarray,
        rate_err_B_rad_s: np.ndarray,
        total_angle_rad: float | None = None,
        axis_B: np.ndarray | None = None,
    ) -> RateDemand:
        """Phase-plane law from the errors directly (tests, single-axis use).

        ``total_angle_rad`` defaults to ``|nu|``; ``axis_B`` (3,) the Euler axis direction
        (defaults to ``nu``).
        """
        nu = np.asarray(nu_B_rad, dtype=float)
        e = np.asarray(rate_err_B_rad_s, dtype=float)
        theta = float(np.linalg.norm(nu)) if total_angle_rad is None else float(total_angle_rad)
        if theta > self.large_rad:
            ax = nu if axis_B is None else np.asarray(axis_B, dtype=float)
            ax = ax / np.linalg.norm(ax)
            w_turn = min(self.w_max, math.sqrt(2.0 * self.axis_accel(ax) * theta),
                         self.slope_1_s * max(theta - self.nu_dz, 0.0))
            e_ref = -w_turn * ax
            mode = "euler_turn"
        else:
            e_ref = np.empty(3)
            on_curve = False
            for i in range(3):
                a = abs(nu[i])
                on_curve |= a > self.curve_rad
                e_ref[i] = self.centre_line(nu[i], self.eps_B_rad_s2[i])
            mode = "curve" if on_curve else "phase_plane"
        lo, hi, region = self._bounds(e, e_ref)
        return RateDemand(
            dw_down_B_rad_s=lo, dw_up_B_rad_s=hi, mode=mode, region=region,
            nu_B_rad=nu, rate_err_B_rad_s=e, e_ref_B_rad_s=e_ref, total_angle_rad=theta,
        )

    def demand_s_law(
        self, Lambda_BO: np.ndarray, omega_BI_B_rad_s: np.ndarray, R_TO: np.ndarray | None = None
    ) -> RateDemand:
        """Seed 002: ``s = phi + k w`` with a dead zone; a full-tick firing beyond it."""
        nu, e, theta, _ = self.errors(Lambda_BO, omega_BI_B_rad_s, R_TO)
        return self.s_law_from_errors(nu, e, theta)

    def s_law_from_errors(
        self, nu_B_rad: np.ndarray, rate_err_B_rad_s: np.ndarray, total_angle_rad: float = 0.0
    ) -> RateDemand:
        """Seed 002 law from the errors (module docstring)."""
        nu = np.asarray(nu_B_rad, dtype=float)
        e = np.asarray(rate_err_B_rad_s, dtype=float)
        s = nu + self.s_gain_s * e
        full_pos = self.authority_pos_rad_s2 * self.full_tick_s
        full_neg = self.authority_neg_rad_s2 * self.full_tick_s
        lo = np.full(3, -self.dw_dz)
        hi = np.full(3, self.dw_dz)
        region = []
        for i in range(3):
            if s[i] > self.s_dz:
                lo[i], hi[i] = -np.inf, -full_neg[i]
                region.append(ABOVE)
            elif s[i] < -self.s_dz:
                lo[i], hi[i] = full_pos[i], np.inf
                region.append(BELOW)
            else:
                region.append(INSIDE)
        return RateDemand(
            dw_down_B_rad_s=lo, dw_up_B_rad_s=hi, mode="s_law", region=tuple(region),
            nu_B_rad=nu, rate_err_B_rad_s=e, e_ref_B_rad_s=-nu / self.s_gain_s,
            total_angle_rad=total_angle_rad,
        )
