"""Vehicle models: every figure of a vehicle, validated once (the design, section 7).

Every figure of a vehicle lives in ``configs/vehicles/<name>.yaml`` (read by the shell,
``hil.config.load_vehicle``). Models forbid unknown keys and are frozen; nothing past the loader
sees a raw dict.

Frames and units: body axes B (x, y, z = roll, yaw, pitch channels as in seed 004), positions in
metres in the structural frame with the same axes (the centre of mass ``com_m`` is given in it),
forces in newtons, torques in N m, rates in rad/s unless the name says ``deg``.

``VehicleArrays`` (at the end) turns a vehicle into the numpy arrays both cores use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from common.schema import Forgetting, NonNegFloat, PosFloat, Vec3, _FieldError, _Model
from common.units import G0_M_S2

# --------------------------------------------------------------------------- vehicle: hardware


class ThrusterCfg(_Model):
    """One thruster. ``direction`` is the unit vector of the force it applies to the vehicle."""

    name: str = Field(min_length=1)
    position_m: Vec3
    direction: Vec3
    thrust_n: PosFloat
    isp_s: PosFloat = 290.0
    manifold: str

    @field_validator("direction")
    @classmethod
    def _unit(cls, v: Vec3) -> Vec3:
        n = math.sqrt(sum(c * c for c in v))
        if not 0.999 <= n <= 1.001:
            raise ValueError(f"a unit vector (norm 1 within 1e-3), norm is {n:.6g}")
        return v


class ThrustProfileCfg(_Model):
    """Non-rectangular thrust profile, seed 004 eq. (4.1), and its equal-area lags.

    Rise ``1 - exp(-k1 (t - T_R)^n1)`` after the electrical delay ``T_R``; decay
    ``exp(-k2 (t - t_off - T_R)^n2)``. ``k1`` and ``k2`` are calibrated by the plant so that the
    equal-area lags equal ``on_lag_ms`` and ``off_lag_ms`` (seed 004 section 4).
    """

    on_lag_ms: PosFloat = 30.0
    off_lag_ms: PosFloat = 27.0
    electrical_delay_ms: NonNegFloat = 10.0
    rise_exponent: PosFloat = 2.0
    decay_exponent: PosFloat = 1.0

    @model_validator(mode="after")
    def _lags_after_the_delay(self) -> ThrustProfileCfg:
        # Equal-area lags include the electrical delay: the profile cannot be calibrated below it.
        for name in ("on_lag_ms", "off_lag_ms"):
            if getattr(self, name) <= self.electrical_delay_ms:
                raise _FieldError(name, f"> electrical_delay_ms ({self.electrical_delay_ms:g})",
                                  getattr(self, name))
        return self


class TimingCfg(_Model):
    """Flight tick and PWM quantisation (seed 004; docs/design.md section 3)."""

    tick_s: PosFloat = 0.2
    pwm_quantum_ms: PosFloat = 10.0
    min_on_ms: NonNegFloat = 30.0
    min_off_ms: NonNegFloat = 30.0


class OrbitCfg(_Model):
    """Circular orbit for the gravity-gradient torque ``3 w0^2 (j x J j)`` (docs/design.md 5.1)."""

    rate_rad_s: NonNegFloat = 0.001162
    gravity_gradient: bool = True


class CmgCfg(_Model):
    """Optional CMG angular momentum in body axes, constant plus a constant rate of change."""

    h_B_Nms: Vec3 = (0.0, 0.0, 0.0)
    h_dot_B_Nm: Vec3 = (0.0, 0.0, 0.0)


class DisturbanceCfg(_Model):
    """External disturbance torque: constant part plus a seeded random part (per axis, 1-sigma).

    The random part is held constant over intervals of ``random_torque_hold_s`` on the global
    time grid (a fresh N(0, std^2) per interval), independent of the plant's integration step:
    the rate of a free body diffuses as ``std^2 hold t / I^2`` whatever ``step_s`` is.
    """

    constant_torque_B_Nm: Vec3 = (0.0, 0.0, 0.0)
    random_torque_std_Nm: NonNegFloat = 0.0
    # chosen: 10 ms, the plant's default step, so a vehicle's figure keeps the statistics it was
    # set with (before, the torque was drawn per integration step)
    random_torque_hold_s: PosFloat = 0.01


class ModeShapeCfg(_Model):
    """Linear ``f`` and angular ``phi`` mode shape at one point (seed 003 eq. 2)."""

    f: Vec3 = (0.0, 0.0, 0.0)
    phi: Vec3 = (0.0, 0.0, 0.0)


class FlexModeCfg(_Model):
    """One elastic mode (seed 003 eq. 2): ``q'' + 2 delta lambda q' + (2 pi lambda)^2 q = ...``.

    ``freq_hz`` is lambda_i, ``log_decrement`` is delta. ``gyro_phi`` is the angular mode shape at
    the gyro (its contribution to the measured rate is ``gyro_phi * q'``, seed 003 eq. 3).
    ``thrusters`` maps thruster names to their mode shapes; ``default`` applies to the others.
    """

    name: str
    freq_hz: PosFloat
    log_decrement: PosFloat
    gyro_phi: Vec3
    default: ModeShapeCfg = ModeShapeCfg()
    thrusters: dict[str, ModeShapeCfg] = {}

    @model_validator(mode="after")
    def _oscillating(self) -> FlexModeCfg:
        # delta >= 2 pi: the damping sigma = delta lambda reaches 2 pi lambda, no ringing at all.
        if self.log_decrement >= 2.0 * math.pi:
            raise _FieldError("log_decrement", "< 2 pi (an oscillating mode)", self.log_decrement)
        return self


class GyroCfg(_Model):
    """Angular-rate sensor (seed 003 eq. 3; seed 002 for the integrating variant)."""

    kind: Literal["rate", "integrating"] = "rate"
    noise_std_rad_s: NonNegFloat = 0.0
    bias_rad_s: Vec3 = (0.0, 0.0, 0.0)
    bias_walk_rad_s_sqrt_s: NonNegFloat = 0.0
    quantum_rad_s: NonNegFloat = 0.0
    rate_hz: PosFloat = 5.0
    latency_ms: NonNegFloat = 0.0


# --------------------------------------------------------------------------- vehicle: flight


class ControllerCfg(_Model):
    """Phase-plane controller (seed 004 section 2) or the seed 002 law ``s = phi + k w``."""

    law: Literal["phase_plane", "s_law"] = "phase_plane"
    rate_deadband_deg_s: PosFloat = 0.12
    angle_deadband_deg: PosFloat = 0.5
    hysteresis_deg_s: NonNegFloat = 0.02
    large_angle_deg: PosFloat = 15.0
    curve_angle_deg: PosFloat = 6.1
    max_rate_deg_s: PosFloat = 3.5
    # Seed 002 law: s = phi + k w with a dead zone on s.
    s_gain_s: PosFloat = 10.0
    s_deadband_deg: PosFloat = 0.5


class AllocatorCfg(_Model):
    """Minimum-fuel LP allocation (seed 004 section 3)."""

    # Dense bounded dual simplex with warm start: fastest here (bench/bench_allocator.py).
    solver: Literal["highs", "simplex", "linprog"] = "simplex"
    carry_remainder: bool = True
    # Roll pairs used in orbit-correction mode (seed 004: (15,19), (17,21), (16,20), (18,22)).
    roll_pairs: list[tuple[str, str]] = []


class OnboardModelCfg(_Model):
    """One-tick rate prediction (seed 003 eq. 9; seed 000 eq. 2)."""

    predict_from: Literal["measured", "model"] = "measured"
    command_latency_ms: NonNegFloat = 0.0


class ObserverCfg(_Model):
    """Self-tuning observer (seed 003 eqs. 7-8); ``rigid`` disables the flex estimate."""

    kind: Literal["adaptive", "rigid"] = "adaptive"
    gains: tuple[float, float, float, float, float, float, float, float] = (
        0.5, 0.5, 0.05, 0.05, 0.01, 0.01, 0.1, 0.1,
    )
    # one a-priori frequency of the dominant mode for all channels, or [x, y, z] per channel
    initial_freq_hz: PosFloat | tuple[PosFloat, PosFloat, PosFloat] = 0.2
    initial_damping: NonNegFloat = 0.01
    # |mu^| bound: the flex share at the gyro of a pulse's rate change (seed 003 eq. 8)
    mu_bound: PosFloat = 5.0
    # The identified frequency stays within [lo, hi] times the a-priori one (and under 0.4 /
    # tick): how well the vehicle's modes are known. The default [1/4, 4] lets a slow drift
    # of the rigid estimate be taken for a mode at the band's floor.
    freq_band: tuple[PosFloat, PosFloat] = (0.25, 4.0)
    # How well the mode frequency is known before flight, 1 sigma, a fraction of
    # initial_freq_hz (None: not modelled). Given, the observer also fits the frequency by
    # least squares on the free ringing (three tick intervals in a row with no thrust on the
    # channel: the flex increments follow z(n+1) = A z(n) - B z(n-1), a constant beside them
    # for a leak), takes the fit once it is known to a third of the prior, and reports the
    # flex prediction's uncertainty (flight/observer.py, "Frequency fitted on the free
    # ringing"; detector.flex_freq_dead_zone widens the dead zone by it).
    freq_prior_sigma: PosFloat | None = None

    @model_validator(mode="after")
    def _band_holds_the_prior(self) -> ObserverCfg:
        lo, hi = self.freq_band
        if not lo < 1.0 < hi:
            raise _FieldError("freq_band", "[lo, hi] with lo < 1 < hi (factors of "
                              "initial_freq_hz)", list(self.freq_band))
        return self


class DetectorCfg(_Model):
    """Integral residuals with forgetting (seed 000; seed 003 threshold 0.5)."""

    dead_zone_rad_s: NonNegFloat = 1e-4
    # The dead zone grows with what was commanded: |dw| below dead_zone_rad_s plus this
    # fraction of the sum of the commanded thrusters' rate changes (sum_j |mu_j| tau_E,j) is
    # treated as zero, so thrust errors of the size the vehicle admits (docs/design.md 10: +/-15 %)
    # are not read as a failure of a whole thruster.
    relative_dead_zone: float = Field(default=0.0, ge=0.0, lt=1.0)
    # The commanded effect the relative dead zone is taken of does not drop to the tick's own
    # when a sustained burn ends (a thruster on for 3/4 of the tick or more): it is the larger
    # of the tick's and this factor times the one kept from the last tick (0: the tick's own).
    # A long burn's model error (thrust and timing errors within the envelope) goes into the
    # observer's states during the burn and comes out of them over the following quiet ticks
    # at the rate its error dynamics decay: about 0.8 per tick for seed 003's recommended gains
    # (flight/observer.py); read there as a leak otherwise. Short pulses are not kept.
    relative_dead_zone_memory: float = Field(default=0.0, ge=0.0, lt=1.0)
    forgetting_on: Forgetting = 0.9
    forgetting_off: Forgetting = 0.9
    threshold_on: PosFloat = 3.0
    threshold_off: PosFloat = 3.0
    # Two thrusters whose unit acceleration vectors differ by less than this angle are reported
    # as a group (seed 003's stated limit of the method).
    same_direction_deg: NonNegFloat = 2.0
    # The isolation of opposite thrusters (flight.software._isolate_opposite: a failing
    # thruster against its opposite stuck on, fitted, or probed) pairs thrusters within this
    # angle of each other's opposite. None: same_direction_deg (the detector's own pairs,
    # whose burns together skip the commanded evidence, keep that angle either way).
    isolation_opposite_deg: float | None = Field(default=None, ge=0.0, le=45.0)
    # ... and fits the gyro's raw residual (before the observer) instead of the observer's:
    # an adaptive observer that takes a stuck thrust in within a few ticks (iss_rs) leaves the
    # leak fading from its residual, and the probe's ticks then read as a deficit.
    isolation_raw: bool = False
    # Online effectiveness of each thruster (flight.detector.Effectiveness): what the onboard
    # model uses is bounded to 1 +/- effectiveness_bound (0 turns the learning off).
    # chosen: docs/design.md 10 admits +/-15 % thrust errors; 0.2 learns them with a margin.
    effectiveness_bound: float = Field(default=0.2, ge=0.0, lt=1.0)
    # Share of the prior variance of the thrust scales that is common to every thruster (one
    # feed pressure and propellant temperature: seed 003's flight test found all thrusters
    # ~15 % weak together). 0: independent scales. With a share, one thruster's firing also
    # informs the scale of those that have not fired yet (flight.detector.Effectiveness).
    effectiveness_common_share: float = Field(default=0.0, ge=0.0, lt=1.0)
    # None: the dead zone is a sphere, its radius the sum above. A number: an ellipsoid, each
    # commanded thruster j adding relative_dead_zone |dw_j| along its own acceleration
    # direction and this fraction of |dw_j| across it (a direction error: sin 2 deg = 0.035),
    # added in quadrature with the absolute dead zone. A residual across every commanded
    # thruster's direction (a leak on another channel) is then not hidden by their errors.
    relative_dead_zone_across: float | None = Field(default=None, ge=0.0, lt=1.0)
    # None: as above. A number kappa: the dead zone is the ellipsoid of what the effectiveness
    # learning still does not know, dw^T (dz^2 I + kappa^2 A P A^T)^-1 dw < 1, A the burning
    # thrusters' rate-change columns mu_j eff_j and P the covariance of their learnt thrust
    # scales: wide on a thruster's first firings (the prior, +/-20 %), as narrow as the
    # learning has made it after (the fixed fraction above stays wide for ever, and a
    # stuck-on thruster that the controller fights hides inside it). Needs
    # effectiveness_bound > 0; replaces relative_dead_zone (and _across).
    relative_dead_zone_sigma: float | None = Field(default=None, gt=0.0, le=10.0)
    # The command latency is learnt online with the effectiveness (one more state of the same
    # filter: the sensitivity of every burn to the latency, from a second burn timeline), within
    # +/- this many ms of the onboard model's nominal latency, and the model predicts with it.
    # A pulse that lands a few ms late spills its tail into the next tick, where the thruster
    # is not commanded: read as a leak. 0 turns it off. Needs effectiveness_bound > 0.
    learn_latency_ms: float = Field(default=0.0, ge=0.0, le=50.0)

    @model_validator(mode="after")
    def _latency_needs_the_learning(self) -> DetectorCfg:
        # The latency is a state of the effectiveness filter: without it, it would be ignored.
        if self.relative_dead_zone_sigma is not None and (
                self.relative_dead_zone > 0.0 or self.relative_dead_zone_across is not None):
            raise _FieldError("relative_dead_zone_sigma", "no relative_dead_zone or "
                              "relative_dead_zone_across with it (it replaces them)",
                              self.relative_dead_zone_sigma)
        if self.relative_dead_zone_sigma is not None and self.effectiveness_bound <= 0.0:
            raise _FieldError("relative_dead_zone_sigma", "none when effectiveness_bound is 0 "
                              "(the dead zone is the learning's uncertainty)",
                              self.relative_dead_zone_sigma)
        if self.relative_dead_zone_memory > 0.0 and self.relative_dead_zone_across is not None:
            raise _FieldError("relative_dead_zone_memory", "0 with relative_dead_zone_across "
                              "(it keeps the spherical dead zone's commanded effect)",
                              self.relative_dead_zone_memory)
        if self.relative_dead_zone_memory > 0.0 and self.relative_dead_zone <= 0.0:
            raise _FieldError("relative_dead_zone_memory", "0 when relative_dead_zone is 0 "
                              "(it keeps that dead zone's commanded effect)",
                              self.relative_dead_zone_memory)
        if self.flex_share > 0.0 and self.relative_dead_zone_sigma is None:
            raise _FieldError("flex_share", "0 without relative_dead_zone_sigma (it widens the "
                              "learnt dead zone only)", self.flex_share)
        if self.weak_below is not None and self.effectiveness_bound <= 0.0:
            raise _FieldError("weak_below", "none when effectiveness_bound is 0 (the test "
                              "reads the learnt effectiveness)", self.weak_below)
        if self.weak_degraded_below is not None and self.weak_below is None:
            raise _FieldError("weak_degraded_below", "none without weak_below (a tier of the "
                              "burn-fraction test)", self.weak_degraded_below)
        if self.weak_small_below is not None and self.weak_below is None:
            raise _FieldError("weak_small_below", "none without weak_below (a tier of the "
                              "burn-fraction test)", self.weak_small_below)
        if self.confirm_stuck_on == "noisy" and self.gyro_noise_all_ticks is None:
            raise _FieldError("confirm_stuck_on", "true or false without gyro_noise_all_ticks "
                              "(noisy reads its level)", self.confirm_stuck_on)
        for name in ("leak_fit_onset_ticks", "leak_fit_long_ticks"):
            if getattr(self, name) is not None and self.leak_fit_min is None:
                raise _FieldError(name, "none without leak_fit_min (it extends the leak-fit "
                                  "test)", getattr(self, name))
        if self.pulse_test_suspect_below is not None and self.pulse_test_suspect_burns is None:
            raise _FieldError("pulse_test_suspect_below", "none without pulse_test_suspect_burns "
                              "(the suspicion's level)", self.pulse_test_suspect_below)
        if not self.leak_fit_short and self.leak_fit_long_ticks is None:
            raise _FieldError("leak_fit_short", "true without leak_fit_long_ticks (false leaves "
                              "the long fit alone)", self.leak_fit_short)
        if not self.leak_fit_short and self.leak_fit_onset_ticks is not None:
            raise _FieldError("leak_fit_onset_ticks", "none with leak_fit_short false (the onset "
                              "fit is the short window's)", self.leak_fit_onset_ticks)
        if self.learn_latency_ms > 0.0 and self.effectiveness_bound <= 0.0:
            raise _FieldError("learn_latency_ms", "0 when effectiveness_bound is 0 (the latency "
                              "is learnt with the effectiveness)", self.learn_latency_ms)
        return self
    # Burn-fraction test (an integrating test of the commanded evidence): a thruster whose
    # last ``weak_burns`` measurable burns (``flight.detector.Effectiveness.fraction``: the
    # thrust over nominal each burn showed, every other thruster taken as learnt) average
    # below ``weak_below`` by ``weak_sigma`` standard errors (their own scatter) is degraded,
    # or fails to fire below fail_fraction. One pulse's deficit can sit inside the per-tick
    # dead zone (a P2 thruster at 33 % on iss_rs: 1.3e-6 rad/s against 2e-6, every tick of
    # 55 s); eight of them cannot. Keep it below the envelope's admitted thrust errors
    # (DESIGN 10: 0.85 x 0.85 = 0.72 at worst). None: off. Needs effectiveness_bound > 0.
    weak_below: float | None = Field(default=None, gt=0.0, lt=1.0)
    weak_sigma: float = Field(default=3.0, ge=0.0, le=10.0)
    weak_burns: int = Field(default=8, ge=2, le=64)
    # The burn-fraction test holds on the raw residual's burns too (the measured rate change
    # against the onboard model alone, before the observer): a thruster is named only when
    # both its innovation's and its raw burns fall short. orel's adaptive observer takes a
    # long deficit in as flex, and its innovation then lends it to the next thruster fired
    # along it: a healthy 15's last 12 burns read -0.90 on its innovation, 0.96 raw (orel-faults
    # run 55).
    weak_raw: bool = False
    # A second, degraded tier of the same test: a thruster whose last ``weak_degraded_burns``
    # measurable burns average below ``weak_degraded_below`` by ``weak_sigma`` standard errors
    # (raw burns too with ``weak_raw``; with ``weak_small_below`` the small burns summed as
    # that tier sums them, and the raw burns always) is named degraded with their mean as its
    # fraction (or fails to fire below fail_fraction). More burns than the first tier: a
    # thruster at half its thrust sits nearer the envelope's 0.72 than one that fails.
    # None: off.
    weak_degraded_below: float | None = Field(default=None, gt=0.0, lt=1.0)
    # A third tier that reads burns too small to measure alone (under twice the dead zone)
    # too: consecutive ones of a thruster as heavy as one measurable burn are one burn of their
    # size-weighted fraction; the last ``weak_burns`` of all its burns below
    # ``weak_small_below`` by ``weak_sigma`` standard errors name it (degraded or fails to fire,
    # with their mean). A full tick of iss_rs's SM roll thrusters moves the rate by
    # 1.2-2.5e-6 rad/s against 4e-6, and one that failed to fire on 272 commanded ticks was
    # never read. Small pulses read further from their thrust than full burns do (their
    # timing errors weigh more), hence a threshold of its own. None: off.
    weak_small_below: float | None = Field(default=None, gt=0.0, lt=1.0)
    weak_degraded_burns: int = Field(default=20, ge=2, le=64)
    # ... reading no burn of the first ``weak_degraded_after_s`` of the flight: each burn's
    # fraction takes every other thruster burning with it as learnt, and at the start none is
    # (each +/-15 %, and +/-15 % together, DESIGN 10), while the initial slew fires groups of
    # them together on every tick.
    weak_degraded_after_s: float = Field(default=0.0, ge=0.0, le=600.0)
    # Test pulses (a commanded test pulse of one candidate; docs/design.md 6.5): when one
    # measurable burn of a thruster reads below ``pulse_test_below`` of its thrust on the
    # innovation and on the raw residual (a burn among others: their errors fall on it too),
    # or the burn-fraction test names it, the flight tests it: two quiet ticks, then the
    # thruster alone for ``pulse_test_ms`` (whole quanta, at least the minimum firing, at most
    # half the tick: it ends before the next sample) and a quiet tick, in turn; every other
    # thruster waits. Each pulse is read on the raw residual against the mean of the quiet
    # samples on either side (a slow structural mode moves the rate nearly as much on them),
    # when the test's quiet samples agree within the pulse's own effect. A read at
    # ``pulse_test_healthy`` or above: healthy, not tested again for ``pulse_test_every_s``;
    # the mean of
    # ``pulse_test_count`` reads below it names the thruster with that fraction (degraded, or
    # fails to fire below fail_fraction). A thruster commanded on a few ticks only (orel fires
    # a belt thruster in bursts of several) gives too few burns for the burn-fraction test; a
    # lone pulse is read against the sensor and the structure, not against its neighbours'
    # errors. Thrusters whose pulse moves the rate by less than ``pulse_test_dead_zones`` dead
    # zones are not tested.
    # Short pulses read low (the thrust's rise is not over when the valve closes: 60 ms
    # pulses of a healthy roll thruster read 0.5-0.6). None: off.
    pulse_test_below: float | None = Field(default=None, gt=0.0, lt=1.0)
    pulse_test_healthy: float = Field(default=0.6, gt=0.0, lt=1.0)
    pulse_test_ms: float = Field(default=100.0, gt=0.0, le=10000.0)
    pulse_test_count: int = Field(default=2, ge=1, le=10)
    pulse_test_every_s: float = Field(default=30.0, ge=0.0, le=3600.0)
    pulse_test_dead_zones: float = Field(default=4.0, ge=0.0, le=100.0)
    # One read at ``pulse_test_clear`` or above clears the thruster at once (None: at
    # ``pulse_test_healthy``); below it, the test goes on to ``pulse_test_count`` reads and
    # judges their mean against ``pulse_test_healthy``.
    pulse_test_clear: float | None = Field(default=None, gt=0.0, le=2.0)
    # A thruster whose last ``pulse_test_suspect_burns`` burns (measurable, and the small ones
    # summed) average below ``pulse_test_suspect_below`` (None: ``pulse_test_below``) on both
    # residuals is tested too (a suspicion, not a finding: the burn-fraction tiers ask 3
    # standard errors). None: off.
    pulse_test_suspect_burns: int | None = Field(default=None, ge=2, le=200)
    pulse_test_suspect_below: float | None = Field(default=None, gt=0.0, lt=1.5)
    # A test that a suspicion started (one burn, or the last few, short), not a burn-fraction
    # tier's finding, names the thruster when its reads' mean is below this (None:
    # ``pulse_test_healthy``): the weaker the evidence before the test, the lower its bar.
    pulse_test_suspect_healthy: float | None = Field(default=None, gt=0.0, lt=1.0)
    # A thruster the pulses name is named fails to fire below this fraction (None:
    # fail_fraction): what a dead thruster's pulses read, which need not be 0.
    pulse_test_fail_below: float | None = Field(default=None, ge=0.0, lt=1.0)
    # False: a test's samples teach the learnt thrust scales, leaks and latency nothing and
    # stay out of the leak-fit test's window (they are kept as burns either way).
    pulse_test_learn: bool = True
    # With the learnt dead zone (relative_dead_zone_sigma): the flex a change of the burns
    # puts into the gyro at once, as a standard deviation per axis of this share of the change
    # of the burning thrusters' rate change along that axis (sum_j |mu_j,axis| eff_j) from
    # the last tick: a burst after a coast rings the structure, steady firing does not. 0: none.
    flex_share: float = Field(default=0.0, ge=0.0, le=1.0)
    # The dead zone (absolute plus relative) widened by this many standard deviations of the
    # adaptive observer's flex prediction error from a frequency not yet known
    # (observer.freq_prior_sigma): |g^| sigma_A per channel, sigma_A from the prior until the
    # fit on the free ringing knows it better. None: off.
    flex_freq_dead_zone: PosFloat | None = None
    # ... and by no more than this many absolute dead zones: the flex estimate g^ also holds
    # what the observer took in of an unmodelled thrust (a stuck thruster: 0.15 rad/s on
    # orel-stuck run 25, where the structure rings at 1e-3), which is no ringing to widen for.
    flex_freq_dead_zone_cap: PosFloat = 2.0
    # Leak-fit test (an integrating test of the no-command evidence): over the last
    # ``leak_fit_ticks`` ticks the raw residual (3 axes) is fitted by each thruster's leak
    # (its closed-valve time times its acceleration, one parameter of positive size); the best
    # fit, when its leak is at least ``leak_fit_min`` of the thrust, ``leak_fit_sigma``
    # standard errors from 0, and clearly better than every other explanation, for
    # ``leak_fit_hold`` ticks in a row, is a thruster stuck on. None: off.
    leak_fit_min: float | None = Field(default=None, gt=0.0, lt=1.0)
    leak_fit_sigma: float = Field(default=6.0, ge=0.0, le=100.0)
    leak_fit_ticks: int = Field(default=25, ge=3, le=1000)
    leak_fit_hold: int = Field(default=5, ge=1, le=1000)
    # The leak-fit test also fits a leak that began inside the window (the onset tick that fits
    # best, with at least this many closed-valve ticks from it), and a burning thruster's
    # deficit likewise as its rival. A stuck-on thruster steps the raw residual up and holds
    # it there; fitted over the whole window, the quiet ticks before the step dilute it for
    # most of the window. None: the whole window only.
    leak_fit_onset_ticks: int | None = Field(default=None, ge=2, le=1000)
    # ... named at this leak or more (a stuck thruster's step; small leaks are the whole
    # window's), for ``leak_fit_onset_hold`` ticks in a row.
    leak_fit_onset_min: float = Field(default=0.3, gt=0.0, lt=1.0)
    leak_fit_onset_hold: int = Field(default=2, ge=1, le=1000)
    # The leak-fit test also fits a longer window of this many ticks (a small leak gives a
    # few noise levels a tick: its fit's standard error falls as the square root of the
    # ticks), on the ticks with no thruster burning, from the best onset with half the window
    # or more after it, with the noise level the fit measures; the same leak and sigma limits,
    # and rivals judged by a margin of noise variances (flight.software._LONG_MARGIN), not a
    # ratio. None: off.
    leak_fit_long_ticks: int | None = Field(default=None, ge=10, le=5000)
    # The whole-window, onset and long leak fits keep a finding only when the leak, fitted
    # again jointly with the flex tones the adaptive observer tracks (each channel's identified
    # frequency, a sine and a cosine on each axis), keeps its limit and at least half its size
    # alone (the joint size is named): pulsing in step with a tone leaves its ringing on the
    # quiet ticks at the same phases, which the leak alone takes in and the joint fit gives
    # back to the tone; a leak beside tones ringing at other phases keeps its size.
    # False: the leak alone.
    leak_fit_tone: bool = False
    # The fits over the last ``leak_fit_ticks`` ticks (the whole window's and the onset's).
    # false: the long fit alone (needs leak_fit_long_ticks): on orel, whose thrusters fight
    # each other over a few ticks, the short window took a fighter's error for a leak or a
    # deficit (stuck-on thrusters' fighters named degraded first, alarms before the fault),
    # where the long fit on the quiet ticks does not.
    leak_fit_short: bool = True
    # A stuck-on crossing whose neighbours in direction (flight.software._ALIKE_DEG) are
    # crossing too waits up to this many ticks for the raw residual to tell them apart: each
    # one's leak is fitted over the evidence ticks, and the best is named once it leaves at
    # least _ALIKE_MARGIN noise variances less than the next (or when the wait is over); each
    # tick waited must go on along the crossing's direction, as a confirmation. On a detector
    # that crosses on one tick (iss_rs), one tick cannot tell thrusters 7-14 deg apart (its
    # noise turns the residual by about as much). None: named at once, from the sum of the
    # raw residual over the ticks (_ALIKE_MIN_TICKS or more).
    alike_wait_ticks: int | None = Field(default=None, ge=1, le=9)
    # A commanded-evidence detection whose estimated thrust fraction is at least this is
    # "degraded" (with the fraction), below it "fails to fire". chosen: halfway between a
    # thruster that gives nothing and the smallest degradation worth reporting (30 %).
    fail_fraction: float = Field(default=0.15, ge=0.0, le=1.0)
    # Ticks the detector skips after an FDIR response before its evidence restarts on the new
    # configuration (a closed manifold's thrust decay, the arrays ringing from the stuck burn,
    # the re-initialised observer converging). chosen: 15 (3 s at 0.2 s), measured on orel,
    # stuck on 100 % in holds, 16 runs, a second detection after a correct first one:
    # 2 ticks 10 of 14, 5 ticks 10 of 14, 10 ticks 3 of 14, 15 ticks 0 of 14.
    response_hold_ticks: int = Field(default=15, ge=0)
    # A one-tick rate jump above this, unexplained by the thrust of the tick, is a gyro error
    # candidate (flight.gyro_check); None: 5 x dead_zone_rad_s (flight.software.JUMP_DZ).
    gyro_jump_rad_s: PosFloat | None = None
    # A one-tick rate jump above this (and not above the jump level), unexplained by the thrust
    # of the tick, is held a tick: kept out of the thruster evidence unless the next tick
    # repeats it along its direction (flight.gyro_check); None: the jump level.
    gyro_hold_rad_s: PosFloat | None = None
    # A stuck-on named by a residual crossing on one tick waits for the next tick's raw
    # residual (the measured rate change minus the model's) to go on along the thruster's
    # direction, at least half of what the crossing tick had along it: a leak repeats every
    # tick, a noisy sample is undone by the next one (differences of white noise), so the
    # crossing is dropped and the evidence restarts. For a detector that decides on one tick
    # (iss_rs: one tick above the dead zone crosses the threshold); costs one tick of latency.
    # ``noisy``: only a crossing whose thruster direction has been noisy over the ticks before
    # it waits (the raw residual's lag-one autocovariance along it above the square of the
    # every-tick noise level, gyro_noise_all_ticks x the gyro's noise_std_rad_s); a crossing
    # out of quiet ticks (a leak's onset) is named at once. Needs gyro_noise_all_ticks.
    confirm_stuck_on: bool | Literal["noisy"] = False
    # The gyro's noise test on every tick, not only on quiet ones (flight.gyro_check: the raw
    # residual's lag-one autocovariance reads the sensor's noise through the thrusters' errors):
    # an axis noisier than this many times the gyro's noise_std_rad_s is a noise increase, and
    # the gyro is suspect while it lasts. For a vehicle that fires on nearly every tick
    # (iss_rs: 97 % of the ticks). None: quiet ticks only.
    gyro_noise_all_ticks: PosFloat | None = None
    # The gyro's noise test on every tick through a fit of the thrusters' errors
    # (flight.gyro_check: the raw residual of the last 75 evidence ticks fitted on each
    # thruster's learnt increment, its latency sensitivity and its partial burns; the
    # leftover's lag-one autocovariance reads the sensor's noise with the thrusters' fixed
    # scale, direction and timing errors taken out; with an adaptive observer, its innovation
    # instead, without the ticks of sustained burns): an axis noisier than this many times the
    # gyro's noise_std_rad_s for 10 ticks in a row, after 30 s of evidence, is a noise
    # increase. For a vehicle that fires on nearly every tick and whose thrust errors are
    # larger than its sensor's noise (kalman_cube), or whose flex rings in the residual (orel).
    # None: off.
    gyro_noise_fit: PosFloat | None = None


class KalmanCfg(_Model):
    """Per-axis Kalman filter with a disturbance state (seed 002) and its leak test."""

    enabled: bool = False
    process_noise_accel: NonNegFloat = 1e-7
    measurement_noise_rad: PosFloat = 1e-5
    leak_threshold_rad_s2: PosFloat = 1e-4
    window_ticks: int = Field(default=5, ge=1)


class FdirCfg(_Model):
    """Response to a detection (docs/design.md 6.4 step 7), per vehicle."""

    on_stuck_on: Literal["close_manifold", "drop_thruster", "none"] = "close_manifold"
    on_fail_to_fire: Literal["close_manifold", "drop_thruster", "none"] = "drop_thruster"
    on_degraded: Literal["close_manifold", "drop_thruster", "none"] = "drop_thruster"


class OrbitCorrectionCfg(_Model):
    """An orbit-correction burn (seed 004 section 3, eqs. 3.3-3.4), set per scenario.

    From ``start_s`` the flight burns ``burn`` (4, 6 or 8 thrusters of the aft belt for +X,
    of the front belt for -X) continuously, holds attitude by off-times, gives the lateral
    components from the middle belt, and stops when its own prediction of the delta-v given
    (no accelerometer: the sum of the allocator's predictions) is within ``tolerance_m_s`` of
    ``delta_v_B_m_s`` (body axes; the craft holds the orbital attitude, so body ~ orbital).
    ``scheme``: seed 004's name of the case (``cartesian``: X, Y, Z components;
    ``polar``: the whole delta-v along X).
    """

    start_s: NonNegFloat = 0.0
    delta_v_B_m_s: tuple[float, float, float]
    burn: list[str] = Field(min_length=1)
    scheme: Literal["cartesian", "polar"] = "cartesian"
    tolerance_m_s: PosFloat = 0.02


class FlightCfg(_Model):
    controller: ControllerCfg = ControllerCfg()
    allocator: AllocatorCfg = AllocatorCfg()
    onboard_model: OnboardModelCfg = OnboardModelCfg()
    observer: ObserverCfg = ObserverCfg()
    detector: DetectorCfg = DetectorCfg()
    kalman: KalmanCfg = KalmanCfg()
    fdir: FdirCfg = FdirCfg()
    orbit_correction: OrbitCorrectionCfg | None = None

    @model_validator(mode="after")
    def _flex_freq_needs_its_prior(self) -> FlightCfg:
        if self.detector.flex_freq_dead_zone is not None and (
                self.observer.kind != "adaptive" or self.observer.freq_prior_sigma is None):
            raise _FieldError("detector.flex_freq_dead_zone",
                              "null unless observer.kind is adaptive with freq_prior_sigma set "
                              "(it widens the dead zone by that prior's flex uncertainty)",
                              self.detector.flex_freq_dead_zone)
        return self


class VehicleCfg(_Model):
    name: str
    description: str = ""
    mass_kg: PosFloat
    inertia_B_kg_m2: tuple[Vec3, Vec3, Vec3]
    com_m: Vec3 = (0.0, 0.0, 0.0)
    timing: TimingCfg = TimingCfg()
    thrust_profile: ThrustProfileCfg = ThrustProfileCfg()
    orbit: OrbitCfg = OrbitCfg()
    cmg: CmgCfg | None = None
    disturbance: DisturbanceCfg = DisturbanceCfg()
    gyro: GyroCfg = GyroCfg()
    flex_modes: list[FlexModeCfg] = []
    manifolds: list[str] = Field(min_length=1)
    thrusters: list[ThrusterCfg] = Field(min_length=1)
    flight: FlightCfg = FlightCfg()

    @field_validator("inertia_B_kg_m2")
    @classmethod
    def _inertia(cls, v: tuple[Vec3, Vec3, Vec3]) -> tuple[Vec3, Vec3, Vec3]:
        j = np.array(v, dtype=float)
        if not np.allclose(j, j.T, rtol=0, atol=1e-9 * max(1.0, float(np.abs(j).max()))):
            raise ValueError("a symmetric 3x3 matrix")
        if np.linalg.eigvalsh(j).min() <= 0:
            raise ValueError("a positive definite 3x3 matrix")
        return v

    @model_validator(mode="after")
    def _cross(self) -> VehicleCfg:
        names = [t.name for t in self.thrusters]
        seen: set[str] = set()
        for i, n in enumerate(names):
            if n in seen:
                raise _FieldError(f"thrusters[{i}].name", "a unique thruster name", n)
            seen.add(n)
        if len(set(self.manifolds)) != len(self.manifolds):
            raise _FieldError("manifolds", "unique manifold names", self.manifolds)
        for i, t in enumerate(self.thrusters):
            if t.manifold not in self.manifolds:
                raise _FieldError(
                    f"thrusters[{i}].manifold", f"one of {self.manifolds}", t.manifold
                )
        for k, m in enumerate(self.flex_modes):
            for tn in m.thrusters:
                if tn not in seen:
                    raise _FieldError(f"flex_modes[{k}].thrusters", "a thruster name", tn)
        for k, (a, b) in enumerate(self.flight.allocator.roll_pairs):
            for n in (a, b):
                if n not in seen:
                    raise _FieldError(f"flight.allocator.roll_pairs[{k}]", "a thruster name", n)
        oc = self.flight.orbit_correction
        for k, n in enumerate(oc.burn if oc else ()):
            if n not in seen:
                raise _FieldError(f"flight.orbit_correction.burn[{k}]", "a thruster name", n)
        return self

    def thruster_index(self, name: str) -> int:
        for i, t in enumerate(self.thrusters):
            if t.name == name:
                return i
        raise KeyError(name)


# --------------------------------------------------------------------------- derived arrays


@dataclass(frozen=True)
class VehicleArrays:
    """Numpy views of a vehicle, shared by the plant and flight cores (nominal values).

    Shapes: N thrusters. ``r_B_m`` (N, 3) lever arms from the centre of mass; ``d_B`` (N, 3) unit
    force directions; ``thrust_n`` (N,); ``torque_per_n_B`` (N, 3) = r x d; ``mu_B_rad_s2`` (N, 3)
    = J^-1 (r x F), the angular acceleration of each thruster (seed 004 section 3);
    ``accel_B_m_s2`` (N, 3) = F / m; ``mdot_kg_s`` (N,) = F / (Isp g0); ``manifold_of`` (N,)
    manifold index of each thruster.
    """

    names: tuple[str, ...]
    manifolds: tuple[str, ...]
    J_B_kg_m2: np.ndarray
    J_inv_B: np.ndarray
    mass_kg: float
    r_B_m: np.ndarray
    d_B: np.ndarray
    thrust_n: np.ndarray
    torque_per_n_B: np.ndarray
    mu_B_rad_s2: np.ndarray
    accel_B_m_s2: np.ndarray
    mdot_kg_s: np.ndarray
    manifold_of: np.ndarray

    @classmethod
    def from_vehicle(cls, v: VehicleCfg) -> VehicleArrays:
        J = np.array(v.inertia_B_kg_m2, dtype=float)
        J_inv = np.linalg.inv(J)
        com = np.array(v.com_m, dtype=float)
        r = np.array([t.position_m for t in v.thrusters], dtype=float) - com
        d = np.array([t.direction for t in v.thrusters], dtype=float)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        F = np.array([t.thrust_n for t in v.thrusters], dtype=float)
        tq = np.cross(r, d)
        mu = (J_inv @ (tq * F[:, None]).T).T
        isp = np.array([t.isp_s for t in v.thrusters], dtype=float)
        man = np.array([v.manifolds.index(t.manifold) for t in v.thrusters], dtype=int)
        arrays = (J, J_inv, r, d, F, tq, mu, d * F[:, None] / v.mass_kg, F / (isp * G0_M_S2), man)
        for a in arrays:
            a.setflags(write=False)
        return cls(
            names=tuple(t.name for t in v.thrusters),
            manifolds=tuple(v.manifolds),
            J_B_kg_m2=J,
            J_inv_B=J_inv,
            mass_kg=float(v.mass_kg),
            r_B_m=r,
            d_B=d,
            thrust_n=F,
            torque_per_n_B=tq,
            mu_B_rad_s2=mu,
            accel_B_m_s2=arrays[7],
            mdot_kg_s=arrays[8],
            manifold_of=man,
        )
