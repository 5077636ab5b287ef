"""The flight software's tick as one pure object (docs/design.md section 3 pipeline).

``FlightSoftware(vehicle, target=None, initial_attitude=None).step(tick, gyro_B_rad_s)`` runs,
in order: read the gyro sample; observer update (seed 003 eqs. 7-8); detector update with the
commands in force over the last tick (seeds 000, 003; Kalman leak test, seed 002); FDIR response;
controller (seed 004 phase plane or seed 002 s-law); allocator (LP, quantisation); output.
It reads no clock: the tick number is an argument, the time is ``tick * h``. The stages are
separate methods listed in ``STAGES`` so that the process shell can time each one::

    fs.begin(tick, sample)
    for name in fs.STAGES:
        t0 = clock(); getattr(fs, "stage_" + name)(); stage_ns[name] = clock() - t0
    out = fs.finish()

``step`` does exactly that without timing.

Timing convention: the sample read at tick n is the rate at ``t_n`` (an integrating gyro gives
the mean over the last tick); the commands of tick n are applied at ``t_n`` plus the nominal
command latency and act until the next sample; the onboard model's prediction for ``t_n+1`` is
made at the end of tick n from the observer's estimate and those commands.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from common.scenario import AttitudeCfg, target_at
from common.vehicle import VehicleArrays, VehicleCfg
from flight.allocator import Allocation, Allocator
from flight.attitude import AttitudeEstimate, propagate, q_rotate_inv
from flight.controller import Controller, RateDemand
from flight.detector import (
    DEGRADED,
    FAIL_TO_FIRE,
    GYRO_FAULT,
    STUCK_ON,
    Detection,
    Detector,
    Effectiveness,
    leak_or_deficit,
    opposite_matrix,
)
from flight.fdir import Fdir
from flight.gyro_check import GyroCheck
from flight.kalman import DisturbanceKalman
from flight.observer import AdaptiveObserver, ObserverOutput
from flight.onboard_model import OnboardModel, Prediction

_Y_ORBIT = np.array([0.0, 1.0, 0.0])  # local vertical in the orbit frame (seed 003 eq. 9)
# Ticks of residuals and burns kept to tell a leak from its opposite thruster's deficit.
# A one-tick raw rate jump above this many dead zones (plus what the thrusters of the tick can
# explain) is a gyro-error candidate (flight.gyro_check), unless the vehicle sets its own.
JUMP_DZ = 5.0
_ISOLATION_TICKS = 10
# A stuck-on detection is checked against the thrusters whose directions are within this
# angle of the named one and whose stuck-on evidence is at least _ALIKE_SHARE of its
# threshold: the one the measured rate change (the gyro's raw residual, before the observer)
# points at most is named. chosen: orel's neighbours are 4-29 deg apart; the adaptive
# observer takes part of a stuck thrust in as flex and turns its residual by that much.
_ALIKE_DEG = 35.0
_ALIKE_SHARE = 0.5
# ... only over at least this many ticks of evidence: the raw residual carries the flex the
# observer removes, and only a sum over a few ticks averages it out (iss_rs crosses on one
# tick, where the raw direction named a neighbour in 3 of 23 stuck-on runs it got right).
_ALIKE_MIN_TICKS = 3
# With DetectorCfg.alike_wait_ticks, a neighbour is named once its leak's fit over the
# evidence ticks (two or more: the crossing's and a tick waited) leaves at least this many
# noise variances (a third of the dead zone, squared) less than the next neighbour's. chosen:
# iss_rs-stuck (120 runs, every tick of every wait): at 6 or more the best fit was the stuck
# thruster on 53 of 54 ticks with two or three ticks of evidence; on the crossing's tick
# alone, 30 of 33 (at 9 or more, 17 of 20: one tick's error is not noise alone).
_ALIKE_MARGIN = 6.0
# A stuck-on crossing whose named thruster's leak explains less than _LONE_NAMED of the raw
# residual's energy over the evidence ticks (its best size, not negative), while one other
# thruster's leak, of a size within _LONE_SIZE of its nominal thrust, explains at least
# _LONE_EXPLAINED of it, names that one: the raw residual is one leak, and not the one named.
# Orel's adaptive observer takes a stuck middle-belt thruster's roll in as flex and its
# residual turns 35-65 deg away, outside the neighbours judged above (orel-stuck runs 26
# and 88: 27 named 8, 29 named 6; the raw residual 4-5 deg from the stuck one, its leak
# explaining 0.87 and 0.99, the named one's 0.46 and 0.22). chosen: over the first crossing
# after the fault of the 120 orel-stuck runs no wrong thruster explained 0.85 where the
# named one explained under 0.5. The lower size bound also holds for the neighbours judged by
# direction (orel-faults runs 66 and 84: a 50 % stuck 23 or 29 named as 17 or 18, whose leaks
# fit at 6 % of their thrust).
_LONE_EXPLAINED = 0.85
_LONE_NAMED = 0.5
_LONE_SIZE = (0.1, 1.4)
# A burn of at least this share of the tick (one thruster) is a sustained firing: its
# commanded effect is kept for the relative dead zone of the next ticks
# (detector.relative_dead_zone_memory). Short pulses, such as the controller's against a
# small leak, charge the observer's states little and are not kept.
_SUSTAINED = 0.75
# A hypothesis replaces the detector's when its residual sum of squares is this many times
# smaller. chosen: a factor that noise over 10 ticks does not reach by chance.
_ISOLATION_RATIO = 2.0
# The gyro's fit noise test on a flexible craft is given no tick on which a thruster burns this
# share of the tick or more (``_fit_regressors``).
_FIT_SKIP_BURN = 1.0
# When the ticks so far cannot tell the two apart (the controller alternating the pair fires
# one of them on every tick), the pair is left out of the allocation for this many ticks (a
# test of seed 003's "commanded test pulse" kind, in reverse: a stuck thruster still pushes,
# a failed one gives nothing) and the hypotheses are fitted again. Two ticks: an integrating
# gyro's mean over the second interval has no burn of either in it.
_PROBE_TICKS = 2
# Test pulses (DetectorCfg.pulse_test_below): candidates queued from one tick's burns.
_PULSE_CANDIDATES = 3
# A test starts with this many quiet ticks: the first holds the tail of the burst before it
# and the ringing it starts (read against it, a healthy thruster's first pulse read below 0.6
# in 8 % of orel-envelope's tests, its later ones in 1 %).
_PULSE_LEAD = 2
# A pulse is read only when the test's quiet samples so far lie within this share of the
# pulse's own effect along it: the straight line between two of them misses a mode of
# 0.6-1.1 Hz (orel's in-plane arrays) by up to 0.5-0.8 of its step per tick, and two that
# agree may straddle its peak (a healthy 1 read 0.31 between quiet samples 1.1 pulses apart,
# orel-envelope run 84; a healthy 2 read 0.12 between two 0.4 apart, the quiet samples of its
# test 1.0 apart). Within the bound, every read of a healthy thruster over 200 envelope runs
# was 0.56 or more.
_PULSE_STILL = 1.0
# The burn-fraction test names no thruster when a leak of another explains the last ticks'
# residual this much better (residual sum of squares) than its own deficit.
_WEAK_LEAK_RSS = 0.8
# The burn-fraction test reads no burn of an orbit correction nor of the time this long after
# its end: a thruster holding the attitude against the burn's residual torque burns on every
# tick, and what the learning has not taken in of that torque reads as its deficit (with the
# test reading them, 28 of the first 87 orel-burn-faults runs named a healthy thruster failing,
# during the burn and up to 24 s after it, in the structure's ringing). chosen: 60 s, over
# twice the longest seen.
_WEAK_AFTER_BURN_S = 60.0
# A stuck-on crossing held for confirmation (DetectorCfg.confirm_stuck_on) is confirmed by a
# next tick above this many times the noise of the last ticks' raw residual along the
# thruster's direction (a noisy sample is undone by the next one; two in a row along one
# direction, the second above twice the noise, are a leak).
_CONFIRM_NOISE = 2.0
# confirm_stuck_on: noisy reads the noise along the thruster over this many ticks before the
# crossing (a large gyro noise increase can build a crossing within a few ticks).
_NOISY_TICKS = 5
# The leak-fit test names a leak only when it leaves less than this share of what the best
# other explanation leaves (another thruster's leak, a burning thruster's deficit).
_LEAK_RIVAL_RSS = 0.7
# The leak-fit onset test judges only after this many windows of evidence since the start or
# a restart: the first seconds' burns (a slew from up to 30 deg with every thrust scale still
# at its prior) fitted as a leak that began inside the first window (iss_rs-envelope: 2 of 500
# runs named a stuck-on 5.4-5.6 s into the run, the only two the onset fit added).
_ONSET_AFTER = 2
# The long leak-fit test names a leak that leaves this many noise variances less than the
# best other explanation.
_LONG_MARGIN = 9.0
# What the isolation returns when neither hypothesis of a pair holds (_isolate_opposite).
NEITHER = Detection(tick=-1, thruster=-1, kind="none", group=(), names=(), rho=0.0)
# The probe starts before a crossing when a failing thruster's and its opposite's stuck-on
# evidence both pass this share of their thresholds within _SUSPECT_TIE of each other, so the
# separating ticks are in by the time one crosses (no latency added); once per pair per
# _ISOLATION_TICKS.
_SUSPECT_SHARE = 0.6
_SUSPECT_TIE = 0.2


@dataclass(frozen=True)
class TickOutput:
    """Everything one flight tick produces. Shapes: N thrusters, M manifolds.

    Commands: ``on_ms`` (N,) int THR_CMD on-times; ``manifold_open`` (M,) bool.
    FDIR: ``detection`` (new this tick, or None); ``fdir_state``; ``safe_mode``;
    ``available`` (N,) bool.
    Telemetry (body axes, rad/s unless named): ``omega_meas`` (3,), ``omega_est`` (3,) observer's
    rigid estimate, ``omega_pred`` (3,) onboard model's prediction for this sample, ``residual``
    (3,) = omega_est - omega_pred, ``gamma_est`` (3,) flex at the gyro, ``freq_est_hz`` (3,),
    ``xi`` (N,), ``rho_on`` (N,), ``rho_off`` (N,), ``threshold_on``, ``threshold_off``,
    ``att_err_rad`` (3,) angle errors nu, ``rate_err`` (3,), ``dw_down`` (3,), ``dw_up`` (3,)
    controller bounds, ``dw_pred`` (3,) allocator's predicted rate change, ``feasible``,
    ``disturbance_rad_s2`` (3,) Kalman estimate (zeros when disabled), ``attitude_BO`` (4,).
    """

    tick: int
    on_ms: np.ndarray
    manifold_open: np.ndarray
    detection: Detection | None
    fdir_state: str
    safe_mode: bool
    available: np.ndarray
    omega_meas: np.ndarray
    omega_est: np.ndarray
    omega_pred: np.ndarray
    residual: np.ndarray
    gamma_est: np.ndarray
    freq_est_hz: np.ndarray
    xi: np.ndarray
    rho_on: np.ndarray
    rho_off: np.ndarray
    threshold_on: float
    threshold_off: float
    att_err_rad: np.ndarray
    rate_err: np.ndarray
    dw_down: np.ndarray
    dw_up: np.ndarray
    dw_pred: np.ndarray
    feasible: bool
    disturbance_rad_s2: np.ndarray
    attitude_BO: np.ndarray


# A leak fit's finding stands beside the flex tones (``leak_fit_tone``) when the leak fitted
# jointly with them keeps at least this share of its size alone: tones that ring at random
# phases leave it, tones sampled at the same phases on every quiet tick (pulsing in step
# with them) take it.
_TONE_KEEP = 0.5


def _rss_one(y: np.ndarray, x: np.ndarray) -> float:
    """Residual sum of squares of the one-parameter least-squares fit ``y ~ c x``, ``c >= 0``
    (arrays of one shape; all of ``y`` when ``x`` is zero or the best ``c`` is negative)."""
    xx = float((x * x).sum())
    yy = float((y * y).sum())
    xy = float((x * y).sum())
    if xx <= 0.0 or xy <= 0.0:
        return yy
    return max(yy - xy * xy / xx, 0.0)


def _onset_fits(raw: np.ndarray, s: np.ndarray, mu: np.ndarray,
                min_support: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One-parameter least-squares fits of the residual ``raw`` (W, 3) by each column of the
    regressor ``s`` (W, N) along its direction ``mu`` (N, 3), each starting at the onset tick
    that fits best: ``raw(k) ~ c s(k, j) mu_j`` for ``k >= k0``, nothing before. Onsets with
    fewer than ``min_support`` ticks of nonzero regressor from them are not tried, nor fits of
    negative size. Returns ``(rss, c, xx, k0)``, each (N,); ``rss`` is ``inf`` where no onset
    fits."""
    a = s * s * (mu * mu).sum(axis=1)[None, :]            # (W, N) |x_k|^2
    b = s * (raw @ mu.T)                                  # (W, N) x_k . raw_k
    A = np.cumsum(a[::-1], axis=0)[::-1]                  # suffix sums from each onset
    B = np.cumsum(b[::-1], axis=0)[::-1]
    support = np.cumsum((s != 0.0)[::-1], axis=0)[::-1]
    ok = (A > 0.0) & (B > 0.0) & (support >= min_support)
    gain = np.where(ok, B * B / np.where(A > 0.0, A, 1.0), -np.inf)   # what each onset explains
    k0 = np.argmax(gain, axis=0)
    cols = np.arange(s.shape[1])
    best = gain[k0, cols]
    yy = float((raw * raw).sum())
    fit = np.isfinite(best)
    rss = np.where(fit, np.maximum(yy - np.where(fit, best, 0.0), 0.0), np.inf)
    xx = A[k0, cols]
    c = np.where(fit, B[k0, cols] / np.where(xx > 0.0, xx, 1.0), 0.0)
    return rss, c, xx, k0


