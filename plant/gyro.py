"""Angular-rate sensor (seed 003 eq. 3) and integrating gyro (seed 002).

A rate sample measured at ``t_meas_s`` is::

    w_meas = w_B + sum_i phi_i(r_gyro) q_i' + b(t) + n,    n ~ N(0, noise_std^2) per axis

with ``w_B`` the true absolute body rate, ``b(t) = bias_rad_s + walk(t) + fault bias steps``
(the walk is a seeded random walk, increment ``N(0, bias_walk^2 dt)`` per sample) and ``n``
seeded white noise, then quantised to ``quantum_rad_s``. Samples are taken every
``1 / rate_hz`` s from t = 0 and become available ``latency_ms`` after they are measured.

Integrating variant (seed 002): the sensor accumulates the angle
``theta(t) = int (w_B + b) dt + sum_i phi_i q_i`` plus noise, quantises the *running total*
(a pulse counter, so quantisation errors do not accumulate) with the angle quantum
``quantum_rad_s / rate_hz``, and outputs the increment since the previous sample. The white
rate noise is integrated (angle random walk): each increment carries independent noise of
standard deviation ``noise_std / rate_hz``. The first sample only starts the count
(``NO_DATA``).
``rate_B_rad_s`` of an integrating sample is the increment divided by the interval.

Faults (``plant.faults``): spike, bias step, frozen output (a rate gyro repeats its last
output; an integrating gyro's counter stops: zero increments), noise increase. Injected faults
are silent: ``status`` stays ``OK``, as a failed sensor would report; the truth recording
carries the active faults.

Random streams are independent ``numpy.random.Generator`` s (noise, bias walk, fault noise)
spawned from the plant seed, so one stream's use never shifts another's.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from hil.config import GyroCfg
from plant.faults import FaultState


class GyroStatus(IntEnum):
    OK = 0
    # The sample's value is not usable (the first integrating sample has no interval yet).
    NO_DATA = 1


@dataclass(frozen=True)
class GyroSample:
    """One gyro output. ``rate_B_rad_s`` (3,) measured rate (for an integrating gyro the mean
    over the interval); ``delta_angle_B_rad`` (3,) the angle increment (integrating gyro only,
    else None); ``t_meas_s`` when it was measured, ``t_avail_s`` when it leaves the sensor."""

    seq: int
    t_meas_s: float
    t_avail_s: float
    rate_B_rad_s: tuple[float, float, float]
    delta_angle_B_rad: tuple[float, float, float] | None
    status: GyroStatus


class Gyro:
    """Sensor model; ``measure`` is called by the plant at each sample time in order."""

    def __init__(self, cfg: GyroCfg, rngs: tuple[np.random.Generator, ...]) -> None:
        self.cfg = cfg
        self.period_s = 1.0 / cfg.rate_hz
        self.latency_s = cfg.latency_ms / 1000.0
        self._rng_noise, self._rng_walk, self._rng_fault = rngs
        self.walk = np.zeros(3)
        self.seq = 0
        self._last_rate = np.zeros(3)
        self._last_delta = np.zeros(3)
        self._last_t: float | None = None
        self._theta_true = np.zeros(3)  # running angle incl. bias, before noise/quantisation
        self._count_prev = np.zeros(3)
        self._counting_frozen = False

    def sample_time(self, k: int) -> float:
        return k * self.period_s

    def measure(self, t_s: float, w_B_rad_s: np.ndarray, flex_rate_B: np.ndarray,
                d_theta_rigid_B: np.ndarray, flex_angle_B: np.ndarray, faults: FaultState
                ) -> GyroSample:
        """The sample measured at ``t_s``.

        ``d_theta_rigid_B`` (3,) is ``int w_B dt`` since the previous sample and
        ``flex_angle_B`` (3,) the current ``sum phi_i q_i`` (integrating gyro only).
        """
        cfg = self.cfg
        dt = self.period_s if self._last_t is None else t_s - self._last_t
        # Draw every stream every sample so the sequences do not depend on the configuration.
        noise = self._rng_noise.standard_normal(3)
        walk_step = self._rng_walk.standard_normal(3)
        extra = self._rng_fault.standard_normal(3)
        if cfg.bias_walk_rad_s_sqrt_s > 0 and self._last_t is not None:
            self.walk = self.walk + walk_step * cfg.bias_walk_rad_s_sqrt_s * np.sqrt(dt)
        bias = np.asarray(cfg.bias_rad_s) + self.walk + faults.gyro_bias_step(t_s)
        noise_rate = noise * cfg.noise_std_rad_s + extra * faults.gyro_extra_noise(t_s)
        spike = faults.take_gyro_spike(t_s)
        frozen = faults.gyro_frozen(t_s)
        status = GyroStatus.OK
        delta: np.ndarray | None = None
        if cfg.kind == "rate":
            rate = w_B_rad_s + flex_rate_B + bias + noise_rate + spike
            if cfg.quantum_rad_s > 0:
                rate = np.round(rate / cfg.quantum_rad_s) * cfg.quantum_rad_s
            if frozen:
                rate = self._last_rate
        else:
            first = self._last_t is None
            if not first:
                self._theta_true = self._theta_true + d_theta_rigid_B + (bias + noise_rate) * dt
            # A spike is one bad reading of the counter: the next increment takes it back.
            total = self._theta_true + flex_angle_B + spike * self.period_s
            q_ang = cfg.quantum_rad_s * self.period_s
            count = np.round(total / q_ang) * q_ang if q_ang > 0 else total
            delta = count - self._count_prev
            self._count_prev = count
            if frozen:
                delta = np.zeros(3)
            if first:
                status = GyroStatus.NO_DATA
            rate = delta / dt if dt > 0 else np.zeros(3)
        self._last_rate = rate
        self._last_t = t_s
        s = GyroSample(
            seq=self.seq,
            t_meas_s=t_s,
            t_avail_s=t_s + self.latency_s,
            rate_B_rad_s=(float(rate[0]), float(rate[1]), float(rate[2])),
            delta_angle_B_rad=None if delta is None else
            (float(delta[0]), float(delta[1]), float(delta[2])),
            status=status,
        )
        self.seq += 1
        return s
