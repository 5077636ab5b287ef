"""Thrust profile (seed 004 eq. 4.1), its equal-area calibration, and the valve timeline.

Profile of one firing, time ``t`` from the valve command (seed 004 eq. 4.1)::

    rise   P(t) = P_nom (1 - exp(-k1 (t - T_R)^n1))          t >= T_R after the on command
    decay  P(t) = P_lvl exp(-k2 (t - t_off - T_R)^n2)         t >= t_off + T_R

Equal-area lags (seed 004, after eq. 4.1): the area missing during the rise, counted from the
on command (so the electrical delay ``T_R`` is part of it) up to ``0.99 P_nom``, equals
``P_nom tau_on``; the area added after the off command down to ``0.01 P_nom`` equals
``P_nom tau_off``. With ``E(x) = int_0^x exp(-k s^n) ds = k^(-1/n) Gamma(1 + 1/n) P(1/n, k x^n)``
(``P`` the regularised lower incomplete gamma function) both conditions are closed forms::

    tau_on  = T_R + E1(x99),  k1 x99^n1 = ln 100  ->  k1 = (G1 P(1/n1, ln 100) / (tau_on - T_R))^n1
    tau_off = T_R + E2(x01),  k2 x01^n2 = ln 100  ->  k2 = (G2 P(1/n2, ln 100) / (tau_off - T_R))^n2

where ``G = Gamma(1 + 1/n)``. No root finding is needed; ``scipy.integrate.quad`` of the
definition is the independent check (tests and ``hil thruster-profile``).

Generalised to any history, the thrust of one thruster is a chain of *segments*, each
``level(t) = B + C exp(-k (t - t_origin)^n)`` in units of the thruster's actual thrust:

* a rise toward the target ``B`` uses ``k1, n1`` and ``C = -B``; if it starts from a level
  ``A > 0`` (a valve reopened while the thrust was still decaying) the origin is moved back so
  that the rise curve passes through ``A``: the chamber is already partly filled, so the rise
  continues along eq. 4.1 instead of restarting from zero;
* a decay toward the target ``B`` (0 when closed, the residual fraction when stuck on) uses
  ``k2, n2`` and starts from the level reached, ``C = A - B``: a short pulse (30, 40 ms) that
  never reached ``P_nom`` decays from where it was, not from ``P_nom``.

A change of target starts a new segment ``T_R`` after the command that caused it (valve
commands, manifold isolation valves); a fault changes the target at its own time (the valve
itself fails; no command is involved). The impulse of a segment over any interval is a closed
form, so the integrator gets the exact impulse of every step whatever its length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erf, gammainc
from scipy.special import gamma as _gamma

from hil.config import ThrustProfileCfg, TimingCfg
from hil.errors import ConfigError

LN100 = math.log(100.0)
# exp(-50) ~ 2e-22: a segment this far past its origin is at its target to double precision.
_SATURATED_EXPONENT = 50.0
# Two command intervals closer than this are one continuous firing (float tick arithmetic).
CONTINUITY_TOL_S = 1e-6


# --------------------------------------------------------------------------- profile


@dataclass(frozen=True)
class ThrustProfile:
    """Calibrated seed 004 eq. 4.1 profile. Times in seconds, ``k`` in s^-n."""

    t_r_s: float
    k1: float
    n1: float
    k2: float
    n2: float
    on_lag_s: float
    off_lag_s: float

    @classmethod
    def calibrate(cls, cfg: ThrustProfileCfg, where: str = "thrust_profile") -> ThrustProfile:
        """Closed-form ``k1, k2`` giving exactly ``on_lag_ms`` and ``off_lag_ms`` (module doc)."""
        t_r = cfg.electrical_delay_ms / 1000.0
        tau_on = cfg.on_lag_ms / 1000.0
        tau_off = cfg.off_lag_ms / 1000.0
        if tau_on <= t_r:
            raise ConfigError(where, "on_lag_ms",
                              f"> electrical_delay_ms={cfg.electrical_delay_ms}", cfg.on_lag_ms)
        if tau_off <= t_r:
            raise ConfigError(where, "off_lag_ms",
                              f"> electrical_delay_ms={cfg.electrical_delay_ms}", cfg.off_lag_ms)
        n1, n2 = float(cfg.rise_exponent), float(cfg.decay_exponent)
        k1 = (_area_factor(n1) / (tau_on - t_r)) ** n1
        k2 = (_area_factor(n2) / (tau_off - t_r)) ** n2
        return cls(t_r_s=t_r, k1=k1, n1=n1, k2=k2, n2=n2, on_lag_s=tau_on, off_lag_s=tau_off)

    # -- single-pulse closed forms (time from the on command, normalised thrust) ----------

    def rise_level(self, t_s: float) -> float:
        """Normalised thrust ``t_s`` after an on command from zero (eq. 4.1, first branch)."""
        x = t_s - self.t_r_s
        return 0.0 if x <= 0 else 1.0 - math.exp(-self.k1 * x**self.n1)

    def decay_level(self, t_s: float, start_level: float = 1.0) -> float:
        """Normalised thrust ``t_s`` after an off command from ``start_level`` (eq. 4.1)."""
        x = t_s - self.t_r_s
        return start_level if x <= 0 else start_level * math.exp(-self.k2 * x**self.n2)

    def rise_time_s(self, level: float) -> float:
        """Time from the on command to reach ``level`` (0 < level < 1)."""
        return self.t_r_s + (-math.log1p(-level) / self.k1) ** (1.0 / self.n1)

    def decay_time_s(self, level: float) -> float:
        """Time from the off command (after a full rise) to fall to ``level``."""
        return self.t_r_s + (-math.log(level) / self.k2) ** (1.0 / self.n2)

    def pulse_level(self, t_s: float, on_s: float) -> float:
        """Normalised thrust of an isolated pulse of commanded length ``on_s`` at time ``t_s``."""
        if on_s <= 0:
            return 0.0
        if t_s < on_s + self.t_r_s:
            return self.rise_level(t_s)
        return self.decay_level(t_s - on_s, self.rise_level(on_s + self.t_r_s))

    def pulse_impulse_s(self, on_s: float) -> float:
        """Exact impulse of an isolated pulse, in units of ``P_nom`` (seconds), from rest.

        Rise from ``T_R`` to ``on_s + T_R``, then the decay from the level reached, to infinity.
        """
        if on_s <= 0:
            return 0.0
        x_on = on_s  # rise lasts from T_R to on_s + T_R
        level = 1.0 - math.exp(-self.k1 * x_on**self.n1)
        rise = x_on - _e_scalar(self.k1, self.n1, x_on)
        decay = level * _e_scalar(self.k2, self.n2, math.inf)
        return rise + decay

    def effective_time_s(self, on_s: float) -> float:
        """Seed 004's effective firing time ``tau_E = tau - tau_on + tau_off`` (the model)."""
        return 0.0 if on_s <= 0 else on_s - self.on_lag_s + self.off_lag_s