class FlightSoftware:
    """Flight tick for one vehicle; pure and deterministic (module doc).

    ``target`` and ``initial_attitude``: ``AttitudeCfg`` or quaternions (4,) relative to the orbit
    frame (the initial attitude is what the flight believes at tick 0, e.g. from the star
    tracker; default identity). ``programme``: programmed turns, (tick, target quaternion (4,))
    in tick order (``ScenarioCfg.programme_ticks``); from its tick on each is the target (of
    two on one tick, the later).
    """

    STAGES = ("observer", "detector", "controller", "allocator", "output")

    def __init__(self, vehicle: VehicleCfg, target: AttitudeCfg | np.ndarray | None = None,
                 initial_attitude: AttitudeCfg | np.ndarray | None = None,
                 lead_s: float = 0.0,
                 programme: list[tuple[int, np.ndarray]] | None = None) -> None:
        self.vehicle = vehicle
        # The controller acts on the state predicted this far ahead: the actuation phase, when
        # commands take effect that long after their sample (the onboard model's latency
        # includes it). 0: on the estimate at the sample.
        if not 0.0 <= lead_s < float(vehicle.timing.tick_s):
            raise ValueError(f"lead_s: expected 0 <= s < the tick, got {lead_s}")
        self.lead_s = float(lead_s)
        fc = vehicle.flight
        self.arrays = VehicleArrays.from_vehicle(vehicle)
        self.h = float(vehicle.timing.tick_s)
        self.n = len(self.arrays.names)
        self.target_TO = self._target0 = _quat(target)
        self._programme = [(int(k), _quat(q)) for k, q in (programme or [])]
        if any(b[0] < a[0] for a, b in itertools.pairwise(self._programme)):
            raise ValueError("programme: expected turns in tick order")
        self.model = OnboardModel(vehicle)
        self.observer = AdaptiveObserver(fc.observer, self.h)
        dc = fc.detector
        # Measurement variance: the residual the detector treats as noise (its dead zone).
        learn_lat = dc.learn_latency_ms / 1000.0  # needs effectiveness_bound > 0 (validated)
        self.effectiveness = Effectiveness(self.arrays.mu_B_rad_s2, dc.effectiveness_bound,
                                           dc.dead_zone_rad_s**2, self.h,
                                           latency_bound_s=learn_lat,
                                           latency_floor_s=-self.model.nominal_latency_s,
                                           common_share=dc.effectiveness_common_share)
        self.effectiveness.kept = max(self.effectiveness.kept, dc.weak_burns,
                                      dc.weak_degraded_burns if dc.weak_degraded_below else 0)
        self.effectiveness.chunk_small = dc.weak_small_below is not None
        if learn_lat > 0.0:
            self.model.learn_latency()
        self.detector = Detector(self.arrays.mu_B_rad_s2, dc, self.arrays.names,
                                 hold_ticks=dc.response_hold_ticks,
                                 effectiveness=self.effectiveness)
        # the pairs the opposite isolation fits and probes (DetectorCfg.isolation_opposite_deg)
        self._iso_opposite = (self.detector.opposite if dc.isolation_opposite_deg is None
                              else opposite_matrix(self.detector.e_B,
                                                   dc.isolation_opposite_deg))
        # Sensor check (flight.gyro_check): the jump level from the detector's dead zone, the
        # noise floor from the gyro's own specification (second difference of
        # the sample, three axes).
        jump = (dc.gyro_jump_rad_s if dc.gyro_jump_rad_s is not None
                else JUMP_DZ * dc.dead_zone_rad_s)
        self.gyro_check = GyroCheck(jump, math.sqrt(18.0) * vehicle.gyro.noise_std_rad_s,
                                    hold_rad_s=dc.gyro_hold_rad_s,
                                    lag_noise_rad_s=None if dc.gyro_noise_all_ticks is None
                                    else dc.gyro_noise_all_ticks * vehicle.gyro.noise_std_rad_s,
                                    fit_noise_rad_s=None if dc.gyro_noise_fit is None
                                    else dc.gyro_noise_fit * vehicle.gyro.noise_std_rad_s,
                                    fit_innovation=self.observer.kind == "adaptive")
        # confirm_stuck_on: noisy: the square of the every-tick noise level, and (tick, raw
        # residual) of the last ticks the gyro check judged (kept only then)
        self._noisy_level2 = None if dc.confirm_stuck_on != "noisy" else (
            dc.gyro_noise_all_ticks * vehicle.gyro.noise_std_rad_s) ** 2
        self._raw_recent: list[tuple[int, np.ndarray]] = []
        self._held: tuple | None = None
        self._deferred_learning: tuple | None = None
        self._weak: int | None = None  # the burn-fraction test's thruster this tick
        # what the tier that named it read, (burns, first update, small burns too) for
        # ``Effectiveness.burn_mean``; None: the first tier (named with ``fraction``)
        self._weak_read: tuple[int, int, bool] | None = None
        self._weak_first: int | None = None  # the degraded tier's first update read
        # The test running (DetectorCfg.pulse_test_below): the thruster, whether this tick's
        # allocation is the test's, the tick of its last command, the raw residual and the
        # thruster's burn of each test tick read so far, what its pulses read.
        self._pulse: dict | None = None
        self._pulse_end: dict[int, int] = {}  # the tick each thruster's last test ended
        self._pulse_sample = -1  # the last sample that answers a test's tick
        # thrusters a suspicion's test cleared below pulse_test_healthy: a tier's finding of
        # one is tested again at once, against pulse_test_healthy
        self._pulse_doubt: set[int] = set()
        self._pulse_frac: float | None = None  # what the pulses read, when they named it
        self._pulse_queue: list[int] = []  # thrusters waiting for their test
        self._pulse_len_ms = self._pulse_ms()
        # the thrusters whose pulse moves the rate by pulse_test_dead_zones dead zones at least
        # (orel's middle belt, 1 in 100 ms, is left to the other tests)
        self._pulse_testable = np.linalg.norm(self.arrays.mu_B_rad_s2, axis=1) \
            * self._pulse_len_ms / 1000.0 >= dc.pulse_test_dead_zones * dc.dead_zone_rad_s
        # (raw residual, burns, variance) of the last ticks, for the leak-fit test
        self._leak_window: list[tuple[np.ndarray, np.ndarray, float, int]] = []
        self._leak_streak: tuple[int, int] = (-1, 0)  # (thruster, ticks in a row)
        # (observer residual, burns, outside the dead zone, raw residual) of the last ticks
        self._window: list[tuple[np.ndarray, np.ndarray, bool, np.ndarray, int]] = []
        # Commanded effect kept for the relative dead zone (detector.relative_dead_zone_memory).
        self._commanded_kept = 0.0
        self._u_abs_last = np.zeros(3)  # the last tick's burns along each axis (flex_share)
        self._burn_prev: np.ndarray | None = None  # the last interval's burns (gyro_noise_fit)
        # (detection held back, the pair left out of the allocation, ticks left) while probing
        self._probe: tuple[Detection | None, tuple[int, int], int] | None = None
        self._onset_streak = (-1, 0)  # the leak-fit onset test's (thruster, ticks in a row)
        self._long_streak = (-1, 0)  # the long leak-fit test's (thruster, ticks in a row)
        self._leak_seen = 0  # ticks in the leak-fit window since it last restarted
        self._probed: dict[tuple[int, int], int] = {}
        # (stuck-on waiting for the next tick, its raw residual along the thruster) and the
        # crossings the next tick did not confirm (DetectorCfg.confirm_stuck_on)
        self._confirm: tuple[Detection, float] | None = None
        # (stuck-on crossing, its neighbours, its raw residual along it, ticks waited) while
        # the next ticks tell the neighbours apart (DetectorCfg.alike_wait_ticks)
        self._alike_hold: tuple[Detection, list[int], float, int] | None = None
        self.unconfirmed_stuck_on = 0
        # the test pulses so far (DetectorCfg.pulse_test_below): started, ended healthy, ended
        # naming the thruster, ended without a verdict; ticks the controller waited for them
        self.pulse_tests = {"started": 0, "healthy": 0, "named": 0, "void": 0, "ticks": 0}
        self._gyro_settle = 0  # ticks left of the settling after a gyro resynchronisation
        self._w_prev: np.ndarray | None = None
        self.fdir = Fdir(fc.fdir, self.arrays.manifold_of, len(self.arrays.manifolds))
        self.kalman = (DisturbanceKalman(fc.kalman, self.h, self.detector.e_B)
                       if fc.kalman.enabled else None)
        self.controller = Controller(vehicle, self.arrays)
        self.allocator = Allocator(vehicle, self.arrays)
        self.attitude = AttitudeEstimate(vehicle.orbit.rate_rad_s, _quat(initial_attitude))
        self.integrating = vehicle.gyro.kind == "integrating"
        self._y_last: tuple[int, np.ndarray] | None = None  # (tick, rate sample) for strapdown
        self._pred: Prediction | None = None
        self._free = np.zeros(3)
        self._phi_meas = np.zeros(3)
        self._tick = -1
        # Orbit correction (seed 004 section 3): delta-v given so far, as the flight predicts it.
        self.orbit_correction = fc.orbit_correction
        self.dv_given_B_m_s = np.zeros(3)
        self.burn_state = "none" if fc.orbit_correction is None else "waiting"
        self._burn_done_tick: int | None = None  # the tick the orbit correction ended

    # ------------------------------------------------------------------ pipeline

    def step(self, tick: int, gyro_B_rad_s: np.ndarray, *, fresh: bool = True,
             evidence: bool = True) -> TickOutput:
        """One whole tick (all stages in order); ``fresh``/``evidence`` as in ``begin``."""
        self.begin(tick, gyro_B_rad_s, fresh=fresh, evidence=evidence)
        for name in self.STAGES:
            getattr(self, "stage_" + name)()
        return self.finish()

    def begin(self, tick: int, gyro_B_rad_s: np.ndarray, *, fresh: bool = True,
              evidence: bool = True) -> None:
        """Stage "read gyro": take the newest sample (3,) for tick ``tick``.

        ``fresh`` False: no valid sample came for this tick (dropped, late, rejected); the
        flight propagates: the onboard model's prediction for this tick stands in for the
        measurement. ``evidence`` False: the sample is real but the tick must not count as
        evidence (the plant did not apply the last command, docs/hostile-bus.md). Either way
        the tick feeds nothing to the gyro check, the detector, the effectiveness learning or
        the Kalman leak test, and the onboard model restarts from the estimate.
        """
        if tick <= self._tick:
            raise ValueError(f"tick: expected > {self._tick}, got {tick}")
        self._tick = int(tick)
        if self._programme:
            self.target_TO = target_at(self._target0, self._programme, self._tick)
        self._y = np.asarray(gyro_B_rad_s, dtype=float).reshape(3)
        if not fresh and self._pred is not None:
            self._y = np.array(self._pred.omega_calc_B_rad_s, dtype=float).reshape(3)
        self._fresh = bool(fresh)
        self._evidence = bool(fresh and evidence)
        self._det: Detection | None = None

    def stage_observer(self) -> None:
        """Observer update with the last tick's model increments; attitude propagation."""
        pred = self._pred
        u = pred.dw_thr_B_rad_s if pred is not None else np.zeros(3)
        lead = None
        if pred is not None and self.model.sample_kind == "instant":
            lead = pred.lead_s  # time from the burns' centroid to this sample, per channel
        self._obs: ObserverOutput = self.observer.update(self._y, self._free, u, lead)
        if self._pred is None:
            self.model.resync(self._obs.omega_hat_B_rad_s)
        # Strapdown attitude from the measured rate (the integrating gyro's mean rate times h is
        # its angle increment; a rate gyro's: _rate_increment).
        if self._tick > 0 or self.integrating:
            if self.integrating:
                self.attitude.update_increment(self._y * self.h, self.h)
            else:
                self.attitude.update_increment(self._rate_increment(pred), self.h)
        self._y_last = (self._tick, self._y.copy())
        self._phi_meas = self._phi_meas + self._y * self.h

    def _rate_increment(self, pred: Prediction | None) -> np.ndarray:
        """A rate gyro's angle increment over the last tick (3,), rad: the trapezoid of the
        samples at both ends, ``h (y[n-1] + y[n]) / 2``, plus where the thrusters' burns sat
        in the tick, ``dangle - h du / 2`` (the onboard model's burn timeline: ``dangle`` the
        integral over the tick of the rate change the burns gave up to each instant, ``du``
        their whole change; 0 for burns centred in the tick). The trapezoid is exact for a
        rate that changes evenly; the burns' term makes it exact for the rectangular burns of
        the model. The rectangle ``h y[n]`` alone, used before, puts every burn at the start of
        the tick: through S004-cart-x's burn the attitude estimate drifted 0.28 deg from the
        truth (0.6 deg in some runs of orel-burn, which then left the 0.8 deg bound), through
        S000's slew 0.26 deg. The burns' term needs the tick's commands to have burnt as
        predicted (not on a tick the plant did not apply); with no previous sample from the
        last tick, the rectangle."""
        h = self.h
        if self._y_last is None or self._y_last[0] != self._tick - 1:
            return self._y * h
        inc = 0.5 * h * (self._y_last[1] + self._y)
        if pred is not None and (self._evidence or not self._fresh):
            inc = inc + pred.dangle_thr_B_rad - 0.5 * h * pred.dw_thr_B_rad_s
        return inc

    def _fit_regressors(self, pred) -> np.ndarray | None:
        """The gyro check's fit noise test inputs of the tick (``detector.gyro_noise_fit``):
        each thruster's learnt equivalent burn, with the latency learnt its change per second
        of command latency, and its partial burns (under a whole tick) split by whether it
        burnt in the interval before (a pulse's tail) or not fully (its head): the on and off
        transients of a pulse, which the equivalent burn holds only to first order, depend on
        where they fall (kalman_cube-hold600 run 19: a limit cycle whose opposite thrusters'
        heads and tails share ticks read 5.6 times the sensor's noise without them). None
        when the test is off, the model gives no burns, or, on a craft with an adaptive
        observer (flex modes), a thruster burns the whole tick: a sustained burn's errors
        there (the flex it drives, the observer's model error) are not a fixed function of the
        burns over a window (orel-burn, the test on the raw residual with those ticks: an
        orbit correction's 107 s burn read as a noise increase in 28 of 60 fault-free runs;
        run 0 on the innovation too), so the test neither learns from those ticks nor judges
        on them. A rigid craft's whole-tick burns are regressors like any other
        (kalman_cube-gyro without them: no noise increase named, 19 of 20 with them)."""
        burn_prev, self._burn_prev = self._burn_prev, np.asarray(pred.burn_s, dtype=float)
        if self.gyro_check.fit_noise2 is None or pred.eff_s is None:
            return None
        burn = self._burn_prev
        bp = burn if burn_prev is None else burn_prev
        whole = self.h - 1e-9
        if self.gyro_check.fit_innovation and (burn >= _FIT_SKIP_BURN * self.h - 1e-9).any():
            return None  # a sustained burn on a flexible craft (docstring)
        partial = (burn > 0.0) & (burn < whole)
        parts = [self.effectiveness.k * pred.eff_s]
        if pred.deff_dlat is not None:
            parts.append(pred.deff_dlat)
        parts += [(partial & (bp < whole)).astype(float), (partial & (bp > 0.0)).astype(float)]
        return np.concatenate(parts)

    def stage_detector(self) -> None:
        """Gyro check, residual, integral residuals, effectiveness, Kalman leak test, FDIR."""
        w_hat = self._obs.omega_hat_B_rad_s
        pred = self._pred
        avail = self.fdir.available
        if pred is not None and not self._evidence:
            # Not evidence (begin): skip every evidence update of this tick.
            self._omega_pred = pred.omega_calc_B_rad_s
            self.gyro_check.skip(self._y)
            self._burn_prev = np.asarray(pred.burn_s, dtype=float)
            self._held = None
            self._deferred_learning = None
            self._det_out = self.detector.skip(w_hat - self._omega_pred)
            self._w_prev = w_hat.copy()
            self.model.resync(w_hat)
            if self.kalman is not None:
                if self._fresh:  # the burns it would be told of did not happen: restart
                    self.kalman.reset(self._phi_meas, w_hat)
                else:  # a propagated sample agrees with the model: keep the filter going
                    burn_dw = self.arrays.mu_B_rad_s2.T @ (self.effectiveness.k * pred.burn_s)
                    on_axis = np.abs(self.detector.e_B[pred.burning]).max(axis=0,
                                                                          initial=0.0) > 0.1
                    self.kalman.update(self._phi_meas, burn_dw, pred.dangle_thr_B_rad, ~on_axis)
            self._det = None
            return
        if pred is None:
            self._omega_pred = w_hat.copy()
            self.gyro_check.step(self._y, np.zeros(3), 0.0)
            self._det_out = self.detector.step(self._tick, np.zeros(3), np.zeros(self.n, bool),
                                               avail)
            # The first tick carries no residual: do not let it age the residuals.
            det = None
        else:
            self._omega_pred = pred.omega_calc_B_rad_s
            change = pred.omega_calc_B_rad_s - self._w_prev
            inc = None
            if pred.eff_s is not None:
                inc = self.arrays.mu_B_rad_s2 * (self.effectiveness.k * pred.eff_s)[:, None]
            verdict = self.gyro_check.step(self._y, change, pred.dw_thr_abs_rad_s, inc,
                                           self._obs.innovation_B_rad_s,
                                           self._fit_regressors(pred))
            if self._noisy_level2 is not None:
                self._raw_recent.append((self._tick, np.asarray(verdict.residual, dtype=float)))
                del self._raw_recent[:-_NOISY_TICKS - 1]
            confirmed = self._confirmed(verdict, pred) if self._confirm is not None else None
            latched = self.detector.latched
            if verdict.fault is not None and latched is not None and latched.kind != GYRO_FAULT:
                # Single fault: a thruster fault is latched and not yet answered, so the rate
                # moving without the model is that thruster, not a second (sensor) fault. The
                # tick stays out of the evidence as the check says; only the naming is dropped.
                verdict = replace(verdict, fault=None)
            pred = self._remembered(pred)
            self.detector.noise_ratio = self.gyro_check.noise_ratio()
            dw = w_hat - self._omega_pred
            det = None
            if verdict.fault is not None:
                det = Detection(tick=self._tick, thruster=-1, kind=GYRO_FAULT, group=(),
                                names=(verdict.fault,), rho=float(np.linalg.norm(
                                    verdict.residual)), source="gyro")
            if verdict.resync:
                self._resync_on_gyro()
            deferred, self._deferred_learning = self._deferred_learning, None
            if verdict.taint_previous:
                # The last tick's evidence was the sensor: the residuals restart (no blind
                # ticks); its learning, deferred, is dropped.
                self.detector.rebaseline(hold_ticks=0)
                self._window = []
                self._leak_window = []
            elif deferred is not None:
                self._learn(*deferred)
            held, self._held = self._held, None
            if held is not None and not verdict.drop_previous:
                # A held jump the next tick showed to be dynamics: commit it first.
                d_held = self._commit(*held)
                det = det or d_held
            if verdict.hold:
                self._held = (self._tick, dw, pred, avail, self._obs.innovation_B_rad_s, True,
                              verdict.residual)
                self._det_out = self.detector.skip(dw)
            elif verdict.suspect:
                self._det_out = self.detector.skip(dw)
            else:
                d_now = self._commit(self._tick, dw, pred, avail, self._obs.innovation_B_rad_s,
                                     learn=not verdict.defer_learning, raw=verdict.residual)
                det = det or d_now
            det = det or confirmed
        self._w_prev = w_hat.copy()
        if self.detector.cfg.flex_share > 0.0:
            self._u_abs_last = self._u_abs(pred, avail)
        settling = self._gyro_settle > 0
        if settling:
            self._gyro_settle -= 1
        if self.kalman is not None and pred is not None:
            burn_dw = self.arrays.mu_B_rad_s2.T @ (self.effectiveness.k * pred.burn_s)
            on_axis = np.abs(self.detector.e_B[pred.burning]).max(axis=0, initial=0.0) > 0.1
            self.kalman.update(self._phi_meas, burn_dw, pred.dangle_thr_B_rad, ~on_axis)
            if settling and self._gyro_settle == 0:
                # settled: the filter starts again from the observer's rate, its quiet window
                # empty
                self.kalman.reset(self._phi_meas, self._obs.omega_hat_B_rad_s)
            if det is None and self.detector.latched is None and self._probe is None \
                    and not settling and not self._gyro_suspect():
                leak = self.kalman.leak_test(self.fdir.available)
                if leak is not None:
                    i = leak.thruster
                    group = tuple(j for j in self.detector.groups[i] if self.fdir.available[j])
                    found = Detection(tick=self._tick, thruster=i, kind=STUCK_ON, group=group,
                                      names=tuple(self.arrays.names[j] for j in group),
                                      rho=leak.projection_rad_s2, source="kalman")
                    # The disturbance state carries what a failing thruster's burns left in
                    # it into the quiet ticks, where it reads as the opposite thruster's
                    # leak: the two hypotheses are fitted as for the detector's crossings.
                    det = self._settle(self._isolate_opposite(found, self.fdir.available),
                                       found)
        weak, self._weak = self._weak, None
        if weak is not None and det is None and self.detector.latched is None \
                and self._probe is None and not self._gyro_suspect() and self.fdir.available[weak]:
            det = self._settle(*self._weak_detection(weak))
        dc = self.detector.cfg
        if dc.leak_fit_min is not None and det is None and self.detector.latched is None \
                and self._probe is None and not self._gyro_suspect():
            det = self._leak_fit()
        self._det = det
        if det is not None:
            resp = self.fdir.handle(det.kind, det)
            if resp.rebaseline:
                self.rebaseline()

    def _confirmed(self, verdict, pred: Prediction) -> Detection | None:
        """The crossing held for confirmation (``DetectorCfg.confirm_stuck_on``), judged on
        this tick's raw residual along the thruster's direction (against it for a thruster that
        fails or is weak), on a tick the gyro check passes. A stuck-on goes on, and so does a
        deficit on a tick the thruster is commanded again: at least half of the crossing
        tick's, and above ``_CONFIRM_NOISE`` times the noise of the last ticks' raw residual
        along the direction; a deficit is not undone on a tick the thruster is not commanded
        (nothing back along it). Named now if so; else dropped, and the evidence restarts as
        after ``NEITHER``."""
        det, along0 = self._confirm
        self._confirm = None
        along = _sense(det) * float(np.asarray(verdict.residual)
                                    @ self.detector.e_B[det.thruster])
        if det.kind == STUCK_ON or (pred.eff_s is not None and pred.eff_s[det.thruster] > 0.0):
            ok = self._goes_on(det.thruster, along, along0)
        else:
            ok = along >= 0.0
        if verdict.fault is None and not verdict.suspect and ok:
            return replace(det, tick=self._tick)
        self.unconfirmed_stuck_on += 1
        self._settle(NEITHER, None)
        return None

    def _goes_on(self, j: int, along: float, along0: float) -> bool:
        """Whether a tick's raw residual ``along`` thruster ``j``'s direction goes on from the
        crossing's ``along0``: above ``_CONFIRM_NOISE`` times the noise of the last ticks along
        it, and at least half of the crossing's."""
        return along > _CONFIRM_NOISE * self._noise_along(self.detector.e_B[j]) \
            and along >= 0.5 * along0

    def _noise_along(self, e: np.ndarray) -> float:
        """The noise of the last ticks' raw residual along direction ``e``, from its first
        differences (a leak cancels in them; white noise's residual, itself differenced, has
        three times its variance in them)."""
        a = np.array([w[3] for w in self._window]) @ e if self._window else np.zeros(0)
        return math.sqrt(float(np.mean(np.diff(a) ** 2)) / 3.0) if len(a) > 2 else 0.0

    def _held_for_confirmation(self, det: Detection) -> bool:
        """Whether the crossing ``det`` waits for the next tick (``DetectorCfg.confirm_stuck_on``):
        always, or with ``noisy`` when the ticks before it were noisy along the thruster: the
        lag-one autocovariance ``-mean(a(k) a(k-1))`` of the raw residual along it, over the
        last ``_NOISY_TICKS`` ticks before the crossing's (every tick the gyro check judged,
        held ones included), above the square of the every-tick noise
        level (white gyro noise of sigma gives sigma^2, flight.gyro_check; a leak's onset steps
        one way and stays there, which gives products of the other sign)."""
        if self._noisy_level2 is None:
            return bool(self.detector.cfg.confirm_stuck_on)
        win = [r for k, r in self._raw_recent if k < det.tick][-_NOISY_TICKS:]
        if len(win) < 2:
            return False
        a = np.array(win) @ self.detector.e_B[det.thruster]
        return float(np.mean(-a[1:] * a[:-1])) > self._noisy_level2

    def _leak_fit(self) -> Detection | None:
        """Leak-fit test (``DetectorCfg.leak_fit_*``): the stuck-on detection it makes on this
        tick, or None."""
        dc = self.detector.cfg
        if len(self._leak_window) < dc.leak_fit_ticks:
            self._leak_streak = (-1, 0)
            self._onset_streak = (-1, 0)
            self._long_streak = (-1, 0)
            return None
        avail = self.fdir.available
        if not dc.leak_fit_short:  # the long fit alone (no onset fit either: validated)
            return self._leak_fit_long(avail)
        win = self._leak_window[-dc.leak_fit_ticks:]
        sw = 1.0 / np.sqrt(np.array([w[2] for w in win]))     # (W,) 1 / sigma per tick
        raw = np.array([w[0] for w in win]) * sw[:, None]      # (W, 3) in sigmas
        eff = np.array([w[1] for w in win])                    # (W, N)
        closed = (self.h - np.clip(eff, 0.0, self.h)) * sw[:, None]
        det = self._leak_fit_whole(raw, eff, closed, sw, avail)
        if det is None and dc.leak_fit_onset_ticks is not None \
                and self._leak_seen >= _ONSET_AFTER * dc.leak_fit_ticks:
            det = self._leak_fit_onset(raw, eff, closed, sw, avail)
        if det is None and dc.leak_fit_long_ticks is not None:
            det = self._leak_fit_long(avail)
        return det

    def _leak_fit_long(self, avail: np.ndarray) -> Detection | None:
        """The leak-fit test over the long window (``DetectorCfg.leak_fit_long_ticks``): a small
        leak, a few noise levels a tick, fitted over many ticks, from the onset tick that fits
        best (with at least half the window's ticks from it: a thruster that burnt early in
        the window and not since would fit a later onset by its pattern alone, and half a
        period of a slow flex mode's ringing, 4.4 s at 0.11 Hz, fits a short onset), on the
        ticks with no thruster burning only (so no burning thruster's deficit or excess is a
        rival). Its rivals, the other direction groups' leaks from their own best onsets, must
        leave ``_LONG_MARGIN`` noise variances more than it: over a long window a ratio would
        ask more of the direction than neighbours have."""
        dc = self.detector.cfg
        win = self._leak_window
        if len(win) < dc.leak_fit_long_ticks:
            self._long_streak = (-1, 0)
            return None
        mu = self.arrays.mu_B_rad_s2
        m = int(dc.leak_fit_long_ticks) // 2
        eff = np.array([w[1] for w in win])
        # Only the ticks with no thruster burning (seed 002): on the others what the learning
        # does not know yet of the burns stays in the residual for many ticks, a tenth of a
        # thrust or more, as a small leak does
        quiet = ~(eff > 0.0).any(axis=1)
        sw = np.where(quiet, 1.0 / np.sqrt(np.array([w[2] for w in win])), 0.0)
        raw = np.array([w[0] for w in win]) * sw[:, None]
        closed = (self.h - np.clip(eff, 0.0, self.h)) * sw[:, None]
        rss, c, xx, k0 = _onset_fits(raw, closed * avail.astype(float)[None, :], mu, m)
        if not np.isfinite(rss).any():
            self._long_streak = (-1, 0)
            return None
        j = int(np.argmin(rss))
        group = self.detector.groups[j]
        others = np.array([x not in group for x in range(len(rss))])
        rival = float(rss[others].min()) if others.any() else math.inf
        # The noise level measured by the fit itself (its residual's variance in units of the
        # assumed one): over a long window the assumed level (a third of the dead zone, and
        # what the learning does not know of the burns) is a bound, several times the noise.
        s2 = float(rss[j]) / max(3 * int(quiet.sum()) - 2, 1)
        se = math.sqrt(s2 / float(xx[j]))
        ok = (c[j] >= dc.leak_fit_min and c[j] >= dc.leak_fit_sigma * se
              and rival - float(rss[j]) >= _LONG_MARGIN * s2)
        size = float(c[j])
        if ok and dc.leak_fit_tone:
            beside = self._beside_tones(raw, closed[:, j] * (np.arange(len(win)) >= k0[j]), j,
                                        sw, [w[3] for w in win], dc.leak_fit_min)
            ok, size = beside is not None, size if beside is None else beside
        streak = self._long_streak[1] + 1 if ok and self._long_streak[0] == j else int(ok)
        self._long_streak = (j if ok else -1, streak)
        if not ok or streak < dc.leak_fit_hold:
            return None
        self._long_streak = (-1, 0)
        found = self._leak_found(j, size, avail)
        return self._settle(found, found)

    def _beside_tones(self, raw: np.ndarray, s: np.ndarray, j: int, sw: np.ndarray,
                      ticks: list[int], least: float) -> float | None:
        """Thruster j's leak fitted again beside the flex tones (``DetectorCfg.leak_fit_tone``):
        the leak (regressor ``s`` (W,) from its onset, along its direction; ``raw`` (W, 3) and
        ``s`` weighted by ``sw`` (W,)) jointly with a sine and a cosine at each frequency the
        observer identifies (one per channel, the same within 2 % taken once), on each axis.
        Returns the joint fit's size when it keeps at least ``least`` and ``_TONE_KEEP`` of
        the leak's size alone, else None (the tones took it: ringing sampled at the same phases
        on every quiet tick); the leak alone's size when there are no tones or too few ticks to
        fit them. Whether the leak is significant is the calling fit's test, on the leak alone:
        twelve more parameters would widen its error in every window, ringing or not."""
        mu = self.arrays.mu_B_rad_s2[j]
        leak = (s[:, None] * mu[None, :]).reshape(-1)            # the leak's regressor
        alone = float(raw.reshape(-1) @ leak) / max(float(leak @ leak), 1e-300)
        if self.observer.kind != "adaptive":
            return alone
        freqs: list[float] = []
        for f in sorted(float(x) for x in self.observer.freq_hz()):
            if f > 0.0 and (not freqs or f > 1.02 * freqs[-1]):
                freqs.append(f)
        t = np.asarray(ticks, dtype=float) * self.h
        w = len(t)
        cols = [leak]
        for f in freqs:
            for g in (np.cos(2.0 * math.pi * f * t), np.sin(2.0 * math.pi * f * t)):
                for a in range(3):
                    z = np.zeros((w, 3))
                    z[:, a] = g * sw
                    cols.append(z.reshape(-1))
        X = np.stack(cols, axis=1)
        y = raw.reshape(-1)
        keep = (X != 0.0).any(axis=1)
        X, y = X[keep], y[keep]
        n, p = X.shape
        if n <= p + 1:
            return alone
        coef, _, rank, _ = np.linalg.lstsq(X, y, rcond=None)
        if rank < p:
            return alone
        c = float(coef[0])
        return c if c >= max(least, _TONE_KEEP * alone) else None

    def _leak_fit_whole(self, raw: np.ndarray, eff: np.ndarray, closed: np.ndarray,
                        sw: np.ndarray, avail: np.ndarray) -> Detection | None:
        """The leak-fit test over the whole window (a leak there from its first tick)."""
        dc = self.detector.cfg
        mu = self.arrays.mu_B_rad_s2
        yy = float((raw * raw).sum())
        fits = []
        for j in np.flatnonzero(avail):
            x = closed[:, j][:, None] * mu[j][None, :]
            xx, xy = float((x * x).sum()), float((x * raw).sum())
            if xx <= 0.0 or xy <= 0.0:
                continue
            rss = max(yy - xy * xy / xx, 0.0)
            c = xy / xx
            se = math.sqrt(max(rss / max(raw.size - 1, 1), 1.0) / xx)
            fits.append((rss, c, se, int(j)))
        if not fits:
            self._leak_streak = (-1, 0)
            return None
        fits.sort()
        rss, c, se, j = fits[0]
        group = self.detector.groups[j]
        rival = next((f[0] for f in fits[1:] if f[3] not in group), None)
        # A deficit of a thruster that burnt (a degraded one) explains a residual against it
        k = self.effectiveness.k
        for i in np.flatnonzero(avail & (eff > 0.0).any(axis=0)):
            x = -(k[i] * eff[:, i] * sw)[:, None] * mu[i][None, :]
            rd = _rss_one(raw, x)
            rival = rd if rival is None else min(rival, rd)
        ok = (c >= dc.leak_fit_min and c >= dc.leak_fit_sigma * se
              and (rival is None or rss < _LEAK_RIVAL_RSS * rival))
        if ok and dc.leak_fit_tone:
            beside = self._beside_tones(raw, closed[:, j], j, sw,
                                        [w[3] for w in self._leak_window[-len(sw):]],
                                        dc.leak_fit_min)
            ok, c = beside is not None, c if beside is None else beside
        streak = self._leak_streak[1] + 1 if ok and self._leak_streak[0] == j else int(ok)
        self._leak_streak = (j if ok else -1, streak)
        if not ok or streak < dc.leak_fit_hold:
            return None
        self._leak_streak = (-1, 0)
        found = self._leak_found(j, c, avail)
        return self._settle(found, found)

    def _leak_found(self, j: int, c: float, avail: np.ndarray) -> Detection:
        """The leak-fit tests' finding: thruster j (its available direction group) stuck on,
        its fitted leak ``c`` as rho."""
        g = tuple(x for x in self.detector.groups[j] if avail[x])
        return Detection(tick=self._tick, thruster=j, kind=STUCK_ON, group=g,
                         names=tuple(self.arrays.names[x] for x in g), rho=float(c),
                         source="leak_fit", fraction=None)

    def _leak_fit_onset(self, raw: np.ndarray, eff: np.ndarray, closed: np.ndarray,
                        sw: np.ndarray, avail: np.ndarray) -> Detection | None:
        """The leak-fit test with the leak's onset inside the window
        (``DetectorCfg.leak_fit_onset_ticks``): each thruster's leak, and each burning
        thruster's deficit as its rival, fitted from the tick it began (``_onset_fits``), so a
        step that began a few ticks ago is not averaged with the quiet ticks before it (the
        adaptive observer takes a stuck thrust in within a few ticks; the raw residual keeps
        it). One parameter more than the fit over the whole window: ``n - 2`` degrees of
        freedom."""
        dc = self.detector.cfg
        mu = self.arrays.mu_B_rad_s2
        m = int(dc.leak_fit_onset_ticks)
        use = avail.astype(float)[None, :]
        rss, c, xx, k0 = _onset_fits(raw, closed * use, mu, m)
        if not np.isfinite(rss).any():
            self._onset_streak = (-1, 0)
            return None
        j = int(np.argmin(rss))
        group = self.detector.groups[j]
        others = np.array([x not in group for x in range(len(rss))]) & np.isfinite(rss)
        rival = float(rss[others].min()) if others.any() else math.inf
        burnt = avail & (eff > 0.0).any(axis=0)
        deficit = math.inf
        rd = None
        if burnt.any():
            rd, cd, _, _ = _onset_fits(raw, -(self.effectiveness.k * eff * burnt) * sw[:, None],
                                       mu, m)
            deficit = float(rd.min())
        dof = max(raw.size - 2, 1)
        se = math.sqrt(max(float(rss[j]) / dof, 1.0) / float(xx[j]))
        sure = c[j] >= dc.leak_fit_onset_min and c[j] >= dc.leak_fit_sigma * se \
            and rss[j] < _LEAK_RIVAL_RSS * rival
        size = float(c[j])
        if sure and dc.leak_fit_tone:
            win = self._leak_window[-dc.leak_fit_ticks:]
            beside = self._beside_tones(raw, closed[:, j] * (np.arange(len(win)) >= k0[j]), j,
                                        sw, [w[3] for w in win], dc.leak_fit_onset_min)
            sure, size = beside is not None, size if beside is None else beside
        ok = sure and rss[j] < _LEAK_RIVAL_RSS * deficit
        if sure and not ok and rd is not None:
            # Only a burning thruster's deficit rivals the leak: when that thruster acts
            # against the leaking one (within _ALIKE_DEG of its opposite: the controller fights
            # the leak with it on every tick, so neither the timing nor the direction tells
            # them apart), probe the pair as for the detector's crossings: two ticks without
            # either, where a leak still pushes and a deficit cannot. A deficit within the
            # admitted thrust errors (the learning's bound) is no fault, and it explains the
            # residual as well: nothing is named then.
            i = int(np.argmin(rd))
            e = self.detector.e_B
            if float(e[i] @ e[j]) <= -math.cos(math.radians(_ALIKE_DEG)) and rss[j] <= rd[i] \
                    and cd[i] > self.effectiveness.bound and \
                    self._tick - self._probed.get((i, j), -10**9) >= _ISOLATION_TICKS:
                self._probed[(i, j)] = self._tick
                self._onset_streak = (-1, 0)
                found = self._leak_found(j, c[j], avail)
                self._probe = (found, (i, j), _PROBE_TICKS)
                return self._settle(None, found)
        streak = self._onset_streak[1] + 1 if ok and self._onset_streak[0] == j else int(ok)
        self._onset_streak = (j if ok else -1, streak)
        if not ok or streak < dc.leak_fit_onset_hold:
            return None
        self._onset_streak = (-1, 0)
        found = self._leak_found(j, size, avail)
        return self._settle(found, found)

    def _leak_probe_decide(self, det: Detection, pair: tuple[int, int]) -> Detection | None:
        """After the probe of a leak-fit finding (``_leak_fit_onset``): j's leak against i's
        deficit, each fitted from its best onset over the window with the probe's ticks in it
        (where a leak still pushes and a deficit cannot); the better fit is named: j stuck on,
        or i degraded or failing with the thrust fraction the deficit's fit leaves. ``NEITHER``
        when neither fits, or the deficit is within the admitted thrust errors."""
        i, j = pair
        win = self._leak_window[-self.detector.cfg.leak_fit_ticks:]
        sw = 1.0 / np.sqrt(np.array([w[2] for w in win]))
        raw = np.array([w[0] for w in win]) * sw[:, None]
        eff = np.array([w[1] for w in win])
        mu = self.arrays.mu_B_rad_s2[[j, i]]
        s = np.stack([(self.h - np.clip(eff[:, j], 0.0, self.h)) * sw,
                      -self.effectiveness.k[i] * eff[:, i] * sw], axis=1)
        rss, c, _, _ = _onset_fits(raw, s, mu, int(self.detector.cfg.leak_fit_onset_ticks))
        if not np.isfinite(rss).any():
            return NEITHER
        avail = self.fdir.available
        if rss[0] <= rss[1]:
            return replace(det, tick=self._tick, source="isolation")
        # The deficit fits better: its size is what i's burns lack from its onset on
        # (the fit's own estimate, over the probe's ticks too); within the admitted thrust
        # errors it is no fault (NEITHER).
        if c[1] <= self.effectiveness.bound:
            return NEITHER
        frac = float(min(max(1.0 - c[1], 0.0), 1.0))
        kind = DEGRADED if frac >= self.detector.cfg.fail_fraction else FAIL_TO_FIRE
        group = tuple(g for g in self.detector.groups[i] if avail[g])
        return Detection(tick=self._tick, thruster=i, kind=kind, group=group,
                         names=tuple(self.arrays.names[g] for g in group),
                         rho=float(self.detector.rho_on[i]), source="isolation", fraction=frac)

    def _weak_detection(self, i: int) -> tuple[Detection | None, Detection | None]:
        """The burn-fraction test named thruster ``i``: ``(what is named, what was found)`` for
        ``_settle``, degraded, or fails to fire below ``fail_fraction`` (the fraction its last
        burns showed), judged against an exactly opposite thruster as the detector's crossings
        are; ``(None, None)`` (nothing named now) when another thruster's leak explains the
        last ticks' residual better than i's deficit."""
        avail = self.fdir.available
        if self._window and self._pulse_frac is None:
            # (A test's pulses fired i alone between quiet ticks and were read against them: a
            # leak of another thruster is on those too and cancels.)
            # A thruster stuck on and fought by i takes from i's burns too, and while i burns
            # on every tick the timing cannot tell them apart; the direction can: a deficit of
            # i moves the rate against i's direction only, a leak of j along j's. Over the last
            # ticks, fit the raw residual (3 axes) by each (a deficit and a leak of positive
            # size): if some j's leak leaves less than _WEAK_LEAK_RSS of what i's deficit
            # leaves, i is not named now.
            raw = np.array([w[3] for w in self._window])            # (W, 3)
            eff = np.array([w[1] for w in self._window])            # (W, N)
            mu = self.arrays.mu_B_rad_s2
            deficit = -(self.effectiveness.k[i] * eff[:, i])[:, None] * mu[i][None, :]
            closed = self.h - np.clip(eff, 0.0, self.h)
            rss_i = _rss_one(raw, deficit)
            for j in np.flatnonzero(avail):
                if j != i and _rss_one(raw, closed[:, j][:, None] * mu[j][None, :]) \
                        < _WEAK_LEAK_RSS * rss_i:
                    return None, None
        read, pulsed, self._pulse_frac = self._weak_read, self._pulse_frac, None
        if pulsed is not None:
            frac = pulsed
        else:
            frac = float(self.effectiveness.fraction[i] if read is None
                         else self.effectiveness.burn_mean(i, read[0], read[1], small=read[2]))
        dc = self.detector.cfg
        fail = dc.fail_fraction if pulsed is None or dc.pulse_test_fail_below is None \
            else dc.pulse_test_fail_below
        kind = DEGRADED if frac >= fail else FAIL_TO_FIRE
        group = tuple(j for j in self.detector.groups[i] if avail[j])
        found = Detection(tick=self._tick, thruster=i, kind=kind, group=group,
                          names=tuple(self.arrays.names[j] for j in group), rho=frac,
                          source="effectiveness" if pulsed is None else "pulse_test",
                          fraction=frac)
        return self._isolate_opposite(found, avail), found

    def _remembered(self, pred: Prediction) -> Prediction:
        """``pred`` with the commanded effect of the relative dead zone kept from the last
        ticks (``detector.relative_dead_zone_memory``; unchanged when 0)."""
        memory = self.detector.cfg.relative_dead_zone_memory
        if memory <= 0.0:
            return pred
        carried = memory * self._commanded_kept
        sustained = float(np.max(pred.burn_s, initial=0.0)) >= _SUSTAINED * self.h
        self._commanded_kept = max(pred.dw_thr_abs_rad_s if sustained else 0.0, carried)
        return replace(pred, dw_thr_abs_rad_s=max(pred.dw_thr_abs_rad_s, carried))

    def _inside(self, dw: np.ndarray, pred: Prediction, avail: np.ndarray) -> bool:
        """Is the residual ``dw`` (3,) inside the detector's dead zone for this tick's
        thrusters (the learnt ellipsoid, the fixed one, or absolute plus relative)?"""
        det = self.detector
        # The flex prediction's uncertainty from a mode frequency not yet known
        # (detector.flex_freq_dead_zone standard deviations per channel; flight/observer.py).
        k = det.cfg.flex_freq_dead_zone
        flex = None
        if k is not None:
            flex = k * self.observer.flex_sigma()
            cap = det.cfg.flex_freq_dead_zone_cap * det.dead_zone_rad_s()
            size = float(np.linalg.norm(flex))
            if size > cap:
                flex = flex * (cap / size)
        if det.cfg.relative_dead_zone_sigma is not None and pred.eff_s is not None:
            cov = self.effectiveness.rate_change_cov(pred.eff_s, avail, pred.deff_dlat)
            share = det.cfg.flex_share
            if share > 0.0:
                # The mode answers the change of the burns (steady firing against a leak
                # holds a steady deflection): the burns along each axis against the last
                # tick's.
                step = self._u_abs(pred, avail) - self._u_abs_last
                cov = cov + np.diag((share * step) ** 2)
            return det.in_learnt_ellipsoid(dw, cov, flex)
        if det.cfg.relative_dead_zone_across is not None and pred.eff_s is not None:
            m = np.linalg.norm(self.arrays.mu_B_rad_s2, axis=1) * np.abs(
                self.effectiveness.k * pred.eff_s)
            return det.in_ellipsoid(dw, m, flex)
        extra = 0.0 if flex is None else float(np.linalg.norm(flex))
        return bool(det.project(dw, pred.dw_thr_abs_rad_s, extra_rad_s=extra)[2])

    def _u_abs(self, pred: Prediction, avail: np.ndarray) -> np.ndarray:
        """(3,) the burning thrusters' rate change along each axis, sum_j |mu_j,axis| eff_j."""
        if pred is None or pred.eff_s is None:
            return np.zeros(3)
        return np.abs(self.arrays.mu_B_rad_s2).T @ np.abs(np.where(avail, pred.eff_s, 0.0))

    def _commit(self, tick: int, dw: np.ndarray, pred: Prediction, avail: np.ndarray,
                eps: np.ndarray, learn: bool = True,
                raw: np.ndarray | None = None) -> Detection | None:
        """Feed one tick's residual to the detector and the observer's innovation ``eps`` (the
        error before the observer's correction: the adaptive observer's residual is only W5 of
        it on switching ticks) to the effectiveness learning."""
        inside = self._inside(dw, pred, avail)
        if raw is not None and not inside and self._inside(raw, pred, avail):
            # The measured rate changed as the model said (the raw residual is inside the
            # dead zone): what the observer's residual shows is its own redistribution
            # between rigid rate and flex (after a long burn), not the dynamics.
            inside = True
        out = self.detector.step(tick, dw, pred.active, avail, pred.dw_thr_abs_rad_s, inside)
        if tick == self._tick:
            self._det_out = out
        if not out.held and pred.eff_s is not None:
            self._window.append((np.asarray(dw, dtype=float), np.asarray(pred.eff_s, float),
                                 not out.dead_zone,
                                 np.asarray(dw if raw is None else raw, dtype=float),
                                 self.effectiveness.updates))
            del self._window[:-_ISOLATION_TICKS]
            if self.detector.cfg.leak_fit_min is not None and self._learns_from(tick):
                # only for the leak-fit test, and not on a test's ticks: every thruster is
                # closed on them but the one pulsed, and what its pulses leave unexplained
                # (their tails, the flex they ring) fits some thruster's leak (iss_rs-envelope
                # run 329: SM-yaw_I named stuck on 6 s after three tests)
                # Each tick's variance: the noise (a third of the dead zone) and what the
                # learning does not know yet of the burning thrusters' thrust (weighted fit).
                var = (self.detector.dead_zone_rad_s() / 3.0) ** 2 + float(np.trace(
                    self.effectiveness.rate_change_cov(pred.eff_s, avail, pred.deff_dlat))) / 3
                self._leak_window.append((self._window[-1][3], self._window[-1][1], var,
                                          int(tick)))
                # ticks of evidence since the window last restarted (start, response, gyro)
                self._leak_seen = self._leak_seen + 1 if len(self._leak_window) > 1 else 1
                dc = self.detector.cfg
                del self._leak_window[:-max(dc.leak_fit_ticks, dc.leak_fit_long_ticks or 0)]
            if self._alike_hold is not None:
                return self._alike_step(np.asarray(dw if raw is None else raw, float), avail)
            if self._probe is not None:
                held_det, pair, left = self._probe
                if held_det is None:  # a probe before any crossing: the detector goes on
                    self._probe = None if left <= 1 else (None, pair, left - 1)
                elif left > 1:
                    self._probe = (held_det, pair, left - 1)
                    return None
                else:
                    self._probe = None
                    if held_det.source == "leak_fit":
                        return self._settle(self._leak_probe_decide(held_det, pair), None)
                    return self._settle(self._isolate_opposite(held_det, avail, decide=True),
                                        None)
            elif out.detection is None and self.detector.latched is None:
                self._suspect(tick, avail)
            if out.detection is not None:
                det = self._isolate_alike(out.detection, avail,
                                          np.asarray(dw if raw is None else raw, float))
                if det is None:  # waiting for the ticks that tell the neighbours apart
                    return self._settle(None, out.detection)
                det = self._settle(self._isolate_opposite(det, avail), out.detection)
                if det is not None and det.kind != GYRO_FAULT and det.source in (
                        "residual", "isolation") and self._held_for_confirmation(det):
                    # Latched, not answered: the next tick confirms or drops it.
                    r = np.asarray(dw if raw is None else raw, dtype=float)
                    self._confirm = (det, _sense(det) * float(r @ self.detector.e_B[det.thruster]))
                    return None
                return det
        if out.detection is None and not out.held and pred.eff_s is not None:
            if learn:
                self._learn(eps, pred, avail, raw, tick)
            else:
                self._deferred_learning = (eps, pred, avail, raw, tick)
        return out.detection

    def _learn(self, eps: np.ndarray, pred: Prediction, avail: np.ndarray,
               raw: np.ndarray | None = None, tick: int | None = None) -> None:
        """One tick of the effectiveness learning (and the latency it may learn); ``raw`` the
        tick's raw residual, for the burn-fraction test's ``weak_raw``; ``tick`` the tick whose
        sample this is (the test pulse reads the sample after its pulse)."""
        # A test's samples are kept as burns (a dead thruster's pulses read 0 there) but teach
        # the scales, leaks and latency nothing (docs/design.md 6.5).
        self.effectiveness.update(eps, pred.eff_s, avail, pred.deff_dlat, raw_B_rad_s=raw,
                                  learn=self._learns_from(tick))
        dc = self.detector.cfg
        if dc.weak_below is not None:
            if self._burn_settling():
                self.effectiveness.forget_burns()  # the test starts afresh after it
                self._weak = None
            else:
                self._weak = self.effectiveness.weak(dc.weak_below, dc.weak_sigma,
                                                     dc.weak_burns, avail, raw=dc.weak_raw)
                self._weak_read = None
                if self._weak is None and dc.weak_degraded_below is not None and \
                        self._tick * self.h >= dc.weak_degraded_after_s:
                    if self._weak_first is None:
                        self._weak_first = self.effectiveness.updates - 1  # this tick's burns
                    # with the small-burn tier set, the small burns summed are read here too,
                    # and always with their raw burns (as that tier reads them)
                    small = self.effectiveness.chunk_small
                    self._weak = self.effectiveness.weak(dc.weak_degraded_below, dc.weak_sigma,
                                                         dc.weak_degraded_burns, avail,
                                                         raw=dc.weak_raw or small,
                                                         first=self._weak_first, small=small)
                    if self._weak is not None:
                        self._weak_read = (dc.weak_degraded_burns, self._weak_first, small)
                if self._weak is None and dc.weak_small_below is not None:
                    self._weak = self.effectiveness.weak(dc.weak_small_below, dc.weak_sigma,
                                                         dc.weak_burns, avail, raw=True,
                                                         small=True)
                    if self._weak is not None:
                        self._weak_read = (dc.weak_burns, 0, True)
        if dc.pulse_test_below is not None:
            if self._weak is not None and self._pulse_testable[self._weak]:
                # The burn-fraction test's finding is a candidate too: the pulses judge it (a
                # healthy 16 that a test had read at 0.92 was named degraded 0.45 by the
                # degraded tier 5.6 s later, orel-envelope run 388).
                j, self._weak = self._weak, None
                if self._pulse is None and tick == self._tick and \
                        (self._pulse_due(j) or j in self._pulse_doubt):
                    self._pulse_doubt.discard(j)
                    self._pulse_queue = [j]
                    self._pulse_next(found=True)
            self._pulse_step(eps, pred, avail, raw, tick)
        if pred.deff_dlat is not None:
            self.model.set_latency_offset(self.effectiveness.latency_s)
        if self.detector.quiet():
            self.effectiveness.trust()

    def _pulse_step(self, eps: np.ndarray, pred: Prediction, avail: np.ndarray,
                    raw: np.ndarray | None, tick: int | None) -> None:
        """The test pulses (``DetectorCfg.pulse_test_below``) on one sample's learning: keep
        the sample of a test tick, read each pulse whose sample and quiet neighbours are all
        kept, and judge; with no test running, queue the thrusters whose burn of this sample
        read short on both residuals (the lowest first, at most ``_PULSE_CANDIDATES``)."""
        dc = self.detector.cfg
        p = self._pulse
        if p is not None:
            i = -1 if tick is None else tick - p["start"] - 1  # the test tick it answers
            if i < 0:
                return
            j = p["j"]
            p["raw"][i] = np.asarray(eps if raw is None else raw, dtype=float)
            p["eff"][i] = float(pred.eff_s[j])
            mu = self.arrays.mu_B_rad_s2[j]
            for k in sorted(set(p["raw"]) - p["read"]):
                if not _pulse_fires(k) or k - 1 not in p["raw"] or k + 1 not in p["raw"]:
                    continue
                # A pulse between two quiet ticks, read on the raw residual against their
                # mean: a structural mode of a few tenths of a hertz moves the rate along the
                # pulse nearly as much on the ticks beside it (a healthy 6 read 0.43-0.44 on
                # two consecutive pulses, orel-fails run 78), and the adaptive observer's
                # innovation takes a pulse's deficit in as flex and lends it to the next.
                p["read"].add(k)
                e = p["eff"][k]
                if e <= 0.0:
                    continue
                c = e * float(mu @ mu)  # the pulse's effect along mu, per unit of thrust
                quiet = [float(r @ mu) for q, r in p["raw"].items()
                         if q <= k + 1 and not _pulse_fires(q)]
                if max(quiet) - min(quiet) > _PULSE_STILL * c:
                    continue  # the structure rings too hard to read the pulse against it
                dw = p["raw"][k] - 0.5 * (p["raw"][k - 1] + p["raw"][k + 1])
                p["reads"].append(float(self.effectiveness.k[j]) + float(dw @ mu) / c)
            reads = p["reads"]
            clear = dc.pulse_test_healthy if dc.pulse_test_clear is None else dc.pulse_test_clear
            if reads and max(reads) >= clear:
                self._pulse_over(j)  # healthy
            elif len(reads) >= dc.pulse_test_count:
                mean = float(np.mean(reads))
                if mean < p["bar"] and self._weak is None:
                    self._pulse_over(j, next_one=False)
                    self._weak, self._weak_read = j, None
                    self._pulse_frac = float(np.clip(mean, 0.0, 1.5))
                else:
                    if mean < dc.pulse_test_healthy:
                        self._pulse_doubt.add(j)
                    self._pulse_over(j)
            return
        if self.detector.latched is not None or self._probe is not None or \
                self._gyro_suspect() or self._burn_settling() or self.fdir.safe_mode or \
                tick != self._tick:
            return
        found = []
        for j in np.flatnonzero(avail & self.fdir.available & self._pulse_testable):
            read = self.effectiveness.last_burn(int(j))
            if read is not None and max(read) < dc.pulse_test_below and self._pulse_due(int(j)):
                found.append((read[0], int(j)))
        if not found and dc.pulse_test_suspect_burns is not None:
            use = avail & self.fdir.available & self._pulse_testable
            use &= np.array([self._pulse_due(int(j)) for j in range(self.n)])
            below = dc.pulse_test_below if dc.pulse_test_suspect_below is None \
                else dc.pulse_test_suspect_below
            j = self.effectiveness.weak(below, 0.0, dc.pulse_test_suspect_burns, use, raw=True,
                                        small=True)
            if j is not None:
                found.append((0.0, int(j)))
        self._pulse_queue = [j for _, j in sorted(found)[:_PULSE_CANDIDATES]]
        self._pulse_next()

    def _pulse_next(self, found: bool = False) -> None:
        """Start the test of the next queued thruster (fired on this tick's allocation);
        ``found``: a burn-fraction tier named it (its mean is judged against
        ``pulse_test_healthy``; a suspicion's against ``pulse_test_suspect_healthy``)."""
        if self._pulse_queue:
            dc = self.detector.cfg
            bar = dc.pulse_test_healthy if found or dc.pulse_test_suspect_healthy is None \
                else dc.pulse_test_suspect_healthy
            self.pulse_tests["started"] += 1
            self._pulse = {"j": self._pulse_queue.pop(0), "start": self._tick, "raw": {},
                           "eff": {}, "read": set(), "reads": [], "bar": bar}

    def _pulse_over(self, j: int, next_one: bool = True, judged: bool = True) -> None:
        """Thruster ``j``'s test ended (``judged``: healthy or named; else abandoned, and it
        may be tested again at once); the next queued one starts (``next_one``)."""
        self._pulse = None
        self.pulse_tests["void" if not judged else "healthy" if next_one else "named"] += 1
        if judged:
            self._pulse_end[j] = self._tick
        if next_one:
            self._pulse_next()
        else:
            self._pulse_queue = []

    def _learns_from(self, tick: int | None) -> bool:
        """Whether the sample of ``tick`` teaches the learnt scales and leaks and enters the
        leak fit's window: not a test's sample with ``pulse_test_learn`` False."""
        return self.detector.cfg.pulse_test_learn or tick is None or tick > self._pulse_sample

    def _pulse_due(self, j: int) -> bool:
        """Whether thruster ``j``'s last judged test ended ``pulse_test_every_s`` ago or more."""
        every = int(round(self.detector.cfg.pulse_test_every_s / self.h))
        return self._tick - self._pulse_end.get(j, -10**9) >= every

    def _pulse_ms(self) -> int:
        """The test pulse (ms): ``pulse_test_ms`` in whole quanta, at least the minimum
        firing, at most the tick less the electrical delay and the off lag (the thrust is
        over by the next sample at the nominal latency)."""
        t = self.vehicle.timing
        tp = self.vehicle.thrust_profile
        q = float(t.pwm_quantum_ms)
        ms = q * math.floor(self.detector.cfg.pulse_test_ms / q + 1e-9)
        lo = q * math.ceil(float(t.min_on_ms) / q - 1e-9)
        room = 1000.0 * self.h - float(tp.electrical_delay_ms) - float(tp.off_lag_ms)
        hi = q * math.floor(room / q + 1e-9)
        return int(min(max(ms, lo), hi))

    def _burn_settling(self) -> bool:
        """An orbit correction burning or trimming, or ended less than ``_WEAK_AFTER_BURN_S``
        ago (the burn-fraction test is off)."""
        if self.burn_state in ("burning", "trimming"):
            return True
        return self._burn_done_tick is not None and \
            (self._tick - self._burn_done_tick) * self.h < _WEAK_AFTER_BURN_S

    def _suspect(self, tick: int, avail: np.ndarray) -> None:
        """Start a probe when a thruster failing and its opposite stuck on are both building
        up alike (module constants ``_SUSPECT_*``)."""
        d = self.detector
        fail = -d.rho_on / d.thresholds_on
        stuck = d.rho_off / d.thresholds_off
        for i in np.flatnonzero(avail & (fail >= _SUSPECT_SHARE)):
            for j in np.flatnonzero(self._iso_opposite[i] & avail & (stuck >= _SUSPECT_SHARE)):
                a, b = float(fail[i]), float(stuck[j])
                if abs(a - b) > _SUSPECT_TIE * max(a, b):
                    continue
                if tick - self._probed.get((int(i), int(j)), -10**9) < _ISOLATION_TICKS:
                    continue
                self._probed[(int(i), int(j))] = tick
                self._probe = (None, (int(i), int(j)), _PROBE_TICKS)
                return

    def _evidence_window(self) -> list[tuple[np.ndarray, np.ndarray, bool, np.ndarray, int]]:
        """The window's ticks from the first one outside the dead zone on: the ticks before the
        fault say nothing of it."""
        first = next((k for k, w in enumerate(self._window) if w[2]), 0)
        return self._window[first:]

    def _isolate_alike(self, det: Detection, avail: np.ndarray,
                       raw: np.ndarray) -> Detection | None:
        """A stuck-on crossing names the thruster the observer's residual points at most; its
        neighbours in direction (within ``_ALIKE_DEG``, their own stuck-on evidence at least
        ``_ALIKE_SHARE`` of the threshold) are judged again by the gyro's raw residual over
        the same ticks (sum of the residual vectors, projected on each unit direction), and
        the best aligned is named, when there are ``_ALIKE_MIN_TICKS`` ticks or more. The
        observer's residual says whether; the raw one says which (orel's adaptive observer
        takes part of a stuck thrust in as flex). With ``alike_wait_ticks``: None, and the next
        ticks decide (``_alike_step``: each neighbour's leak fitted by ``_alike_fit``, the best
        named once clearly better; ``raw``: this tick's raw residual). Without the wait, a
        thruster whose leak alone explains the raw residual is named when the named one's does
        not (``_lone_leak``)."""
        if det.kind != STUCK_ON or not self._window:
            return det
        d = self.detector
        i = det.thruster
        cos = math.cos(math.radians(_ALIKE_DEG))
        cands = [j for j in np.flatnonzero(avail & (d.e_B @ d.e_B[i] >= cos))
                 if d.rho_off[j] >= _ALIKE_SHARE * d.thresholds_off[j]]
        if d.cfg.alike_wait_ticks is not None:
            # one per direction group (its members cannot be told apart), the crossing's own
            reps = [i] + [j for j in cands if j not in d.groups[i]]
            reps = [j for k, j in enumerate(reps)
                    if not any(j in d.groups[r] for r in reps[:k])]
            if len(reps) < 2:
                return det
            self._alike_hold = (det, reps, float(raw @ d.e_B[i]), 0)
            return None
        win = self._evidence_window()
        if len(win) < _ALIKE_MIN_TICKS:
            return det
        fits = self._leak_fits(range(self.n))  # every thruster's, once
        if len(cands) >= 2:
            # Only neighbours whose leak fits the raw residual at a plausible size: a thruster of
            # a long lever arm matches the direction of a smaller one's leak at a few per cent
            # of its own thrust.
            sized = [j for j in cands if fits[0][j] >= _LONE_SIZE[0]]
            total = np.sum([w[3] for w in win], axis=0)
            best = int(max(sized or cands, key=lambda j: (float(total @ d.e_B[j]), j == i)))
            det = self._alike_named(det, best, avail)
        lone = self._lone_leak(det.thruster, avail, fits)
        return det if lone is None else self._alike_named(det, lone, avail)

    def _leak_fits(self, cands) -> tuple[np.ndarray, np.ndarray, float]:
        """Each candidate's leak (one size, not negative: ``mu_j`` times the tick's closed-valve
        time) fitted to the raw residual (3 axes) over the evidence window by least squares:
        (the sizes, as fractions of nominal thrust; what each fit leaves, summed over axes and
        ticks; the raw residual's own sum of squares)."""
        win = self._evidence_window()
        raw = np.array([w[3] for w in win])
        closed = self.h - np.clip(np.array([w[1] for w in win]), 0.0, self.h)
        size, rss = [], []
        for j in cands:
            x = closed[:, j, None] * self.arrays.mu_B_rad_s2[j][None, :]
            xx = float(np.sum(x * x))
            a = max(float(np.sum(x * raw)) / xx, 0.0) if xx > 0.0 else 0.0
            size.append(a)
            rss.append(float(np.sum((raw - a * x) ** 2)))
        return np.array(size), np.array(rss), float(np.sum(raw * raw))

    def _lone_leak(self, named: int, avail: np.ndarray,
                   fits: tuple[np.ndarray, np.ndarray, float]) -> int | None:
        """The thruster whose leak alone explains the raw residual over the evidence ticks, when
        the named one's does not (``_LONE_*``); None otherwise. ``fits``: every thruster's
        (``_leak_fits``)."""
        size, rss, energy = fits
        if energy <= 0.0:
            return None
        explained = 1.0 - rss / energy
        if explained[named] >= _LONE_NAMED:
            return None
        ok = avail & (size >= _LONE_SIZE[0]) & (size <= _LONE_SIZE[1])
        ok[list(self.detector.groups[named])] = False
        k = int(np.argmax(np.where(ok, explained, -np.inf)))
        return k if ok[k] and explained[k] >= _LONE_EXPLAINED else None

    def _alike_fit(self, cands: list[int]) -> tuple[int, float]:
        """Each candidate's leak fitted to the raw residual over the evidence window
        (``_leak_fits``); returns the best candidate and how much less it leaves than the next,
        in noise variances (a third of the dead zone, squared, per axis and tick)."""
        _, rss, _ = self._leak_fits(cands)
        order = np.argsort(rss, kind="stable")
        var = (self.detector.dead_zone_rad_s() / 3.0) ** 2
        return int(cands[order[0]]), (rss[order[1]] - rss[order[0]]) / max(var, 1e-300)

    def _alike_named(self, det: Detection, j: int, avail: np.ndarray) -> Detection:
        """``det`` naming ``j`` (its direction group) instead, when ``j`` is not in it."""
        if j in det.group or j == det.thruster:
            return det
        d = self.detector
        group = tuple(g for g in d.groups[j] if avail[g])
        return replace(det, thruster=j, group=group,
                       names=tuple(self.arrays.names[g] for g in group),
                       rho=float(d.rho_off[j]), source="isolation")

    def _alike_step(self, raw: np.ndarray, avail: np.ndarray) -> Detection | None:
        """One tick of the wait for the neighbours of a stuck-on crossing to be told apart
        (``DetectorCfg.alike_wait_ticks``): the tick must go on along the crossing's direction
        as a confirmation does (else the crossing is dropped, as an unconfirmed one); the best
        fit is named once clearly better or when the wait is over (no confirmation after it:
        the ticks waited were one)."""
        det, reps, along0, waited = self._alike_hold
        self._alike_hold = None
        if not self._goes_on(det.thruster, float(raw @ self.detector.e_B[det.thruster]), along0):
            self.unconfirmed_stuck_on += 1
            return self._settle(NEITHER, None)
        waited += 1
        best, margin = self._alike_fit(reps)
        if margin < _ALIKE_MARGIN and waited < self.detector.cfg.alike_wait_ticks:
            self._alike_hold = (det, reps, along0, waited)
            return None
        named = self._alike_named(replace(det, tick=self._tick), best, avail)
        return self._settle(self._isolate_opposite(named, avail), named)

    def _isolate_opposite(self, det: Detection, avail: np.ndarray,
                          decide: bool = False) -> Detection | None:
        """A failed (or degraded) thruster and a stuck-on opposite one move both residuals
        alike on the ticks the failed one fires; the ticks where neither fires tell them apart
        (a leak still pushes). Over the last ticks, fit both hypotheses to the residual
        (``flight.detector.leak_or_deficit``) and name the one that fits clearly better. When
        neither does, return None and probe (``_PROBE_TICKS``); after the probe (``decide``)
        the better fit is named. ``NEITHER`` when the deficit fits better but the thruster's
        own burns show its full thrust (``_settle`` latches nothing then)."""
        if det.kind not in (STUCK_ON, FAIL_TO_FIRE, DEGRADED) or not self._window:
            return det
        d = self.detector
        mu_abs = np.linalg.norm(self.arrays.mu_B_rad_s2, axis=1)
        k = self.effectiveness.k
        # From the first tick outside the dead zone on: the ticks before the fault say nothing
        # of it (a leak fitted over them would be judged by ticks it did not exist on).
        win = self._evidence_window()
        dw = np.array([w[3] if d.cfg.isolation_raw else w[0] for w in win])
        eff = np.array([w[1] for w in win])
        closed = self.h - np.clip(eff, 0.0, self.h)
        if det.kind == STUCK_ON:
            j = det.thruster
            rivals = [i for i in np.flatnonzero(self._iso_opposite[j] & avail)
                      if -d.rho_on[i] >= 0.5 * d.thresholds_on[i]]
        else:
            i0 = det.thruster
            rivals = [j for j in np.flatnonzero(self._iso_opposite[i0] & avail)
                      if d.rho_off[j] >= 0.5 * d.thresholds_off[j]]
        for r in rivals:
            i, j = (int(r), det.thruster) if det.kind == STUCK_ON else (det.thruster, int(r))
            ratio = leak_or_deficit(dw @ d.e_B[i], mu_abs[i] * k[i] * eff[:, i],
                                    mu_abs[j] * closed[:, j])
            need = 1.0 if decide else _ISOLATION_RATIO
            if det.kind == STUCK_ON:
                lead = (d.rho_off[j] / d.thresholds_off[j]) / (-d.rho_on[i] / d.thresholds_on[i])
            else:
                lead = (-d.rho_on[i] / d.thresholds_on[i]) / (d.rho_off[j] / d.thresholds_off[j])
            if not decide and 1.0 / need <= ratio <= need and lead < 1.0 + _SUSPECT_TIE:
                # Neither the fit nor the residuals' own lead (ticks that only one of the two
                # hypotheses explains) tells them apart: probe.
                self._probe = (det, (i, j), _PROBE_TICKS)
                return None
            if det.kind == STUCK_ON and ratio > need:
                frac = self.effectiveness.fraction_since(i, win[0][4])
                eff_bound = self.effectiveness.bound
                if eff_bound > 0.0 and self.effectiveness.fraction_since(
                        i, win[0][4], healthiest=True) >= 1.0 - eff_bound:
                    # The deficit of i fits better, but i's own burns show its thrust within
                    # the admitted errors: neither hypothesis holds (the detector's own rule
                    # for a fails-to-fire crossing). Seen in real time on kalman_cube: a
                    # "degraded" thruster at 105 % of its thrust.
                    return NEITHER
                kind = DEGRADED if frac >= d.cfg.fail_fraction else FAIL_TO_FIRE
                who = i
                rho = float(d.rho_on[i])
            elif det.kind != STUCK_ON and ratio < 1.0 / need:
                kind, who, frac, rho = STUCK_ON, j, None, float(d.rho_off[j])
            else:
                continue
            group = tuple(g for g in d.groups[who] if avail[g])
            return Detection(tick=self._tick, thruster=who, kind=kind, group=group,
                             names=tuple(self.arrays.names[g] for g in group), rho=rho,
                             source="isolation", fraction=frac)
        # After a probe the detection is the pair's fit, on this tick (source "isolation");
        # the replay of the residuals (hil campaign sweep) sees only the detector's crossings.
        return replace(det, tick=self._tick, source="isolation") if decide else det

    def _settle(self, det: Detection | None, found: Detection | None) -> Detection | None:
        """Latch what the isolation named (``det``; while a probe runs, None: ``found`` is
        held). ``NEITHER`` (neither hypothesis of the pair holds): nothing is latched, the
        residuals and the leak test restart on the next ticks."""
        if det is NEITHER:
            self.detector.rebaseline(hold_ticks=0)
            self._window = []
            self._leak_window = []
            self._probe = None
            self._alike_hold = None
            if self.kalman is not None:
                self.kalman.reset(self._phi_meas, self._obs.omega_hat_B_rad_s)
            self.detector.latched = None
            return None
        self.detector.latched = det if det is not None else found
        return det

    def _gyro_suspect(self) -> bool:
        return self._held is not None or self.gyro_check.suspect

    def _resync_on_gyro(self) -> None:
        """The output jumped without the dynamics: estimators restart on the new output."""
        self.observer.resync(self._y)
        self._obs = self.observer._out(self._obs.innovation_B_rad_s, self._obs.switching)
        self.model.resync(self._obs.omega_hat_B_rad_s)
        if self.kalman is not None:
            self.kalman.reset(self._phi_meas, self._obs.omega_hat_B_rad_s)
        # The thruster evidence restarts with the estimators and waits for them to settle, as
        # after a response (after a freeze the craft may be turning fast: the Kalman filter
        # restarted on the first live sample took the rest for a disturbance, and kalman_cube
        # named a thruster after 8 of 20 freezes). An unanswered thruster detection stays
        # latched (single fault); one waiting for its confirmation was the sensor.
        if self.detector.latched is None or self._confirm is not None \
                or self._alike_hold is not None:
            self._confirm = None
            self._settle(NEITHER, None)
            self.detector.rebaseline(hold_ticks=self.detector.cfg.response_hold_ticks)
            self._gyro_settle = self.detector.cfg.response_hold_ticks

    def stage_controller(self) -> None:
        """Seed 004 phase plane (or seed 002 s-law) on the estimated attitude and rigid rate,
        predicted ``lead_s`` ahead (``_lead_state``)."""
        lam, w = self._lead_state()
        self._demand: RateDemand = self.controller.demand(lam, w, self.target_TO)

    def _lead_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Attitude and rigid rate when this tick's command takes effect, ``lead_s`` after
        the nominal: the rate changed by what the commands already given still burn until
        then (the onboard model's burn timeline, learnt effectiveness) and by the free
        dynamics; the attitude turned by the mean rate. Without a lead, the estimate."""
        lam, w = self.attitude.Lambda_BO, self._obs.omega_hat_B_rad_s
        if self.lead_s <= 0.0:
            return lam, w
        tl = self.model.timeline
        burn = tl.carried_burn(tl.latency_s - self.lead_s, tl.latency_s)
        dw = self.arrays.mu_B_rad_s2.T @ (self.effectiveness.k * burn) \
            + self._free * (self.lead_s / self.h)
        w_lead = w + dw
        lam_lead = propagate(lam, w + 0.5 * dw, self.lead_s, self.attitude.w0_rad_s)
        return lam_lead, w_lead

    def stage_allocator(self) -> None:
        """LP allocation over the available thrusters, quantisation, prediction."""
        av = self.fdir.available
        if self._probe is not None:
            av = av.copy()
            av[list(self._probe[1])] = False
        if self.fdir.safe_mode or not av.any():
            self._alloc = None
            self._on_ms = np.zeros(self.n, dtype=int)
            return
        p = self._pulse
        if p is not None:
            i = self._tick - p["start"]  # the test's tick
            if self.detector.latched is not None or not av[p["j"]] or \
                    self.burn_state in ("burning", "trimming") or \
                    i >= _pulse_ticks(self.detector.cfg.pulse_test_count):
                # overtaken, or too many of its samples not kept (the gyro check held or
                # skipped them) to read its pulses: no verdict
                self._pulse_over(p["j"], next_one=False, judged=False)
                p = None
        if p is not None:
            # A test's tick: quiet, or the thruster alone (_pulse_fires); every other
            # thruster waits.
            self._alloc = None
            self._on_ms = np.zeros(self.n, dtype=int)
            self.pulse_tests["ticks"] += 1
            self._pulse_sample = self._tick + 1
            if _pulse_fires(i) and i < _pulse_ticks(self.detector.cfg.pulse_test_count) - 1:
                self._on_ms[p["j"]] = self._pulse_len_ms
            return
        d = self._demand
        oc = self.orbit_correction
        if oc is not None and self.burn_state != "done" and self._tick * self.h >= oc.start_s:
            self._alloc = self._burn_tick(oc, d, av)
        else:
            self._alloc: Allocation | None = self.allocator.allocate(
                d.dw_down_B_rad_s, d.dw_up_B_rad_s, av)
        self._on_ms = np.asarray(self._alloc.on_ms, dtype=int)

    def _burn_tick(self, oc, d: RateDemand, av: np.ndarray) -> Allocation:
        """One tick of an orbit correction: the main burn with attitude held by off-times
        (seed 004 eq. 3.4, roll from pairs eq. 3.3), then what is left of the lateral
        components by the 6-channel LP; done when the predicted delta-v is within tolerance."""
        rem = np.asarray(oc.delta_v_B_m_s, dtype=float) - self.dv_given_B_m_s
        tol = oc.tolerance_m_s
        if np.all(np.abs(rem) <= tol):
            self.burn_state = "done"
            self._burn_done_tick = self._tick
            # The burn's end is the flight's own large change of the dynamics (several
            # thrusters that burnt every tick for minutes stop at once): the structure rings
            # for tens of seconds after, and the quiet ticks' level learnt before the burn
            # would call that a noisier gyro (orel-burn: 11 of 60 runs). Learnt again, as after
            # an FDIR response.
            self.gyro_check.restart_noise()
            return self.allocator.allocate(d.dw_down_B_rad_s, d.dw_up_B_rad_s, av)
        idx = [self.vehicle.thruster_index(b) for b in oc.burn]
        along = self.allocator.acc[idx].sum(axis=0)
        main = float(rem @ along) / max(float(np.linalg.norm(along)), 1e-12)
        if main > tol:
            self.burn_state = "burning"
            alloc = self.allocator.allocate_burn(d.dw_down_B_rad_s, d.dw_up_B_rad_s, idx, av,
                                                 rem)
        else:
            self.burn_state = "trimming"
            alloc = self.allocator.allocate_trim(d.dw_down_B_rad_s, d.dw_up_B_rad_s, av, rem,
                                                 tol)
        self.dv_given_B_m_s = self.dv_given_B_m_s + alloc.dv_pred_B_m_s
        return alloc

    def stage_output(self) -> None:
        """Onboard-model prediction for the next sample with this tick's commands."""
        w_hat = self._obs.omega_hat_B_rad_s
        j_B = q_rotate_inv(self.attitude.Lambda_BO, _Y_ORBIT)
        t_s = self._tick * self.h
        self._free = self.model.free_increment(w_hat, j_B, t_s)
        self._pred = self.model.predict(w_hat, self._on_ms / 1000.0, j_B, t_s,
                                        scale=self.effectiveness.k)

    def finish(self) -> TickOutput:
        """Assemble the tick's output (after every stage ran)."""
        d, o, dt = self._demand, self._obs, self._det_out
        alloc = self._alloc
        k = self.kalman
        return TickOutput(
            tick=self._tick, on_ms=self._on_ms.copy(), manifold_open=self.fdir.manifold_open.copy(),
            detection=self._det, fdir_state=self.fdir.state, safe_mode=self.fdir.safe_mode,
            available=self.fdir.available, omega_meas=self._y.copy(),
            omega_est=o.omega_hat_B_rad_s, omega_pred=np.array(self._omega_pred),
            residual=o.omega_hat_B_rad_s - self._omega_pred, gamma_est=o.gamma_hat_B_rad_s,
            freq_est_hz=o.freq_hat_hz, xi=dt.xi, rho_on=dt.rho_on, rho_off=dt.rho_off,
            threshold_on=float(self.detector.cfg.threshold_on),
            threshold_off=float(self.detector.cfg.threshold_off),
            att_err_rad=d.nu_B_rad.copy(), rate_err=d.rate_err_B_rad_s.copy(),
            dw_down=d.dw_down_B_rad_s.copy(), dw_up=d.dw_up_B_rad_s.copy(),
            dw_pred=np.zeros(3) if alloc is None else alloc.dw_pred_B_rad_s.copy(),
            feasible=True if alloc is None else bool(alloc.feasible),
            disturbance_rad_s2=np.zeros(3) if k is None else k.disturbance_B_rad_s2,
            attitude_BO=self.attitude.Lambda_BO.copy(),
        )

    # ------------------------------------------------------------------ events

    def rebaseline(self) -> None:
        """After an FDIR reconfiguration: restart the residuals and the model's own state."""
        self.detector.rebaseline()
        self._held = None
        self._deferred_learning = None
        self._window = []
        self._leak_window = []
        self._probe = None
        self._confirm = None
        self._alike_hold = None
        self._pulse = None
        self._pulse_frac = None
        self._pulse_queue = []
        self.gyro_check.forget_pending()
        self.gyro_check.restart_noise()
        # The evidence restarts on the new configuration: effectiveness back to its last
        # trusted value (healthy thrusters fought the fault), and the observer's flex state,
        # frequency and influence re-initialised (a stuck thruster's thrust was taken in as
        # "flex" and dragged the frequency to the band's edge).
        self.effectiveness.restore()
        if self.model.shadow is not None:
            self.model.set_latency_offset(self.effectiveness.latency_s)
        if self.observer.kind == "adaptive":
            self.observer.reset(self._obs.omega_hat_B_rad_s)
        self.model.resync(self._obs.omega_hat_B_rad_s)
        if self.kalman is not None:
            self.kalman.reset(self._phi_meas, self._obs.omega_hat_B_rad_s)

    def peer_lost(self) -> None:
        """The shell lost the plant's heartbeat: safe mode (all valves closed)."""
        self.fdir.handle("peer_lost")

    def peer_back(self) -> None:
        """The plant is back: leave safe mode, restart the residuals."""
        resp = self.fdir.handle("peer_back")
        if resp.rebaseline and getattr(self, "_obs", None) is not None:
            self.rebaseline()


def _pulse_fires(i: int) -> bool:
    """Whether tick ``i`` of a test (from 0) fires the pulse: ``_PULSE_LEAD`` quiet ticks,
    then a pulse and a quiet tick in turn."""
    return i >= _PULSE_LEAD and (i - _PULSE_LEAD) % 2 == 0


def _pulse_ticks(count: int) -> int:
    """The most ticks a test of ``count`` pulses lasts: the lead, a pulse and a quiet tick per
    pulse, and room for one more pulse when a sample was not kept."""
    return _PULSE_LEAD + 2 * (count + 1) + 1


def _sense(det: Detection) -> float:
    """+1 for a stuck-on (the residual goes along the thruster's direction), -1 for a
    thruster that fails to fire or is weak (against it)."""
    return 1.0 if det.kind == STUCK_ON else -1.0


def _quat(att: AttitudeCfg | np.ndarray | None) -> np.ndarray:
    if att is None:
        return np.array([1.0, 0.0, 0.0, 0.0])
    if isinstance(att, AttitudeCfg):
        return att.quaternion()
    q = np.asarray(att, dtype=float).reshape(4)
    return q / np.linalg.norm(q)
