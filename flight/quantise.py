"""PWM quantisation of thruster firing times with the remainder carried to the next tick.

Seed 004 section 4: a thruster is commanded once per tick of 200 ms in quanta of 10 ms, with a
minimum on-time of 30 ms and a minimum pause of 30 ms, so the allowed on-durations are
``{0, 30, 40, ..., 170, 200}`` ms (180 and 190 would leave a pause shorter than 30 ms; 200 means
continuous). The effective firing time of a commanded pulse ``tau`` is
``tau_E = tau - tau_on + tau_off`` (30 ms and 27 ms: ``tau_E = tau - 3 ms``); a thruster commanded
0 gives nothing.

The allocator's LP works in effective time. :class:`Quantiser` turns the LP's effective times into
allowed commands, one thruster at a time, with an effective-time remainder ("carry"):

* target ``e = tau_LP + carry`` (ms, effective);
* pick the allowed command ``q`` whose effective time ``E(q)`` is nearest to ``e`` (ties go to the
  shorter command); ``carry <- e - E(q)``.

Demands below the shortest pulse (``E(30) = 27`` ms) therefore accumulate: below half of it they
give no pulse and the whole demand waits in the carry; from half of it on they fire the minimum
pulse and the surplus is paid back by the following ticks. The carry is bounded by half the
largest gap between allowed effective times (15 ms here), so over ``n`` ticks the mean command
differs from the mean LP demand by at most ``15 / n`` ms.

Two rules keep a remainder from firing a thruster against the controller's will: the carry is
dropped when the LP asks nothing of the thruster this tick (it then stays off), and when the
thruster is not available (failed, disabled, closed manifold).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from common.vehicle import ThrustProfileCfg, TimingCfg


@dataclass(frozen=True)
class PulseSet:
    """The allowed commands of one tick and their effective times.

    ``on_ms`` (K,) int ascending, starting with 0; ``eff_ms`` (K,) float, ``eff_ms[0] = 0`` and
    ``eff_ms[k] = on_ms[k] - lag_delta_ms``; ``lag_delta_ms = tau_on - tau_off`` (3 ms).
    """

    on_ms: np.ndarray
    eff_ms: np.ndarray
    lag_delta_ms: float
    tick_ms: int

    @classmethod
    def from_config(cls, timing: TimingCfg, profile: ThrustProfileCfg) -> PulseSet:
        """Seed 004 section 4 from the vehicle's timing and thrust-profile sections."""
        quantum = float(timing.pwm_quantum_ms)
        tick = round(timing.tick_s * 1000.0)
        n = round(tick / quantum)
        if abs(n * quantum - tick) > 1e-9:
            raise ValueError(
                f"timing: expected tick_s a multiple of pwm_quantum_ms, got {timing.tick_s} s "
                f"and {quantum} ms"
            )
        allowed = [0]
        for k in range(1, n + 1):
            q = round(k * quantum)
            if q == tick or (q >= timing.min_on_ms and tick - q >= timing.min_off_ms):
                allowed.append(q)
        on = np.array(allowed, dtype=np.int64)
        delta = float(profile.on_lag_ms - profile.off_lag_ms)
        eff = np.where(on > 0, on - delta, 0.0).astype(float)
        if np.any(np.diff(eff) <= 0):
            raise ValueError(
                f"thrust_profile: expected on_lag_ms - off_lag_ms below the shortest pulse, "
                f"got {delta} ms"
            )
        on.setflags(write=False)
        eff.setflags(write=False)
        return cls(on_ms=on, eff_ms=eff, lag_delta_ms=delta, tick_ms=tick)

    @property
    def max_eff_s(self) -> float:
        """Longest effective firing time of one tick, s (197 ms for seed 004)."""
        return float(self.eff_ms[-1]) / 1000.0

    def effective_s(self, on_ms: np.ndarray) -> np.ndarray:
        """Seed 004 section 4: ``tau_E = tau - (tau_on - tau_off)`` for ``tau > 0``, else 0 (s)."""
        on = np.asarray(on_ms, dtype=float)
        return np.where(on > 0, on - self.lag_delta_ms, 0.0) / 1000.0

    @cached_property
    def _mid_ms(self) -> np.ndarray:
        """(K-1,) midpoints between consecutive allowed effective times."""
        return 0.5 * (self.eff_ms[:-1] + self.eff_ms[1:])

    def nearest(self, target_eff_ms: np.ndarray) -> np.ndarray:
        """Index (N,) of the allowed command whose effective time is nearest (ties: shorter).

        The index is the number of midpoints strictly below the target.
        """
        return np.searchsorted(self._mid_ms, target_eff_ms, side="left")


class Quantiser:
    """Per-thruster quantiser with carried remainder (module docstring).

    State: ``carry_ms`` (N,) effective-time remainder. ``carry=False`` rounds each tick alone.
    """

    def __init__(self, pulses: PulseSet, n_thrusters: int, carry: bool = True) -> None:
        self.pulses = pulses
        self.carry_enabled = bool(carry)
        self.carry_ms = np.zeros(n_thrusters)

    def reset(self) -> None:
        self.carry_ms[:] = 0.0

    def step(self, tau_eff_s: np.ndarray, available: np.ndarray) -> np.ndarray:
        """Quantise LP effective times (N,) s; returns allowed commands ``on_ms`` (N,) int.

        ``available`` (N,) bool: an unavailable thruster is commanded 0 and its carry dropped.
        """
        return self.step_eff(tau_eff_s, available)[0]

    def step_eff(self, tau_eff_s: np.ndarray,
                 available: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`step`; also returns the effective times (N,) s of the commands."""
        demand_ms = np.asarray(tau_eff_s, dtype=float) * 1000.0
        active = np.asarray(available, dtype=bool) & (demand_ms > 0.0)
        target = demand_ms + self.carry_ms if self.carry_enabled else demand_ms
        target *= active
        idx = self.pulses.nearest(target)
        eff = self.pulses.eff_ms[idx]
        if self.carry_enabled:
            self.carry_ms = (target - eff) * active
        return self.pulses.on_ms[idx], eff / 1000.0

    def peek(self, tau_eff_s: np.ndarray, available: np.ndarray) -> np.ndarray:
        """As :meth:`step` without changing the carry."""
        saved = self.carry_ms.copy()
        try:
            return self.step(tau_eff_s, available)
        finally:
            self.carry_ms = saved