def _area_factor(n: float) -> float:
    """``k^(1/n) E(x)`` at ``k x^n = ln 100``: ``Gamma(1 + 1/n) P(1/n, ln 100)``."""
    return float(_gamma(1.0 + 1.0 / n) * gammainc(1.0 / n, LN100))


def _e_scalar(k: float, n: float, x: float) -> float:
    """``int_0^x exp(-k s^n) ds`` (closed form through the incomplete gamma function)."""
    if x <= 0:
        return 0.0
    full = k ** (-1.0 / n) * float(_gamma(1.0 + 1.0 / n))
    if math.isinf(x):
        return full
    return full * float(gammainc(1.0 / n, k * x**n))


def _e_vec(k: float, n: float, full: float, x: np.ndarray) -> np.ndarray:
    """Vectorised ``_e_scalar`` for one ``(k, n)``; ``full = k^(-1/n) Gamma(1 + 1/n)``.

    The common exponents have cheaper closed forms: ``n = 1`` gives ``(1 - exp(-k x)) / k``
    and ``n = 2`` gives ``full * erf(sqrt(k) x)``.
    """
    xp = np.maximum(x, 0.0)
    if n == 1.0:
        return -np.expm1(-k * xp) / k
    if n == 2.0:
        return full * erf(math.sqrt(k) * xp)
    return full * gammainc(1.0 / n, k * xp**n)


