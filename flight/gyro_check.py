"""Gyro plausibility check: sensor faults told apart from thruster faults (DESIGN 6.4).

A thruster fault changes the *dynamics*: a stuck-on thruster adds its acceleration on every
tick, a thruster that fails to fire removes its commanded increment on the ticks it is
commanded. A gyro fault changes the *measurement*. Per tick, with the raw one-tick residual

    r(n) = y(n) - y(n-1) - d_free(n-1) - u(n-1)        (3,) rad/s

(the measured rate change minus the onboard model's increment over the tick, before any
observer: the adaptive observer would spread a one-sample error over several ticks), four
signatures no single thruster fault can produce are recognised:

* **frozen output**: the sample repeats exactly on every axis (a rate gyro holding its last
  output; an integrating gyro whose counter stopped gives exact zeros). With sensor noise of
  ``noise_std`` over the bus's 1e-7 rad/s quantum, two repeats in a row on all three axes do
  not happen on a live sensor;
* **spike**: a jump ``r(n)`` the thrusters of the tick cannot explain, followed by the
  opposite jump: ``|r(n) + r(n+1)| < return_fraction |r(n)|`` (one bad sample of a rate gyro),
  or ``r(n+1) = -2 r(n)`` within the same fraction (one bad reading of an integrating gyro's
  counter: the mean rates of the two intervals around it are off by ``+s`` and ``-s``; the
  third tick, ``+s`` again, is kept out too). No thruster fault turns its residual around: a
  stuck-on thruster adds along its direction on every tick, one that fails to fire removes
  along it on every tick it is commanded;
* **bias step**: the same unexplained jump followed by nothing (``|r(n+1)| < return_fraction
  |r(n)|``): the output moved, the dynamics did not. A stuck-on thruster repeats its jump tick
  after tick, so it is never a step, except while it is commanded: it then leaks in the closed
  part of each tick only, so a step is named only out of a calm (``_CALM_TICKS``);
* a held jump is named (spike or bias step) only if the observer's one-step prediction (flex
  included) missed it too, ``_observer_surprised``: a sensor's jump is all innovation, a flex
  mode ringing off the rigid prediction is in ``r`` but not in the innovation of an observer
  that follows it (its swing back to zero is no step); such a jump is still held and dropped;
* "unexplained": with the thrusters' increments of the tick ``u_j = mu_j k_j eff_j`` given,
  the residual is larger than ``jump_rad_s`` plus what the thrusters' errors can put along it
  (the envelope's ``sum_j 0.4 |u_j . r/|r|| + 0.1 |u_j|`` over this tick's thrusters, or on a
  tick without thrust the last tick's, whose late pulses spill over: scale and timing along,
  direction across;
  once learnt, at most 6 times the share of the thrust this run's healthy residuals have
  been) even after taking out up to the whole increment
  of any one of them (``r + c u_j``, ``0 <= c <= 1``: that thruster failed to fire or is
  weak), so a fails-to-fire is never taken for a step. A jump only one such thruster explains
  is evidence at once (its learning deferred a tick); if that thruster is commanded again and
  fires right (more than half its increment) while nothing more comes along the jump, the
  output stepped, and the thruster evidence restarts. A held jump the next tick neither
  explains as the sensor's nor repeats along itself (``r(n+1) . r(n) >= 0.5 |r(n)|^2``, a
  stuck-on thruster) is dropped from the evidence without a name. ``hold_rad_s`` (default the
  jump level) may hold smaller jumps too: they are never named, only kept out unless repeated
  (a vehicle whose detector decides on one tick, iss_rs, keeps a noisy sensor's single large
  ticks out of its evidence this way). Without the increments, larger than
  ``jump_rad_s + explain_factor * sum_j |u_j|``. A jump right after a jump is dynamics going on
  (a stuck-on thruster) and is not held;
* **noise increase**: per axis, the differences of the observer's innovation (the sample
  minus its one-step prediction, flex included; ``r`` when none is given) between consecutive
  quiet ticks (no thrust inside either; a steady residual such as a stuck thruster's cancels,
  and a ringing mode the observer follows is not counted as noise) against the
  axis's long-run level (forgotten with ``slow_forget``, each sample capped at ``_SLOW_CAP``
  times the level, frozen while the gyro is suspect or the axis's window holds three large
  differences, never under the floor from
  ``noise_floor_rad_s``): at least 10 of the last 20 above 5 times the level, for
  ``noise_ticks`` quiet ticks in a row, while the differences look white (lag-one correlation
  between -0.75 and 0; white noise's differences: -0.5, a ringing the observer does not follow:
  near +1, or near -1 at the Nyquist frequency). One step (a thruster starting, a torque) is
  one large difference (three: a second difference), not ten. The rates are with the
  constants;
* **noise increase on every tick** (``lag_noise_rad_s``, for a vehicle that fires on nearly
  every tick and so has almost no quiet ticks): per axis, the raw residual's lag-one
  autocovariance over the last ``_LAG_WINDOW`` consecutive ticks, ``-mean(r(k) r(k-1))``
  without its ``_LAG_TRIM`` largest products. White sensor noise of sigma gives ``sigma^2``
  (the residual holds it differenced) whatever else is independent from tick to tick (the
  thrusters' errors); a leak or a slow ringing only lowers it. Above ``lag_noise_rad_s``
  squared, on an axis whose lag-one correlation is at most ``-_LAG_WHITE``, for
  ``noise_ticks`` ticks in a row: a noise increase; suspect from the first such tick, and
  after the name until no axis's plain mean has read above ``_LAG_AGAIN`` of the level for
  a whole window.

While a jump waits for its next tick, and while the output is frozen or noisy, the gyro is
*suspect*: the flight does not feed the tick to the thruster detector nor to the effectiveness
learning (the evidence stays clean), and after a recognised jump it re-synchronises the observer
and the Kalman filter on the new output. The first recognised fault is reported once
(``fault``: ``spike``, ``bias_step``, ``frozen`` or ``noise``); later anomalies keep the gyro
suspect without a new report (one sensor, one report). After a noise increase the gyro stays
suspect while the quiet ticks' median level is twice the level it was named against.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

SPIKE, BIAS_STEP, FROZEN, NOISE = "spike", "bias_step", "frozen", "noise"
# A quiet tick's square residual enters the long-run noise level capped at this many times it;
# the capped mean of a chi-square(1) settles at _SLOW_BIAS of its mean (E[min(X, 4 m)] = m),
# which the reference divides out.
_SLOW_CAP, _SLOW_BIAS = 4.0, 0.90
# After a noise increase was named the gyro stays suspect while an axis's median level (last
# _BIG_WINDOW quiet differences) is above this many times the level it was named against.
_NOISY_AGAIN = 2.0
# Per axis, of the last _BIG_WINDOW quiet differences at least _BIG_COUNT above _BIG_RATIO times
# the axis's level (a robust order statistic: one step, a thruster starting or a torque, is one
# large difference; noise is many), for noise_ticks ticks in a row. Consecutive differences of
# a second difference are correlated (-2/3), so the binomial does not give the rate: simulated
# on 2e7 ticks of white noise at the level, 5e-8 alarms per tick and axis; with the noise three
# times up, named after 27 quiet ticks (median; 99 % within 100), five times up, 16 (those
# two without the whiteness condition, _WHITE_CORR, which delays a few).
_BIG_WINDOW, _BIG_COUNT, _BIG_RATIO = 20, 10, 5.0
# Lag-one correlation of the window's differences inside which they are white noise (white:
# -0.5, with 20 samples outside this band 2.8 % of the time; a slow oscillation: near +1; one
# at the sampling's Nyquist frequency, the observer ringing with a mode: near -1).
_WHITE_CORR = (-0.75, 0.0)
# An axis with this many of its window above keeps its level (white noise at the level: 1 %
# of the ticks).
_FREEZE_COUNT = 3
# Share of each thruster's increment a healthy tick's residual may reach beyond what the learnt
# effectiveness explains: along the residual (thrust scale 0.85-1.15 twice over and timing) and
# in any direction (2 deg of direction error, with margin).
_ALONG, _ACROSS = 0.4, 0.1
# Learnt share of the thrust in a healthy tick's residual: the slack is _SHARE_K times it (never
# more than the envelope's), after _SHARE_WARMUP thrust ticks; forgotten over ~50 ticks, each
# tick capped at _SHARE_CAP times the mean.
_SHARE_K, _SHARE_WARMUP, _SHARE_FORGET, _SHARE_CAP = 6.0, 25, 0.98, 3.0
# Noise test on every tick (``lag_noise_rad_s``): the raw residual's lag-one autocovariance
# over the last _LAG_WINDOW consecutive ticks, per axis. White sensor noise of sigma enters the
# residual differenced (``n(k) - n(k-1)``), so ``-E[r(k) r(k-1)] = sigma^2`` whatever the
# thrusters do: thrust errors of different ticks are independent (no product on average), a
# leak or a slow flex ringing repeats (a negative contribution). Named when its square root
# is above the level on an axis whose lag-one correlation is at most -_LAG_WHITE (the noise
# dominates that axis's residual: -0.5 for noise alone). The level is the window's mean
# without its _LAG_TRIM largest products per axis (a robust mean: one burst's timing error,
# late in one tick and early in the next, gives two large products of the same sign, with the
# ticks before and after it; noise gives many).
# Once the noise is named, the gyro stays suspect until no axis's plain mean has read above
# _LAG_AGAIN of the level for a whole window (the window's mean of products fluctuates by
# half its value on white noise: a dwell, not one tick below).
_LAG_WINDOW, _LAG_WHITE, _LAG_TRIM, _LAG_AGAIN = 30, 0.35, 2, 0.25
# Noise test on every tick through a fit of the thrusters' errors (``fit_noise_rad_s``): per axis,
# the raw residual of the last _FIT_WINDOW evidence ticks (at least _FIT_DOF more than the fit's
# unknowns) is fitted by least squares on the tick's regressors (given by the flight: each
# thruster's learnt equivalent burn, its change per second of command latency and its partial
# burns as a pulse's head and tail; a thruster's scale, direction and timing errors are fixed over
# a window, so their share of the residual is a fixed linear function of them) and a constant; the
# leftover's lag-one autocovariance over consecutive ticks, per degree of freedom, is the sensor's
# white noise variance (it enters differenced) with the thrusters' systematic errors taken out.
# Named when above the level on an axis whose leftover's lag-one correlation is at most
# -_FIT_WHITE (noise alone: -0.5; the controller's reaction to a noisier sensor adds per-tick
# errors of its own, which lower it: -0.27 to -0.49 under 7e-5 rad/s of noise on kalman_cube) for
# _FIT_TICKS ticks in a row, and suspect from then (not before: a one-tick jump lifts the window's
# level for a few ticks, and the jump tests must see them untouched) until no axis has read above
# _FIT_AGAIN of the level (squared) for a whole window. Judged only once _FIT_WARMUP * _FIT_WINDOW
# evidence ticks (30 s; orel's window is longer, 121 ticks) have gone by since the start or a
# response: a window holding the first pulses after a coast, before the latency and the
# effectiveness are learnt, read up to 7 times the sensor's noise (kalman_cube-hold600 run 2,
# ticks 37-39). Measured on kalman_cube, offline on the recorded residuals (141
# kalman_cube-envelope and 20 kalman_cube-hold600 runs fault-free, 20 kalman_cube-gyro noise
# increases of 3-10 times the sensor's noise): the ten-tick minimum of the level peaked at 2.1
# times the gyro's noise_std fault-free, 3.0 in one 600 s hold (run 16: a limit cycle changing
# pattern); without the heads and tails 5.6 (run 19: opposite thrusters' tails sharing ticks); the
# noise increases crossed 3.5 times it in 19 of 20 runs.
# With ``fit_innovation`` (a flexible craft, orel) the test reads the adaptive observer's
# innovation instead and is given no tick of a sustained burn (FlightSoftware._fit_regressors):
# orel's raw residual holds the flex modes' ringing (0.2-0.9 Hz, correlated from tick to tick: the
# lag-one level read negative, -1.1e-9 (rad/s)^2 on roll in orel-gyro run 71 under a noise 7 times
# the sensor's); the adaptive observer's innovation has the ringing taken out and read that noise
# at 10 times the sensor's (5.2e-5 rad/s), the other axes 0.9-1.7 times. A rigid craft has no
# ringing to take out, and its whole-tick burns are regressors like any other: kalman_cube-gyro
# without them named no noise increase (19 of 20 with them).
_FIT_WINDOW, _FIT_DOF, _FIT_TICKS, _FIT_AGAIN, _FIT_WARMUP = 75, 30, 10, 0.5, 2
_FIT_WHITE = 0.2
# A held jump is named a spike or a bias step only if the observer's innovation along it is at
# least this share of it (``_observer_surprised``). orel-envelope: the in-plane mode ringing at
# 0.92 Hz put 6.0e-4 rad/s into the raw residual with 0.26e-4 in the innovation (4 %), and its
# swing back read as a bias step in runs 70 and 187; a sensor's jump is all innovation (100 %).
_INNOVATION_SHARE = 0.5
# A held jump is named a bias step only out of a calm: the observer's innovation (the raw
# residual without one), and the raw residual as well, along the jump over the _CALM_TICKS
# ticks before it, root mean square, under return_fraction of the jump. The raw residual too:
# a mode the observer does not follow yet (orel-envelope-3 run 365, roll at 1.33 times its
# prior, 6.6 s into a slew) swings the raw residual by 5-9e-4 rad/s along the jump before it
# while the innovation stays quiet, then puts a 1.4e-3 swing into both; named a bias step.
# A sensor's step comes out of whatever the residual was
# (thrust errors, noise: on kalman_cube's limit cycle about 40e-6 rad/s a tick); a thruster
# stuck on while it is commanded leaks only in the closed part of each tick, so its residual
# comes and goes along its direction with the burns (kalman_cube-leaks run 10: Z+ at 15 %,
# 0.1-1.5e-3 rad/s along z for 15 ticks, then a 9.0e-4 rad/s tick followed by 1.7e-4 was
# named a bias step 3.5 s after the onset).
_CALM_TICKS = 10


@dataclass(frozen=True)
class GyroVerdict:
    """One tick of the check. ``suspect``: keep this tick out of the thruster evidence;
    ``drop_previous``: the previous tick (held back as a possible jump) was a gyro error too,
    or no evidence (neither the sensor's pattern nor repeated along itself);
    ``resync``: the output moved without the dynamics (re-synchronise estimators on it);
    ``fault``: newly recognised fault kind (first one only) or None; ``residual`` r (3,);
    ``taint_previous``: the previous tick, already evidence, was a sensor error: the thruster
    evidence restarts; ``defer_learning``: evidence for the detector now, for the effectiveness
    learning only if the next tick does not taint it (a learnt step would move the next
    tick's prediction and hide the step)."""

    suspect: bool
    hold: bool
    drop_previous: bool
    resync: bool
    fault: str | None
    residual: np.ndarray
    taint_previous: bool = False
    defer_learning: bool = False


class GyroCheck:
    """Frozen / spike / bias-step / noise tests on the raw one-tick residual (module doc).

    ``step(y, predicted_change, thrust_abs, increments)``: ``y`` (3,) this tick's sample;
    ``predicted_change`` (3,) the onboard model's rate change over the last tick (free
    dynamics plus thrusters, ``d_free + u``); ``thrust_abs`` the scale of the thrusters'
    share (``sum_j |mu_j| eff_j`` over the tick); ``increments`` (N, 3) each thruster's
    predicted rate change over the tick (``mu_j k_j eff_j``), or None.
    """

    def __init__(self, jump_rad_s: float, noise_floor_rad_s: float, *,
                 explain_factor: float = 1.5, return_fraction: float = 0.3,
                 slow_forget: float = 0.995, noise_ticks: int = 3, warmup_ticks: int = 30,
                 start_ticks: int = 2, hold_rad_s: float | None = None,
                 lag_noise_rad_s: float | None = None,
                 fit_noise_rad_s: float | None = None,
                 fit_innovation: bool = False) -> None:
        self.jump_rad_s = float(jump_rad_s)
        self.hold_rad_s = self.jump_rad_s if hold_rad_s is None else float(hold_rad_s)
        # per axis: a third of the three axes' floor (sensor noise sigma: 18 sigma^2 for the
        # second difference of three axes)
        self.noise_floor2 = float(noise_floor_rad_s) ** 2 / 3.0
        self.explain_factor = float(explain_factor)
        self.return_fraction = float(return_fraction)
        self.slow_forget = float(slow_forget)
        self.noise_ticks = int(noise_ticks)
        self.warmup_ticks = int(warmup_ticks)
        self.fault: str | None = None
        self.suspect = False
        self.start_ticks = int(start_ticks)
        self._calls = 0
        self._y_prev: np.ndarray | None = None
        self._repeats = 0
        self._pending: np.ndarray | None = None
        self._last_fail: tuple[np.ndarray, int] | None = None
        self._pending_named = False
        self._noisy_ref: np.ndarray | None = None
        self._noisy_now = False
        self._innovation: np.ndarray | None = None
        self._u_prev: np.ndarray | None = None
        self._share = 0.0
        self._share_n = 0
        self._run = False
        self._settle = False
        self._r_quiet: np.ndarray | None = None
        self._big: list[np.ndarray] = []
        self._recent: list[np.ndarray] = []
        self._diffs: list[np.ndarray] = []
        self._slow = np.zeros(3)
        self._quiet = 0
        self._over = 0
        self.lag_noise2 = None if lag_noise_rad_s is None else float(lag_noise_rad_s) ** 2
        self._lag: list[np.ndarray] = []      # -r(k) r(k-1), consecutive ticks
        self._lag_sq: list[np.ndarray] = []   # r(k)^2 of the same ticks
        self._lag_last: tuple[int, np.ndarray] | None = None
        self._lag_over = 0
        self._lag_calm = 0  # ticks in a row without noise after it was named
        self.lag_sigma_rad_s = 0.0  # the largest axis's noise the lag test reads (0 until known)
        self.fit_noise2 = None if fit_noise_rad_s is None else float(fit_noise_rad_s) ** 2
        # a flexible craft (adaptive observer): the fit reads the innovation, not the raw
        # residual, and is given no tick of a sustained burn (FlightSoftware._fit_regressors)
        self.fit_innovation = bool(fit_innovation)
        self._fit_rows: list[tuple[int, np.ndarray, np.ndarray]] = []  # (call, r, regressors)
        self._fit_over = 0
        self._fit_calm = 0
        self._fit_seen = 0  # evidence ticks since the start or the last restart
        self.fit_sigma_rad_s = 0.0  # the largest white axis's noise the fit test reads
        self.fit_lag2 = np.zeros(3)  # per axis, the fit's last lag-one level (rad/s)^2
        self._calm: list[np.ndarray] = []  # the last ticks' innovation (raw residual without)
        self._calm_raw: list[np.ndarray] = []  # the last ticks' raw residual

    def forget_pending(self) -> None:
        """The flight changed the dynamics itself (an FDIR response): a held jump is not to be
        judged against the next tick."""
        self._pending = None
        self._last_fail = None
        self._run = False
        self._settle = False
        self._calm = []
        self._calm_raw = []

    def restart_noise(self) -> None:
        """The flight changed the dynamics itself (an FDIR response): the quiet ticks' level
        is learnt again, from a new warm-up (a response leaves the structure ringing, which the
        old level would call a noisier sensor)."""
        self._r_quiet = None
        self._big = []
        self._recent = []
        self._diffs = []
        self._slow = np.zeros(3)
        self._quiet = 0
        self._over = 0
        self._fit_rows = []
        self._fit_seen = 0
        self._fit_over = 0

    def _white(self) -> np.ndarray:
        """Per axis: do the window's differences look like white noise's? The differences of
        white noise have a lag-one correlation of -0.5; an oscillation the observer does not
        follow (a flex mode off its frequency) gives smooth differences, correlation near +1,
        one at the Nyquist frequency near -1. White inside the band _WHITE_CORR."""
        d = np.asarray(self._diffs)
        if len(d) < 3:
            return np.zeros(3, dtype=bool)
        a, b = d[1:], d[:-1]
        num = (a * b).sum(axis=0)
        den = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
        corr = np.divide(num, den, out=np.zeros(3), where=den > 0.0)
        return (corr > _WHITE_CORR[0]) & (corr < _WHITE_CORR[1])

    def noise_ratio(self) -> float:
        """How many times noisier the quiet ticks are now than their long-run level: the
        square root of the ratio of the sums over the axes of the level of the squared
        differences of consecutive quiet ticks' noise input, now (from the median of the last
        ``_BIG_WINDOW``: a chi-square(1) median is 0.455 of the mean) and long-run (the level
        the noise test learns, never under the floor). 1 until both are known."""
        if len(self._recent) < _BIG_WINDOW or self._quiet <= self.warmup_ticks:
            return 1.0
        now = np.median(np.asarray(self._recent), axis=0) / 0.455
        ref = np.maximum(self._slow / _SLOW_BIAS, self.noise_floor2)
        return float(np.sqrt(now.sum() / ref.sum()))

    def skip(self, y: np.ndarray) -> None:
        """A tick whose data is not evidence (sample missing or propagated, command not
        applied): ``y`` becomes the previous output without being judged, a held jump is
        dropped."""
        self._y_prev = np.asarray(y, dtype=float).copy()
        self._r_quiet = None
        self._lag_last = None
        self.forget_pending()

    def _report(self, kind: str) -> str | None:
        if self.fault is not None:
            return None
        self.fault = kind
        return kind

    def step(self, y: np.ndarray, predicted_change: np.ndarray,
             thrust_abs: float, increments: np.ndarray | None = None,
             innovation: np.ndarray | None = None,
             regressors: np.ndarray | None = None) -> GyroVerdict:
        """One tick (class doc); ``regressors`` (M,): the tick's inputs of the fit noise test
        (``fit_noise_rad_s``; each thruster's learnt increment and its latency sensitivity),
        the same layout on every tick."""
        self._innovation = None if innovation is None else np.asarray(innovation, float)
        v = self._step(y, predicted_change, thrust_abs, increments)
        self._calm.append(np.array(v.residual if self._innovation is None else self._innovation))
        del self._calm[:-_CALM_TICKS - 1]
        self._calm_raw.append(np.array(v.residual))
        del self._calm_raw[:-_CALM_TICKS - 1]
        self._u_prev = None if increments is None else np.array(increments, dtype=float)
        if self.lag_noise2 is not None:
            v = self._lag_noise(v)
        if self.fit_noise2 is not None and regressors is not None:
            v = self._fit_noise(v, np.asarray(regressors, dtype=float))
        if self._noisy_now and not v.suspect:
            # A gyro known to be noisy: no tick of it is thruster evidence.
            self._pending = None
            v = replace(v, suspect=True, hold=False, drop_previous=True, defer_learning=False)
        self.suspect = v.suspect
        return v

    def explained(self, r: np.ndarray, thrust_abs: float,
                  increments: np.ndarray | None, base: float | None = None) -> int | None:
        """Can the thrusters of the tick explain the residual ``r``? None: no; -1: yes, as the
        envelope's errors; ``j``: only as thruster ``j`` failing to fire or weak.

        Without ``increments``: ``|r| <= jump + explain_factor * thrust_abs`` (-1). With them:
        the envelope's errors of the thrusters (``_slack``), else after taking out at most the
        whole increment of one thruster of the tick (``r + c u_j``, ``0 <= c <= 1``). A
        stuck-on thruster's first jump is not explained: the next tick tells (it repeats)."""
        base = self.jump_rad_s if base is None else float(base)
        norm = float(np.linalg.norm(r))
        if increments is None:
            ok = norm <= base + self.explain_factor * float(thrust_abs)
            return -1 if ok else None
        u = np.asarray(increments, dtype=float)
        # On a tick without thrust the errors of the last tick's thrusters spill into it (a late
        # or long pulse's tail).
        u_err = u
        if self._u_prev is not None and len(self._u_prev) == len(u) and not u.any():
            u_err = self._u_prev
        if norm <= self._slack(r, u_err, base):
            return -1
        uu = np.einsum("ij,ij->i", u, u)
        best, best_rest = None, np.inf
        for j in np.flatnonzero(uu > 0.0):
            c = min(max(-float(u[j] @ r) / float(uu[j]), 0.0), 1.0)
            rest = r + c * u[j]
            nr = float(np.linalg.norm(rest))
            if nr <= self._slack(rest, u_err, base) and nr < best_rest:
                best, best_rest = int(j), nr
        return best

    def _slack(self, r: np.ndarray, u: np.ndarray, base: float | None = None) -> float:
        """What the thrusters' errors can put into a residual along ``r``, on top of
        ``jump_rad_s``: at most the envelope's (each thruster ``_ALONG`` of its increment's
        share along ``r``, scale and timing, and ``_ACROSS`` of its increment, direction), and
        once learnt (``_SHARE_WARMUP`` thrust ticks) ``_SHARE_K`` times the share of the
        thrust the residual has been on this run's healthy ticks (``_learn_share``)."""
        n = float(np.linalg.norm(r))
        along = np.abs(u @ (r / n)) if n > 0.0 else np.zeros(len(u))
        total = float(np.linalg.norm(u, axis=1).sum())
        env = float(_ALONG * along.sum()) + _ACROSS * total
        if self._share_n >= _SHARE_WARMUP:
            env = min(env, _SHARE_K * self._share * total)
        return (self.jump_rad_s if base is None else base) + env

    def _learn_share(self, r: np.ndarray, u: np.ndarray | None) -> None:
        """A healthy tick with thrust: the residual's share of the thrust, a mean forgotten
        with ``_SHARE_FORGET``, each tick capped at ``_SHARE_CAP`` times the mean."""
        if u is None:
            return
        total = float(np.linalg.norm(u, axis=1).sum())
        if total <= 0.0:
            return
        q = float(np.linalg.norm(r)) / total
        self._share_n += 1
        if self._share_n == 1:
            self._share = q
            return
        if self._share_n > _SHARE_WARMUP:
            q = min(q, _SHARE_CAP * self._share)
        a = max(1.0 - _SHARE_FORGET, 1.0 / self._share_n)
        self._share = (1.0 - a) * self._share + a * q

    def _step(self, y: np.ndarray, predicted_change: np.ndarray,
              thrust_abs: float, increments: np.ndarray | None) -> GyroVerdict:
        y = np.asarray(y, dtype=float)
        prev = self._y_prev
        self._y_prev = y.copy()
        self._calls += 1
        if prev is None or self._calls <= self.start_ticks:
            # Start-up: the first samples may be a sensor's "no data" (an integrating gyro's
            # first count) or the flight's zero before any sample.
            return GyroVerdict(prev is not None, False, False, False, None, np.zeros(3))
        r = y - prev - np.asarray(predicted_change, dtype=float)
        # Frozen output: exact repeats on all axes.
        if np.array_equal(y, prev):
            self._repeats += 1
            fault = self._report(FROZEN) if self._repeats >= 2 else None
            # The jump into the freeze (a held one, or one a thruster's failure explained and
            # already evidence) was the sensor: the held tick is dropped, the committed one
            # taints the evidence (an integrating gyro's counter stopping reads as the rate
            # falling to zero at once; committed, kalman_cube named a thruster after 12 of 20
            # freezes).
            dropped, tainted = self._pending is not None, self._last_fail is not None
            self._pending = None
            self._last_fail = None
            self._r_quiet = None
            return GyroVerdict(True, False, dropped, False, fault, r, taint_previous=tainted)
        was_frozen = self._repeats >= 2
        self._repeats = 0
        if was_frozen:
            # The first live sample after a freeze jumps by whatever the rate did meanwhile.
            self._pending = None
            self._r_quiet = None
            return GyroVerdict(True, False, False, True, None, r)
        if self._settle:
            # The third tick of a doublet (an integrating gyro's counter read wrong once: the
            # mean rate is off by +s, then -s): the output is right again, resynchronise.
            self._settle = False
            self._r_quiet = None
            return GyroVerdict(True, False, False, True, None, r)
        if self._last_fail is not None:
            v = self._after_fail(r, increments)
            if v is not None:
                return v
        continuation = False
        dropped = False
        if self._pending is not None:
            p = self._pending
            pn = float(np.linalg.norm(p))
            named, self._pending_named = self._pending_named, False
            self._pending = None
            kind = None
            settle = False
            # No thruster fault turns its residual around: a stuck-on thruster adds along its
            # direction on every tick, one that fails removes on every tick commanded.
            if not named:
                pass
            elif float(np.linalg.norm(r + p)) < self.return_fraction * pn:
                kind = SPIKE  # one bad sample of a rate gyro: +s, -s
            elif float(np.linalg.norm(r + 2.0 * p)) < 2.0 * self.return_fraction * pn:
                kind, settle = SPIKE, True  # one bad counter reading: +s, -2s, +s
            elif float(np.linalg.norm(r)) < self.return_fraction * pn and self._calm_before(p):
                kind = BIAS_STEP
            if kind is not None:
                self._settle = settle
                self._r_quiet = None
                return GyroVerdict(True, False, True, not settle, self._report(kind), r)
            if float(r @ p) >= 0.5 * pn * pn:
                continuation = True  # the jump repeats along itself: dynamics (stuck on)
            else:
                dropped = True  # neither the sensor's pattern nor a thruster's: not evidence
        why = self.explained(r, thrust_abs, increments, self.hold_rad_s)
        if why is None:
            if continuation or self._run:
                # A jump that follows a jump is dynamics going on (a stuck thruster): commit it
                # now; when it stops (a response, a fault clearing) that is not a gyro step.
                self._run = True
                self._r_quiet = None
                return GyroVerdict(False, False, False, False, None, r)
            self._pending = r.copy()
            self._pending_named = (self.hold_rad_s >= self.jump_rad_s or self.explained(
                r, thrust_abs, increments) is None) and self._observer_surprised(r)
            self._r_quiet = None
            return GyroVerdict(True, True, dropped, False, None, r)
        self._run = False
        if why == -1:
            self._learn_share(r, increments)
        if why >= 0 and not continuation:
            # Only one thruster failing to fire explains the jump: it is evidence now (no
            # delay for a real failure), and judged again on the next tick.
            self._last_fail = (r.copy(), why)
            self._r_quiet = None
            return GyroVerdict(False, False, dropped, False, None, r, defer_learning=True)
        v = self._noise(r if self._innovation is None else self._innovation, thrust_abs)
        v = replace(v, residual=r)
        return replace(v, drop_previous=True) if dropped else v

    def _calm_before(self, p: np.ndarray) -> bool:
        """Were the innovation and the raw residual calm along the held jump ``p`` before it
        (``_CALM_TICKS``)? The ticks before the held one (the last kept is the held tick
        itself), root mean square along ``p`` under ``return_fraction`` of ``|p|`` for each;
        True with no tick before."""
        pn = float(np.linalg.norm(p))
        for hist in (self._calm, self._calm_raw):
            before = hist[:-1]
            if not before or pn == 0.0:
                continue
            along = np.asarray(before) @ (p / pn)
            if float(np.sqrt(np.mean(along * along))) >= self.return_fraction * pn:
                return False
        return True

    def _observer_surprised(self, r: np.ndarray) -> bool:
        """Did the observer's one-step prediction (flex included) miss the jump ``r`` too? Its
        innovation along ``r`` at least ``_INNOVATION_SHARE`` of ``|r|``. A sensor's jump is
        news to every estimator (the whole jump is in the innovation); a flex mode ringing
        off the onboard model's rigid prediction is in the raw residual but not in the
        innovation of an observer that follows the mode, and its swing back to zero a tick
        later is not a bias step. True when no innovation is given."""
        if self._innovation is None:
            return True
        n = float(np.linalg.norm(r))
        return n == 0.0 or float(self._innovation @ r) >= _INNOVATION_SHARE * n * n

    def _lag_noise(self, v: GyroVerdict) -> GyroVerdict:
        """The noise test on every tick (``_LAG_WINDOW``): suspect while an axis reads noisy,
        the noise named after ``noise_ticks`` such ticks in a row. Ticks the other tests hold,
        name or resynchronise on, and frozen ones, are not in it (nor is the tick after)."""
        r = v.residual
        ok = not (v.hold or v.resync or v.fault is not None or v.taint_previous
                  or self._repeats > 0 or self._calls <= self.start_ticks)
        last, self._lag_last = self._lag_last, ((self._calls, r.copy()) if ok else None)
        if ok and last is not None and last[0] == self._calls - 1:
            self._lag = (self._lag + [-r * last[1]])[-_LAG_WINDOW:]
            self._lag_sq = (self._lag_sq + [r * r])[-_LAG_WINDOW:]
        if len(self._lag) < _LAG_WINDOW:
            return v
        lag = np.asarray(self._lag)
        m = np.mean(np.sort(lag, axis=0)[:-_LAG_TRIM], axis=0)  # the level, robust
        white = lag.mean(axis=0) >= _LAG_WHITE * np.mean(self._lag_sq, axis=0)
        noisy = (m > self.lag_noise2) & white
        if self.fault == NOISE:
            if (lag.mean(axis=0) > _LAG_AGAIN * self.lag_noise2).any():
                self._lag_calm = 0
            else:
                self._lag_calm += 1
            noisy = noisy | np.full(3, self._lag_calm < _LAG_WINDOW)
        self.lag_sigma_rad_s = float(np.sqrt(max(float(m.max()), 0.0)))
        if not noisy.any():
            self._lag_over = 0
            return v
        self._lag_over += 1
        fault = v.fault
        if fault is None and self._lag_over >= self.noise_ticks:
            fault = self._report(NOISE)
        self._pending = None
        return replace(v, suspect=True, hold=False, drop_previous=True, fault=fault,
                       defer_learning=False)

    def _fit_noise(self, v: GyroVerdict, x: np.ndarray) -> GyroVerdict:
        """The noise test through a fit of the thrusters' errors (``_FIT_WINDOW``): suspect
        while an axis reads noisy, the noise named after ``_FIT_TICKS`` such ticks in a row.
        The same ticks as the lag test are left out of it."""
        ok = not (v.hold or v.resync or v.fault is not None or v.taint_previous
                  or self._repeats > 0 or self._calls <= self.start_ticks)
        if ok:
            if self._fit_rows and len(self._fit_rows[-1][2]) != len(x):
                self._fit_rows = []
            r = v.residual
            if self.fit_innovation and self._innovation is not None:
                r = self._innovation
            self._fit_rows.append((self._calls, r.copy(), x.copy()))
            self._fit_seen += 1
        window = max(_FIT_WINDOW, len(x) + 1 + _FIT_DOF)
        del self._fit_rows[:-window]
        if self._fit_seen < _FIT_WARMUP * _FIT_WINDOW:
            return v
        calls = np.array([c for c, _, _ in self._fit_rows])
        pairs = calls[1:] == calls[:-1] + 1
        if not pairs.any():
            return v
        r = np.array([q for _, q, _ in self._fit_rows])
        a = np.column_stack([np.array([z for _, _, z in self._fit_rows]), np.ones(window)])
        scale = np.linalg.norm(a, axis=0)
        a = a / np.where(scale > 0.0, scale, 1.0)
        beta, _, rank, _ = np.linalg.lstsq(a, r, rcond=None)
        e = r - a @ beta
        dof = max(window - int(rank), 1)
        var = (e * e).sum(axis=0) / dof
        lag = -(e[1:] * e[:-1])[pairs].sum(axis=0) / int(pairs.sum()) * (window - 1) / dof
        self.fit_lag2 = lag
        white = lag >= _FIT_WHITE * var
        noisy = (lag > self.fit_noise2) & white
        self.fit_sigma_rad_s = float(np.sqrt(max(float(np.max(np.where(white, lag, 0.0))),
                                                 0.0)))
        if self.fault == NOISE:
            if (lag > _FIT_AGAIN * self.fit_noise2).any():
                self._fit_calm = 0
            else:
                self._fit_calm += 1
            noisy = noisy | np.full(3, self._fit_calm < window)
        if not noisy.any():
            self._fit_over = 0
            return v
        self._fit_over += 1
        if self._fit_over < _FIT_TICKS and self.fault != NOISE:
            # Not yet: one tick's jump (a bias step, a spike) lifts the window's level for a
            # few ticks, and the jump tests must see the ticks around it untouched.
            return v
        fault = v.fault
        if fault is None:
            fault = self._report(NOISE)
        self._pending = None
        return replace(v, suspect=True, hold=False, drop_previous=True, fault=fault,
                       defer_learning=False)

    def _after_fail(self, r: np.ndarray, increments: np.ndarray | None) -> GyroVerdict | None:
        """The tick after a jump only one thruster's failure explained (already evidence):
        the opposite jump is a spike (``-2s``: a counter glitch); nothing, while that thruster
        fires right, a bias step.
        Either way the previous tick was the sensor (``taint_previous``)."""
        p, who = self._last_fail
        self._last_fail = None
        pn = float(np.linalg.norm(p))
        kind = None
        settle = False
        if float(np.linalg.norm(r + p)) < self.return_fraction * pn:
            kind = SPIKE
        elif float(np.linalg.norm(r + 2.0 * p)) < 2.0 * self.return_fraction * pn:
            kind, settle = SPIKE, True
        elif increments is not None and float(r @ p) < self.return_fraction * pn * pn \
                and float(np.linalg.norm(r)) <= self.return_fraction * pn + self._slack(
                    r, np.asarray(increments, dtype=float)):
            # Nothing more along the jump (a weak thruster repeats its deficit along it), the
            # rest within the thrusters' errors, and that thruster commanded again giving
            # more than half its increment.
            u = np.asarray(increments[who], dtype=float)
            un = float(np.linalg.norm(u))
            if un >= 2.0 * self.jump_rad_s and -float(r @ u) / un < 0.5 * un:
                kind = BIAS_STEP
        if kind is None:
            return None
        self._r_quiet = None
        self._settle = settle
        return GyroVerdict(True, False, False, not settle, self._report(kind), r,
                           taint_previous=True)

    def _noise(self, r: np.ndarray, thrust_abs: float) -> GyroVerdict:
        """Noise level on quiet ticks, per axis (module doc)."""
        suspect = False
        fault = None
        quiet_prev, self._r_quiet = self._r_quiet, (r.copy() if thrust_abs == 0.0 else None)
        if thrust_abs == 0.0 and quiet_prev is not None:
            # Differences of consecutive quiet residuals: a steady residual (a stuck thruster,
            # an unmodelled torque) cancels, sensor noise does not (twice its variance).
            dr = r - quiet_prev
            r2 = dr * dr
            self._quiet += 1
            warm = self._quiet <= self.warmup_ticks
            if self._quiet == 1:
                self._slow = r2.copy()
            ref = np.maximum(self._slow / (1.0 if warm else _SLOW_BIAS), self.noise_floor2)
            self._big = (self._big + [r2 > _BIG_RATIO * ref])[-_BIG_WINDOW:]
            self._recent = (self._recent + [r2])[-_BIG_WINDOW:]
            self._diffs = (self._diffs + [dr])[-_BIG_WINDOW:]
            count = np.sum(self._big, axis=0)
            noisy = (not warm and len(self._big) == _BIG_WINDOW
                     and bool(((count >= _BIG_COUNT) & self._white()).any()))
            if self._noisy_ref is not None:
                # After a noise increase was named: suspect while the axes' median level is
                # still above _NOISY_AGAIN times the level it was named against.
                med = np.median(np.asarray(self._recent), axis=0) / 0.455
                self._noisy_now = bool((med > _NOISY_AGAIN * self._noisy_ref).any())
                noisy = noisy or self._noisy_now
            if noisy:
                self._over += 1
                suspect = True
                if self._over >= self.noise_ticks:
                    fault = self._report(NOISE)
                    if fault is not None:
                        self._noisy_ref = ref.copy()
                        self._noisy_now = True
            else:
                self._over = 0
                # Each sample counts at most _SLOW_CAP times the level (a robust mean): a
                # noise increase must not drag the reference up before the test shows it.
                # During the warm-up a running mean (capped from the floor). An axis whose
                # window already holds _FREEZE_COUNT large differences keeps its level (a
                # noise increase must not drag the level up while the count builds).
                r2c = np.minimum(r2, _SLOW_CAP * np.maximum(self._slow, self.noise_floor2))
                a = 1.0 / self._quiet if warm else 1.0 - self.slow_forget
                keep = (count >= _FREEZE_COUNT) & (not warm)
                self._slow = np.where(keep, self._slow, (1.0 - a) * self._slow + a * r2c)
        elif self._over > 0 or self._noisy_now:
            suspect = True
        return GyroVerdict(suspect, False, False, False, fault, r)
