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

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from common.vehicle import GyroCfg
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
    """Sensor model; ``measure`` is called by the plant at each sample time in order.

    The 3-vector arithmetic is on plain floats (numpy calls cost more than they compute for
    three numbers); each component sees the same operations, in the same order, as the
    vector formulas of the module doc.
    """

    def __init__(self, cfg: GyroCfg, rngs: tuple[np.random.Generator, ...]) -> None:
        self.cfg = cfg
        self.period_s = 1.0 / cfg.rate_hz
        self.latency_s = cfg.latency_ms / 1000.0
        self._rng_noise, self._rng_walk, self._rng_fault = rngs
        self.walk = [0.0, 0.0, 0.0]
        self.seq = 0
        self._last_rate = [0.0, 0.0, 0.0]
        self._last_t: float | None = None
        self._theta_true = [0.0, 0.0, 0.0]  # running angle incl. bias, before noise/quantisation
        self._count_prev = [0.0, 0.0, 0.0]
        self._bias = [float(b) for b in cfg.bias_rad_s]

    def sample_time(self, k: int) -> float:
        return k * self.period_s

    def measure(self, t_s: float, w_B_rad_s: Sequence[float], flex_rate_B: Sequence[float],
                d_theta_rigid_B: Sequence[float], flex_angle_B: Sequence[float],
                faults: FaultState) -> GyroSample:
        """The sample measured at ``t_s``.

        ``w_B_rad_s`` (3,) true rate and ``flex_rate_B`` (3,) the flex part; ``d_theta_rigid_B``
        (3,) is ``int w_B dt`` since the previous sample and ``flex_angle_B`` (3,) the current
        ``sum phi_i q_i`` (integrating gyro only: a rate gyro ignores both). Any sequences of
        three numbers.
        """
        cfg = self.cfg
        first = self._last_t is None
        dt = self.period_s if first else t_s - self._last_t
        # Draw every stream every sample so the sequences do not depend on the configuration.
        n0, n1, n2 = self._rng_noise.standard_normal(3).tolist()
        walk_step = self._rng_walk.standard_normal(3).tolist()
        x0, x1, x2 = self._rng_fault.standard_normal(3).tolist()
        walk = self.walk
        bw = cfg.bias_walk_rad_s_sqrt_s
        if bw > 0 and not first:
            sq = math.sqrt(dt)
            walk = self.walk = [walk[i] + walk_step[i] * bw * sq for i in range(3)]
        cb = self._bias
        sd = cfg.noise_std_rad_s
        if faults.has_gyro_faults:
            bs = faults.gyro_bias_step(t_s).tolist()
            xs = faults.gyro_extra_noise(t_s).tolist()
            b0, b1, b2 = cb[0] + walk[0] + bs[0], cb[1] + walk[1] + bs[1], cb[2] + walk[2] + bs[2]
            r0, r1, r2 = n0 * sd + x0 * xs[0], n1 * sd + x1 * xs[1], n2 * sd + x2 * xs[2]
            s0, s1, s2 = faults.take_gyro_spike(t_s).tolist()
            frozen = faults.gyro_frozen(t_s)
        else:  # the fault terms are exact zeros
            b0, b1, b2 = cb[0] + walk[0], cb[1] + walk[1], cb[2] + walk[2]
            r0, r1, r2 = n0 * sd, n1 * sd, n2 * sd
            s0 = s1 = s2 = 0.0
            frozen = False
        status = GyroStatus.OK
        delta: tuple[float, float, float] | None = None
        if cfg.kind == "rate":
            w, f = w_B_rad_s, flex_rate_B
            rate = (w[0] + f[0] + b0 + r0 + s0, w[1] + f[1] + b1 + r1 + s1,
                    w[2] + f[2] + b2 + r2 + s2)
            if cfg.quantum_rad_s > 0:
                qr = cfg.quantum_rad_s
                rate = tuple((np.round(np.array(rate) / qr) * qr).tolist())
            if frozen:
                rate = self._last_rate
        else:
            th = self._theta_true
            if not first:
                d = d_theta_rigid_B
                th = self._theta_true = [th[0] + d[0] + (b0 + r0) * dt,
                                         th[1] + d[1] + (b1 + r1) * dt,
                                         th[2] + d[2] + (b2 + r2) * dt]
            # A spike is one bad reading of the counter: the next increment takes it back.
            fa, per = flex_angle_B, self.period_s
            total = (th[0] + fa[0] + s0 * per, th[1] + fa[1] + s1 * per, th[2] + fa[2] + s2 * per)
            q_ang = cfg.quantum_rad_s * per
            count = (np.round(np.array(total) / q_ang) * q_ang).tolist() if q_ang > 0 else total
            cp = self._count_prev
            delta = (count[0] - cp[0], count[1] - cp[1], count[2] - cp[2])
            self._count_prev = count
            if frozen:
                delta = (0.0, 0.0, 0.0)
            if first:
                status = GyroStatus.NO_DATA
            rate = (delta[0] / dt, delta[1] / dt, delta[2] / dt) if dt > 0 else (0.0, 0.0, 0.0)
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
