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
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import erf, gammainc
from scipy.special import gamma as _gamma

from common.errors import ConfigError
from common.vehicle import ThrustProfileCfg, TimingCfg

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
    """Vectorised ``_e_scalar`` for one ``(k, n)`` and ``x >= 0`` (+inf allowed);
    ``full = k^(-1/n) Gamma(1 + 1/n)``.

    The common exponents have cheaper closed forms: ``n = 1`` gives ``(1 - exp(-k x)) / k``
    and ``n = 2`` gives ``full * erf(sqrt(k) x)``.
    """
    if n == 1.0:
        return np.expm1(-k * x) / -k  # = -expm1(-k x) / k exactly (rounding is odd)
    if n == 2.0:
        return full * erf(math.sqrt(k) * x)
    return full * gammainc(1.0 / n, k * x**n)


# --------------------------------------------------------------------------- commands


def allowed_on_ms(timing: TimingCfg) -> tuple[int, ...]:
    """Allowed on-durations per tick in ms (seed 004 section 4; docs/design.md section 3).

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

    The plant takes whatever arrives from the bus and must not crash on it (docs/style.md habit 6):
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


class Segment:
    """``level(t) = B + C exp(-k (t - t_origin)^n)`` from ``t_start_s`` (normalised thrust).

    Immutable by convention (a change of target makes a new segment). ``rise``: True for
    ``k1, n1``, False for ``k2, n2``. ``row`` is ``(t_start_s, t_origin_s, b, c, rise as 0/1)``,
    the segment's row in ``ThrusterBank.impulse_on_grid``.
    """

    __slots__ = ("t_start_s", "t_origin_s", "b", "c", "rise", "row")

    def __init__(self, t_start_s: float, t_origin_s: float, b: float, c: float,
                 rise: bool) -> None:
        self.t_start_s = t_start_s
        self.t_origin_s = t_origin_s
        self.b = b
        self.c = c
        self.rise = rise
        self.row = (t_start_s, t_origin_s, b, c, 1.0 if rise else 0.0)

    def __repr__(self) -> str:
        return (f"Segment(t_start_s={self.t_start_s!r}, t_origin_s={self.t_origin_s!r}, "
                f"b={self.b!r}, c={self.c!r}, rise={self.rise!r})")

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
    started since the last call in closed form. Only the thrusters whose segment is not
    identically zero (``_lit``) are visited; an idle one, or one at rest after a decay, costs
    nothing.
    """

    def __init__(self, n: int, prof: ThrustProfile) -> None:
        self.n = n
        self.prof = prof
        self.current: list[Segment] = [Segment(0.0, 0.0, 0.0, 0.0, False) for _ in range(n)]
        self.target = [0.0] * n
        # Segments of the chunk being built: (thruster, Segment), in time order per thruster.
        self._pending: list[tuple[int, Segment]] = []
        self._chunk_start: list[Segment] = list(self.current)
        # Thrusters whose current segment is not identically zero (b or c != 0), now and at
        # the chunk start.
        self._lit: set[int] = set()
        self._lit_start: set[int] = set()
        self._full1 = prof.k1 ** (-1.0 / prof.n1) * float(_gamma(1.0 + 1.0 / prof.n1))
        self._full2 = prof.k2 ** (-1.0 / prof.n2) * float(_gamma(1.0 + 1.0 / prof.n2))

    def level(self, j: int, t_s: float) -> float:
        return self.current[j].level(t_s, self.prof)

    def set_target(self, j: int, t_s: float, target: float) -> None:
        """From ``t_s`` on, thruster ``j`` moves toward ``target`` (normalised thrust)."""
        if target == self.target[j]:
            return
        self.target[j] = target
        p = self.prof
        cur = self.current[j]
        a = cur.b if cur.c == 0.0 else cur.level(t_s, p)
        if target > a:
            # Rise along eq. 4.1 scaled to the target; shift the origin back to pass through a.
            x0 = 0.0 if a <= 0.0 else (-math.log1p(-a / target) / p.k1) ** (1.0 / p.n1)
            seg = Segment(t_s, t_s - x0, target, -target, True)
        elif target < a:
            seg = Segment(t_s, t_s, target, a - target, False)
        else:
            seg = Segment(t_s, t_s, target, 0.0, False)
        self.current[j] = seg
        if seg.b != 0.0 or seg.c != 0.0:
            self._lit.add(j)
        else:
            self._lit.discard(j)
        self._pending.append((j, seg))

    def start_chunk(self, t0_s: float) -> None:
        """Begin a chunk at ``t0_s``: remember the segments in force (call before the chunk's
        ``set_target`` calls). Segments at their target to double precision become constants."""
        cur, p = self.current, self.prof
        k1, n1, k2, n2 = p.k1, p.n1, p.k2, p.n2
        for j in list(self._lit):
            seg = cur[j]
            if seg.c == 0.0:
                continue
            x = t0_s - seg.t_origin_s  # Segment.saturated, inline
            if x > 0 and (k1 * x**n1 if seg.rise else k2 * x**n2) > _SATURATED_EXPONENT:
                cur[j] = Segment(seg.t_start_s, seg.t_origin_s, seg.b, 0.0, seg.rise)
                if seg.b == 0.0:
                    self._lit.discard(j)
        self._chunk_start = list(cur)
        self._lit_start = set(self._lit)
        self._pending = []

    def impulse_on_grid(self, t_grid_s: Sequence[float], weights: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray] | None:
        """Exact normalised impulse over each grid interval of the chunk.

        ``t_grid_s`` (K+1,) increasing, starting at the chunk start; ``weights`` (N, W)
        per-thruster factors (actual thrust times direction, lever arm, mode shapes...).
        Returns ``(per_step (K, W), per_thruster (N,))``: ``per_step[k] = sum_j w_j
        int_{t_k}^{t_k+1} level_j dt`` and the normalised impulse of each thruster over the
        chunk (seconds of full thrust); None when no thruster gives any thrust in the chunk
        (both would be zeros).
        """
        t0 = float(t_grid_s[0])
        start = self._chunk_start
        chains: dict[int, list[Segment]] = {}
        for j, seg in self._pending:
            chain = chains.get(j)
            if chain is None:
                chains[j] = [start[j], seg]
            else:
                chain.append(seg)
        self._pending = []
        live = self._lit_start.union(chains) if chains else self._lit_start
        # One row per segment that gives thrust in the chunk, in thruster order (the order of
        # the sums in per_step): start, origin, B, C, rise (Segment.row), then its end.
        flat: list[float] = []
        thr: list[int] = []
        kinds: set[float] = set()  # kinds (rise 1.0 / decay 0.0) of the moving segments
        inf = math.inf
        for j in sorted(live):
            chain = chains.get(j)
            if chain is None:  # lit through the whole chunk on the segment in force
                row = start[j].row
                flat += row
                flat.append(inf)
                thr.append(j)
                if row[3] != 0.0:
                    kinds.add(row[4])
                continue
            last = len(chain) - 1
            for i, seg in enumerate(chain):
                end = chain[i + 1].t_start_s if i < last else inf
                if end <= seg.t_start_s or (seg.b == 0.0 and seg.c == 0.0):
                    continue
                row = seg.row
                flat += row
                flat.append(end)
                thr.append(j)
                if row[3] != 0.0:
                    kinds.add(row[4])
        self._chunk_start = list(self.current)
        self._lit_start = set(self._lit)
        if not thr:
            return None
        ts, to, b, c, rise, te = np.array(flat).reshape(len(thr), 6).T
        p = self.prof
        # Each segment's integration limits clipped to the chunk: a first row at the segment's
        # own lower limit lo = max(ts, t0) (the -inf point clips to it), then the grid points.
        lo = np.maximum(ts, t0)
        x = np.minimum(np.maximum(np.array((-inf, *t_grid_s))[:, None], lo),
                       np.maximum(te, lo))  # (K+2, S)
        cum = b * (x[1:] - lo)  # cumulative integral of each segment to every grid point
        if kinds:
            xs = x - to  # >= 0: a segment's origin is never after its start
            if 1.0 in kinds:
                e = _e_vec(p.k1, p.n1, self._full1, xs)
                if 0.0 in kinds:
                    e = np.where(rise, e, _e_vec(p.k2, p.n2, self._full2, xs))
            else:
                e = _e_vec(p.k2, p.n2, self._full2, xs)
            # Constant segments (C = 0) add exact zeros (e is finite everywhere).
            cum += c * (e[1:] - e[0])
        per_step = (cum[1:] - cum[:-1]) @ weights[thr]  # (K, W)
        per_thr = np.bincount(thr, weights=cum[-1], minlength=self.n)
        return per_step, per_thr
