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
* **spike**: a jump ``r(n)`` larger than ``jump_rad_s`` that the thrusters burning in the tick
  cannot explain (``|r| > jump_rad_s + explain_factor * sum_j |mu_j| eff_j``), followed by the
  opposite jump (``|r(n) + r(n+1)| < return_fraction |r(n)|``): one bad sample;
* **bias step**: the same unexplained jump followed by nothing (``|r(n+1)| < return_fraction
  |r(n)|``): the output moved, the dynamics did not. A stuck-on thruster repeats its jump tick
  after tick, so it is never a step;
* **noise increase**: the mean square of the change of ``r`` between consecutive quiet ticks
  (no thrust inside either; a steady residual such as a stuck thruster's cancels),
  forgotten with ``fast_forget``, exceeds ``noise_ratio`` times its long-run level (forgotten
  with ``slow_forget``, each sample capped at ``_SLOW_CAP`` times the level, frozen while the
  gyro is suspect) and the floor ``noise_floor_rad_s``
  for ``noise_ticks`` ticks in a row.

While a jump waits for its next tick, and while the output is frozen or noisy, the gyro is
*suspect*: the flight does not feed the tick to the thruster detector nor to the effectiveness
learning (the evidence stays clean), and after a recognised jump it re-synchronises the observer
and the Kalman filter on the new output. The first recognised fault is reported once
(``fault``: ``spike``, ``bias_step``, ``frozen`` or ``noise``); later anomalies keep the gyro
suspect without a new report (one sensor, one report).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SPIKE, BIAS_STEP, FROZEN, NOISE = "spike", "bias_step", "frozen", "noise"
# A quiet tick's square residual enters the long-run noise level capped at this many times it.
_SLOW_CAP = 4.0
# Of the last _BIG_WINDOW quiet differences, at least _BIG_COUNT above _BIG_RATIO times the level.
_BIG_WINDOW, _BIG_COUNT, _BIG_RATIO = 6, 4, 9.0


@dataclass(frozen=True)
class GyroVerdict:
    """One tick of the check. ``suspect``: keep this tick out of the thruster evidence;
    ``drop_previous``: the previous tick (held back as a possible jump) was a gyro error too;
    ``resync``: the output moved without the dynamics (re-synchronise estimators on it);
    ``fault``: newly recognised fault kind (first one only) or None; ``residual`` r (3,)."""

    suspect: bool
    hold: bool
    drop_previous: bool
    resync: bool
    fault: str | None
    residual: np.ndarray


class GyroCheck:
    """Frozen / spike / bias-step / noise tests on the raw one-tick residual (module doc).

    ``step(y, predicted_change, thrust_abs)``: ``y`` (3,) this tick's sample;
    ``predicted_change`` (3,) the onboard model's rate change over the last tick (free
    dynamics plus thrusters, ``d_free + u``); ``thrust_abs`` the scale of the thrusters'
    share (``sum_j |mu_j| eff_j`` over the tick).
    """

    def __init__(self, jump_rad_s: float, noise_floor_rad_s: float, *,
                 explain_factor: float = 1.5, return_fraction: float = 0.3,
                 noise_ratio: float = 25.0, fast_forget: float = 0.8,
                 slow_forget: float = 0.995, noise_ticks: int = 5, warmup_ticks: int = 20,
                 start_ticks: int = 2) -> None:
        self.jump_rad_s = float(jump_rad_s)
        self.noise_floor2 = float(noise_floor_rad_s) ** 2
        self.explain_factor = float(explain_factor)
        self.return_fraction = float(return_fraction)
        self.noise_ratio = float(noise_ratio)
        self.fast_forget = float(fast_forget)
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
        self._chain = False
        self._r_quiet: np.ndarray | None = None
        self._big: list[bool] = []
        self._fast = 0.0
        self._slow = 0.0
        self._quiet = 0
        self._over = 0

    def forget_pending(self) -> None:
        """The flight changed the dynamics itself (an FDIR response): a held jump is not to be
        judged against the next tick."""
        self._pending = None
        self._chain = False

    def skip(self, y: np.ndarray) -> None:
        """A tick whose data is not evidence (sample missing or propagated, command not
        applied): ``y`` becomes the previous output without being judged, a held jump is
        dropped."""
        self._y_prev = np.asarray(y, dtype=float).copy()
        self.forget_pending()

    def _report(self, kind: str) -> str | None:
        if self.fault is not None:
            return None
        self.fault = kind
        return kind

    def step(self, y: np.ndarray, predicted_change: np.ndarray,
             thrust_abs: float) -> GyroVerdict:
        v = self._step(y, predicted_change, thrust_abs)
        self.suspect = v.suspect
        return v

    def _step(self, y: np.ndarray, predicted_change: np.ndarray,
              thrust_abs: float) -> GyroVerdict:
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
            self._pending = None
            return GyroVerdict(True, False, False, False, fault, r)
        was_frozen = self._repeats >= 2
        self._repeats = 0
        norm = float(np.linalg.norm(r))
        if was_frozen:
            # The first live sample after a freeze jumps by whatever the rate did meanwhile.
            self._pending = None
            return GyroVerdict(True, False, False, True, None, r)
        continuation = False
        if self._pending is not None:
            p = self._pending
            pn = float(np.linalg.norm(p))
            self._pending = None
            kind = None
            if not self._chain:
                if float(np.linalg.norm(r + p)) < self.return_fraction * pn:
                    kind = SPIKE
                elif norm < self.return_fraction * pn:
                    kind = BIAS_STEP
            if kind is not None:
                return GyroVerdict(True, False, True, True, self._report(kind), r)
            continuation = True
        unexplained = norm > self.jump_rad_s + self.explain_factor * float(thrust_abs)
        if unexplained:
            # A jump that follows a jump is dynamics going on (a stuck thruster): when it
            # stops (a response, a fault clearing) that is not a gyro step.
            self._pending = r.copy()
            self._chain = continuation
            return GyroVerdict(True, True, False, False, None, r)
        # Noise level on quiet ticks.
        suspect = False
        fault = None
        quiet_prev, self._r_quiet = self._r_quiet, (r.copy() if thrust_abs == 0.0 else None)
        if thrust_abs == 0.0 and quiet_prev is not None:
            # Differences of consecutive quiet residuals: a steady residual (a stuck thruster,
            # an unmodelled torque) cancels, sensor noise does not (twice its variance).
            dr = r - quiet_prev
            r2 = float(dr @ dr)
            self._quiet += 1
            if self._quiet == 1:
                self._fast = self._slow = r2
            self._fast = self.fast_forget * self._fast + (1.0 - self.fast_forget) * r2
            ref = max(self._slow, self.noise_floor2)
            # Noise is many large differences, a step (a thruster starting, a torque) one: the
            # fast mean must be high and most of the last quiet differences large on their own.
            self._big = (self._big + [r2 > _BIG_RATIO * ref])[-_BIG_WINDOW:]
            noisy = (self._quiet > self.warmup_ticks and self._fast > self.noise_ratio * ref
                     and sum(self._big) >= _BIG_COUNT)
            if noisy:
                self._over += 1
                suspect = True
                if self._over >= self.noise_ticks:
                    fault = self._report(NOISE)
            else:
                self._over = 0
                # Each sample counts at most _SLOW_CAP times the level (a robust mean): a
                # noise increase must not drag the reference up before the fast mean shows it.
                r2c = min(r2, _SLOW_CAP * max(self._slow, self.noise_floor2))
                self._slow = self.slow_forget * self._slow + (1.0 - self.slow_forget) * r2c
        elif self._over > 0:
            suspect = True
        return GyroVerdict(suspect, False, False, False, fault, r)