# --------------------------------------------------------------------------- commands


def allowed_on_ms(timing: TimingCfg) -> tuple[int, ...]:
    """Allowed on-durations per tick in ms (seed 004 section 4; DESIGN.md section 3).

    ``{0} U {min_on .. tick - min_off step quantum} U {tick}``: ``(0, 30, 40, ..., 170, 200)``
    for the default timing (180 and 190 are impossible: a 30 ms pause must remain).
    """
    q = int(round(timing.pwm_quantum_ms))
    tick = int(round(timing.tick_s * 1000.0))
    lo, hi = int(round(timing.min_on_ms)), tick - int(round(timing.min_off_ms))
    out = {0, tick}
    out.update(v for v in range(q, tick, q) if lo <= v <= hi)
    return tuple(sorted(out))


def clamp_on_ms(on_ms: np.ndarray, allowed: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Map received on-durations to the nearest allowed value (ties to the shorter one).

    The plant takes whatever arrives from the bus and must not crash on it (STYLE.md habit 6):
    an out-of-set value is replaced, and the caller counts it. Returns ``(applied_ms (N,) int,
    clamped (N,) bool)``.
    """
    req = np.asarray(on_ms, dtype=float).reshape(-1)
    values = req.tolist()
    if set(values) <= set(allowed):  # the normal case: a valid command
        return req.astype(int), np.zeros(req.shape[0], dtype=bool)
    req = np.where(np.isfinite(req), req, 0.0)
    table = np.asarray(allowed, dtype=float)
    dist = np.abs(req[:, None] - table[None, :])
    applied = table[np.argmin(dist, axis=1)].astype(int)  # argmin takes the first: the shorter
    return applied, applied != req


# --------------------------------------------------------------------------- valve timeline


@dataclass
class Segment:
    """``level(t) = B + C exp(-k (t - t_origin)^n)`` from ``t_start_s`` (normalised thrust)."""

    t_start_s: float
    t_origin_s: float
    b: float
    c: float
    rise: bool  # True: k1, n1; False: k2, n2

    def level(self, t_s: float, prof: ThrustProfile) -> float:
        if self.c == 0.0:
            return self.b
        k, n = (prof.k1, prof.n1) if self.rise else (prof.k2, prof.n2)
        x = max(t_s - self.t_origin_s, 0.0)
        return self.b + self.c * math.exp(-k * x**n)

    def saturated(self, t_s: float, prof: ThrustProfile) -> bool:
        k, n = (prof.k1, prof.n1) if self.rise else (prof.k2, prof.n2)
        x = t_s - self.t_origin_s
        return x > 0 and k * x**n > _SATURATED_EXPONENT


class ThrusterBank:
    """Normalised thrust segments of N thrusters and their exact impulse on a time grid.

    Each thruster has a *target level* set by the discrete state (valve commanded open,
    manifold open, faults) and a current segment moving toward it (module doc). The owner
    calls ``set_target`` in time order; ``impulse_on_grid`` then integrates every segment
    started since the last call in closed form.
    """

    def __init__(self, n: int, prof: ThrustProfile) -> None:
        self.n = n
        self.prof = prof
        self.current: list[Segment] = [Segment(0.0, 0.0, 0.0, 0.0, False) for _ in range(n)]
        self.target = np.zeros(n)
        # Segments of the chunk being built: (thruster, Segment), in time order per thruster.
        self._pending: list[tuple[int, Segment]] = []
        self._chunk_start: list[Segment] = list(self.current)
        self._full1 = prof.k1 ** (-1.0 / prof.n1) * float(_gamma(1.0 + 1.0 / prof.n1))
        self._full2 = prof.k2 ** (-1.0 / prof.n2) * float(_gamma(1.0 + 1.0 / prof.n2))

    def level(self, j: int, t_s: float) -> float:
        return self.current[j].level(t_s, self.prof)

    def set_target(self, j: int, t_s: float, target: float) -> None:
        """From ``t_s`` on, thruster ``j`` moves toward ``target`` (normalised thrust)."""
        if target == self.target[j]:
            return
        self.target[j] = target
        a = self.current[j].level(t_s, self.prof)
        p = self.prof
        if target > a:
            # Rise along eq. 4.1 scaled to the target; shift the origin back to pass through a.
            x0 = 0.0 if a <= 0.0 else (-math.log1p(-a / target) / p.k1) ** (1.0 / p.n1)
            seg = Segment(t_s, t_s - x0, target, -target, True)
        elif target < a:
            seg = Segment(t_s, t_s, target, a - target, False)
        else:
            seg = Segment(t_s, t_s, target, 0.0, False)
        self.current[j] = seg
        self._pending.append((j, seg))

    def start_chunk(self, t0_s: float) -> None:
        """Begin a chunk at ``t0_s``: remember the segments in force (call before the chunk's
        ``set_target`` calls). Segments at their target to double precision become constants."""
        for j, seg in enumerate(self.current):
            if seg.c != 0.0 and seg.saturated(t0_s, self.prof):
                self.current[j] = Segment(seg.t_start_s, seg.t_origin_s, seg.b, 0.0, seg.rise)
        self._chunk_start = list(self.current)
        self._pending = []

    def impulse_on_grid(self, t_grid_s: np.ndarray, weights: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Exact normalised impulse over each grid interval of the chunk.

        ``t_grid_s`` (K+1,) increasing, starting at the chunk start; ``weights`` (N, W)
        per-thruster factors (actual thrust times direction, lever arm, mode shapes...).
        Returns ``(per_step (K, W), per_thruster (N,))``: ``per_step[k] = sum_j w_j
        int_{t_k}^{t_k+1} level_j dt`` and the normalised impulse of each thruster over the
        chunk (seconds of full thrust).
        """
        t0 = float(t_grid_s[0])
        chains: dict[int, list[Segment]] = {}
        for j, seg in self._pending:
            chains.setdefault(j, [self._chunk_start[j]]).append(seg)
        self._pending = []
        rows: list[tuple[float, float, float, float, float, float]] = []
        rise_l: list[bool] = []
        for j in range(self.n):
            chain = chains.get(j) or [self._chunk_start[j]]
            for i, seg in enumerate(chain):
                end = chain[i + 1].t_start_s if i + 1 < len(chain) else math.inf
                if end <= seg.t_start_s or (seg.b == 0.0 and seg.c == 0.0):
                    continue
                rows.append((j, seg.t_start_s, end, seg.t_origin_s, seg.b, seg.c))
                rise_l.append(seg.rise)
        self._chunk_start = list(self.current)
        k_steps = len(t_grid_s) - 1
        per_thr = np.zeros(self.n)
        if not rows:
            return np.zeros((k_steps, weights.shape[1])), per_thr
        arr = np.array(rows, dtype=float)
        rise = np.array(rise_l, dtype=bool)
        thr = arr[:, 0].astype(int)
        ts, te, to, b, c = arr[:, 1], arr[:, 2], arr[:, 3], arr[:, 4], arr[:, 5]
        p = self.prof
        # Cumulative integral of each segment from max(ts, t0) to every grid point.
        lo = np.maximum(ts, t0)
        x = np.clip(t_grid_s[:, None], lo[None, :], np.maximum(te, lo)[None, :])  # (K+1, S)
        cum = b * (x - lo)
        for is_rise, k, n, full in ((True, p.k1, p.n1, self._full1),
                                    (False, p.k2, p.n2, self._full2)):
            sel = (rise == is_rise) & (c != 0.0)
            if sel.any():
                xs = np.concatenate(((lo - to)[None, sel], x[:, sel] - to[sel]), axis=0)
                e = _e_vec(k, n, full, xs)
                cum[:, sel] += c[sel] * (e[1:] - e[0])
        step = np.diff(cum, axis=0)  # (K, S)
        per_step = step @ weights[thr]
        np.add.at(per_thr, thr, cum[-1])
        return per_step, per_thr
