"""Thruster fault detector: integral residuals with forgetting (seed 000; seed 003).

Every tick (docs/design.md 6.4), with ``dw`` (3,) the residual ``w_obs - w_calc`` in body axes
(rad/s):

1. dead zone: ``|dw| < dead_zone_rad_s`` -> ``dw_n = 0``; otherwise ``dw_n = dw / |dw|``
   (seed 000: the normalisation keeps a strong thruster's fault from tripping a weak one first);
2. ``xi_i = (dw_n, e_i)``, ``e_i = mu_i / |mu_i|`` the unit angular acceleration of thruster i
   (seed 003: not the control axes);
3. ``rho_off,i = w_off rho_off,i + xi_i`` on ticks i was not commanded,
   ``rho_on,i = w_on rho_on,i + xi_i`` on ticks it was (seed 000, seed 003);
4. opposing pairs (seed 000 tables 1-2): a tick on which i and a thruster with the opposite
   acceleration direction were both commanded says nothing about i (the residual cannot be
   shared between them), so ``rho_on,i`` keeps its value on that tick. Ticks with only one of the
   pair commanded are used: seed 000's stuck-on case shows rho_off of X+ and rho_on of X- both
   growing while X- fires against the stuck X+;
5. stuck on: ``rho_off,i > threshold_off``; fails to fire: ``rho_on,i < -threshold_on``. The first
   crossing names the thruster and the type. When several cross on the same tick, the largest
   ratio to its threshold wins, then fails-to-fire before stuck-on (a failed thruster commanded on
   every tick moves rho_on of itself and rho_off of its opposite by the same amount; only the
   missing residual on ticks without the command separates them, and stuck-on would have shown
   there), then the lower index;
6. thrusters whose directions agree within ``same_direction_deg`` cannot be told apart (seed 003's
   stated limit): the detection carries the whole group ("one of {i, j}").

Single-fault assumption: after a detection the detector is latched (no new detection) until
``rebaseline()``, which FDIR calls after its response; ``rebaseline`` zeroes every residual and
skips ``hold_ticks`` ticks so the response itself (a closing manifold, the tail of the stuck
thruster's thrust) is not read as a new fault. Thrusters that are not available (dropped, on a
closed manifold) are not monitored: their residuals stay at zero.

Progressions (seed 000): for a constant ``xi``, ``rho[n] = xi (1 - w^(n+1)) / (1 - w)`` tends to
``xi / (1 - w)``; a single outlier decays as ``xi w^n``. Choose the thresholds below the limit
(``flight/thresholds.py``).

Arrays: N thrusters; ``rho_on``, ``rho_off``, ``xi`` (N,); ``active``, ``available`` (N,) bool.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.vehicle import DetectorCfg

STUCK_ON = "stuck_on"
FAIL_TO_FIRE = "fail_to_fire"
DEGRADED = "degraded"
GYRO_FAULT = "gyro_fault"


@dataclass(frozen=True)
class Detection:
    """A detected thruster fault.

    ``thruster`` the index whose residual crossed; ``group`` every thruster with the same
    direction (indices, sorted, includes ``thruster``); ``kind`` ``stuck_on`` or
    ``fail_to_fire``, ``degraded`` or ``gyro_fault`` (a sensor fault: ``thruster`` is -1, the
    group empty, ``names`` the fault's kind, ``flight.gyro_check``); ``rho`` the residual value
    at the crossing (the thrust fraction for ``effectiveness``, the fitted leak for
    ``leak_fit``); ``source`` ``residual`` (seed
    000/003), ``kalman`` (seed 002 leak test), ``effectiveness`` (the burn-fraction test,
    ``Effectiveness.weak``), ``leak_fit`` (the leak-fit test, ``flight.software``), ``gyro``,
    or ``isolation`` (renamed, or decided after a probe, by
    the flight's isolation of opposite thrusters, ``flight.software``); ``fraction`` the
    estimated thrust fraction of a degraded (or failed) thruster.
    """

    tick: int
    thruster: int
    kind: str
    group: tuple[int, ...]
    names: tuple[str, ...]
    rho: float
    source: str = "residual"
    fraction: float | None = None

    @property
    def ambiguous(self) -> bool:
        return len(self.group) > 1

    def describe(self) -> str:
        if self.kind == GYRO_FAULT:
            return f"gyro fault ({self.names[0] if self.names else 'unknown'})"
        who = self.names[0] if len(self.names) == 1 else "one of {" + ", ".join(self.names) + "}"
        return f"{who} {self.kind}"


@dataclass(frozen=True)
class DetectorOutput:
    """One detector tick: ``xi`` (N,), ``rho_on`` (N,), ``rho_off`` (N,) (copies), ``dw_norm_rad_s``
    the residual's norm, ``dead_zone`` whether it was zeroed, ``detection`` (new on this tick or
    None), ``held`` the tick was skipped after a re-baseline."""

    xi: np.ndarray
    rho_on: np.ndarray
    rho_off: np.ndarray
    dw_norm_rad_s: float
    dead_zone: bool
    detection: Detection | None
    held: bool


def unit_directions(mu_B_rad_s2: np.ndarray) -> np.ndarray:
    """Unit angular-acceleration vectors e_i (N, 3) of the thrusters; zero rows stay zero."""
    mu = np.asarray(mu_B_rad_s2, dtype=float)
    n = np.linalg.norm(mu, axis=1, keepdims=True)
    return np.divide(mu, n, out=np.zeros_like(mu), where=n > 0)


def direction_groups(e_B: np.ndarray, same_direction_deg: float) -> list[tuple[int, ...]]:
    """For each thruster, the sorted indices whose e agree within the angle (itself included)."""
    cos_tol = math.cos(math.radians(same_direction_deg))
    c = e_B @ e_B.T
    return [tuple(int(j) for j in np.flatnonzero(c[i] >= cos_tol - 1e-12)) for i in range(len(e_B))]


def opposite_matrix(e_B: np.ndarray, opposite_deg: float) -> np.ndarray:
    """(N, N) bool: e_j within ``opposite_deg`` of -e_i."""
    cos_tol = math.cos(math.radians(opposite_deg))
    return (e_B @ e_B.T) <= -(cos_tol - 1e-12)


# Ticks of a thruster's own burns the reported thrust fraction is the mean of.
_FRACTION_TICKS = 3
# Burns too small to be measured alone kept per thruster (``Effectiveness.fraction_since``).
_SMALL_BURNS_KEPT = 50
# Burns kept per thruster for ``Effectiveness.fraction_since`` (a detection's evidence window
# is at most a few seconds of ticks; a thruster burns on some of them).
_FRACTION_KEPT = 16
# A burn is measurable alone when it moves the rate by this many residual-noise sigmas
# (``|mu_j eff_j| >= _MEASURABLE_SIGMA sqrt(r_var)``); smaller ones count only together.
_MEASURABLE_SIGMA = 2.0
# The absolute dead zone widens in proportion to the sensor noise when the quiet ticks show
# more than its long-run level (GyroCheck.noise_ratio), so a noisier gyro does not read as
# thrusters. Relative, not absolute: a vehicle's residual on quiet ticks holds more than its
# sensor (3.5 times the measured noise was 1.7 times generic's configured dead zone at the
# median of a fault-free run, and cost it two degraded thrusters of twelve). Only beyond
# NOISE_MARGIN: the median of 20 squares fluctuates by tens of % on a steady sensor, and a
# dead zone widened by that moved REC-nofire's detection a second and named it degraded.
NOISE_MARGIN = 1.2


# Normalised innovation (chi^2, 3 degrees of freedom) above which the effectiveness estimate of
# the burning thrusters restarts from its prior variance: 25 is ~1e-5 for a consistent filter.
_CHI2_RESET = 25.0


class Effectiveness:
    """Online, bounded effectiveness of each thruster (seed 003 identifies an influence
    coefficient; this is the same idea per thruster).

    The onboard model predicts the thrusters' rate change as ``sum_j k_j mu_j eff_j``. On every
    tick, ``z = r + sum_j k_j mu_j eff_j`` (the residual ``r`` plus what was predicted) is a
    measurement of::

        z = sum_j theta_j mu_j eff_j + sum_j lambda_j mu_j (h - eff_j)

    ``theta_j`` the thruster's actual thrust over nominal while it burns, ``lambda_j`` its
    leak (thrust fraction while the valve is meant to be closed). Both are estimated by one
    Kalman filter (random walks, prior variances ``p0`` and ``p0_leak``, process variances
    ``q`` and ``q_leak`` per tick, measurement variance ``r_var`` per axis). The leak terms are
    what keeps the effectiveness clean: a lit thruster 15 % weak and its opposite leaking 15 %
    look alike on the ticks the first fires (seed 002 uses only ticks with no command for a
    leak), and only the ticks where neither fires tell them apart; with both in the model the
    filter puts the residual where the timing says it belongs. The leak is not fed back (a
    leak is a fault: its evidence stays in the residual for the detector).

    What the model uses is ``k = clip(theta, 1 - bound, 1 + bound)``: thrust errors of the
    size the vehicle admits (DESIGN 10: +/-15 %) are learnt and stop reading as faults, while
    a thruster that fails to fire or is degraded below the bound leaves the rest of its error
    in the residual, so the commanded evidence judges it against the learnt effectiveness.
    ``fraction`` is reported with a degraded detection. An innovation beyond the random walk
    (chi^2 above ``_CHI2_RESET``) restarts the variance of the burning thrusters' ``theta``
    and of every leak, so a new thrust is estimated within a few ticks.

    ``common_share`` (in [0, 1)) is the share of the thrust scales' prior variance ``p0``
    that all thrusters have in common: the prior covariance of theta is
    ``p0 (c 1 1^T + (1 - c) I)``, so the filter learns a common scale error from whichever
    thrusters fire, and each thruster's own error on top of it (the envelope of DESIGN 10
    stacks a global and a per-thruster +/-15 %).

    ``trust()`` keeps a copy of the estimate while the detector's evidence is quiet; after a
    response ``restore()`` goes back to it, so what the fault pushed does not carry into the
    new configuration.
    """

    def __init__(self, mu_B_rad_s2: np.ndarray, bound: float, r_var: float, tick_s: float,
                 p0: float = 0.04, q: float = 1e-4, p0_leak: float = 0.01,
                 q_leak: float = 1e-6, latency_bound_s: float = 0.0,
                 q_latency: float = 1e-10, latency_floor_s: float | None = None,
                 common_share: float = 0.0) -> None:
        self.mu = np.asarray(mu_B_rad_s2, dtype=float)
        n = len(self.mu)
        self.n = n
        self.h = float(tick_s)
        self.bound = float(bound)
        self.r_var = float(r_var)
        # Last state (when latency_bound_s > 0): the command latency's offset from the onboard
        # model's nominal one, s, within [floor, bound] (floor: -nominal, a latency is never
        # negative; default -bound); prior standard deviation half the bound.
        self.latency_bound_s = float(latency_bound_s)
        self.latency_floor_s = (-self.latency_bound_s if latency_floor_s is None
                                else max(float(latency_floor_s), -self.latency_bound_s))
        lat = [] if self.latency_bound_s <= 0.0 else [0.0]
        self.p0 = np.concatenate([np.full(n, p0), np.full(n, p0_leak),
                                  np.full(len(lat), (0.5 * self.latency_bound_s) ** 2)])
        self.q = np.concatenate([np.full(n, q), np.full(n, q_leak), np.full(len(lat), q_latency)])
        self.x = np.concatenate([np.ones(n), np.zeros(n), lat])
        self.P = np.diag(self.p0)
        if not 0.0 <= common_share < 1.0:
            raise ValueError(f"common_share: expected a value in [0, 1), got {common_share}")
        self.P[:n, :n] += float(common_share) * p0 * (np.ones((n, n)) - np.eye(n))
        self._trusted = (self.x.copy(), self.P.copy())
        # Per thruster: (update count, thrust over nominal) of its last burns (``fraction``).
        self._recent: list[list[tuple[int, float]]] = [[] for _ in range(n)]
        # The same from the raw residual, when ``update`` is given it (``weak`` with ``raw``).
        self._recent_raw: list[list[tuple[int, float]]] = [[] for _ in range(n)]
        # Per thruster: (update count, burn weight |mu_j eff_j|^2, thrust over nominal) of its
        # last burns of any size: their weighted mean stands in for ``theta`` when none of the
        # window's burns is measurable alone (``fraction_since``).
        self._burns: list[list[tuple[int, float, float]]] = [[] for _ in range(n)]
        self.updates = 0  # calls of ``update`` so far: the stamp of the next one's burns
        self.kept = _FRACTION_KEPT  # burns kept per thruster (at least the weak test's)
        self._since = 0  # the first update whose burns ``weak`` reads (after a restore)
        # With ``chunk_small``, consecutive burns too small to measure alone are summed per
        # thruster (weight, weighted innovation and raw fractions) until they weigh as much as
        # one measurable burn, then kept as one burn (stamp, fraction) in ``_chunks`` (and
        # ``_chunks_raw``), which ``weak`` with ``small`` reads beside the measurable burns.
        self.chunk_small = False
        self._chunk: list[list[float]] = [[0.0, 0.0, 0.0] for _ in range(n)]
        self._chunks: list[list[tuple[int, float]]] = [[] for _ in range(n)]
        self._chunks_raw: list[list[tuple[int, float]]] = [[] for _ in range(n)]

    @property
    def theta(self) -> np.ndarray:
        return self.x[: self.n]

    @property
    def leak(self) -> np.ndarray:
        return self.x[self.n: 2 * self.n]

    @property
    def latency_s(self) -> float:
        """Learnt command-latency offset (s) from the nominal, within [floor, bound] (0 when
        the latency is not learnt)."""
        if self.latency_bound_s <= 0.0:
            return 0.0
        return float(np.clip(self.x[2 * self.n], self.latency_floor_s, self.latency_bound_s))

    @property
    def k(self) -> np.ndarray:
        """(N,) effectiveness the onboard model uses (bounded)."""
        if self.bound <= 0.0:
            return np.ones(self.n)
        return np.clip(self.theta, 1.0 - self.bound, 1.0 + self.bound)

    @property
    def fraction(self) -> np.ndarray:
        """(N,) thrust over nominal each thruster showed on its last ``_FRACTION_TICKS``
        ticks with a burn worth twice the residual noise (else ``theta``), every other
        thruster taken as predicted: ``k_j + (mu_j eff_j) . r / |mu_j eff_j|^2``, their
        median (one burn may straddle the fault: a thruster that failed to fire 81 % into a
        burn and then gave 11 % and -15 % read 25 % on the mean, named degraded; kalman_cube-
        faults run 31), in [0, 1.5]. It answers "what is left of this thruster's thrust"
        once the commanded evidence named it, which the joint estimate cannot yet tell from an
        opposite thruster leaking so soon after the fault."""
        return self._fraction(healthiest=False)

    @property
    def fraction_healthiest(self) -> np.ndarray:
        """(N,) the larger of the mean and the median of the same burns as ``fraction``: what
        the "within the admitted errors, not a fault" checks read, so that one burn, low or
        high, never turns a thruster the mean would pass into a fault."""
        return self._fraction(healthiest=True)

    def _fraction(self, healthiest: bool) -> np.ndarray:
        return np.array([self.fraction_since(j, -1, healthiest) for j in range(self.n)])

    def fraction_since(self, j: int, stamp: int, healthiest: bool = False) -> float:
        """``fraction[j]`` (``fraction_healthiest[j]`` with ``healthiest``) from the burns of
        updates ``stamp`` and later only (a detection's evidence window: the burns before the
        fault say nothing of what is left); ``theta`` when there was none. With a 30 ms
        actuation phase a burn spills past the next sample, and the last three burns of a
        thruster that failed to fire still held one from before the fault (105 %): it read
        27 % on their mean and was named degraded."""
        since = [f for t, f in self._recent[j] if t >= stamp][-_FRACTION_TICKS:]
        if not since:
            value = self.theta[j]
            if not healthiest:
                # What is named (not what decides): with no burn measurable alone (a full tick
                # of iss_rs's SM yaw or P2 roll thrusters moves the rate by less than twice the
                # residual noise), the last burns together, newest first, until they weigh as
                # much as _FRACTION_TICKS measurable ones, each weighted by its size, when they
                # add up to one at least. Theta follows a thrust change only over many ticks: a
                # P2 roll thruster that failed to fire while burning every tick still read 0.79
                # eight seconds later, named degraded.
                one = _MEASURABLE_SIGMA**2 * self.r_var  # |mu_j eff_j|^2 of a measurable burn
                weight = total = 0.0
                for t, w, f in reversed(self._burns[j]):
                    if t < stamp or weight >= _FRACTION_TICKS * one:
                        break
                    weight += w
                    total += w * f
                if weight >= one:
                    value = total / weight
        elif healthiest:
            value = max(np.mean(since), np.median(since))
        else:
            value = np.median(since)
        return float(np.clip(value, 0.0, 1.5))

    def update(self, residual_B_rad_s: np.ndarray, eff_s: np.ndarray, use: np.ndarray,
               deff_dlat: np.ndarray | None = None, raw_B_rad_s: np.ndarray | None = None,
               learn: bool = True) -> None:
        """One tick: ``eff_s`` (N,) equivalent burn in the interval, ``use`` (N,) bool
        (available); ``residual`` measured minus predicted with the current ``k`` and the
        current ``latency_s``; ``deff_dlat`` (N,) the change of ``eff_s`` per second of extra
        command latency (the onboard model's, ``OnboardModel.latency_sensitivity``);
        ``raw_B_rad_s`` the same tick's raw residual (before the observer), whose burn
        fractions ``weak`` reads with ``raw``; it is not learnt from. ``learn`` False: the
        burns' fractions are kept, the thrust scales, leaks and latency are not updated."""
        n = self.n
        lat = self.latency_bound_s > 0.0 and deff_dlat is not None
        # eff may be negative for an integrating gyro (the change of the mean burn): the thrust
        # term is linear in it either way; the closed time is what is left of the tick.
        e = np.asarray(eff_s, dtype=float)
        closed = self.h - np.clip(e, 0.0, self.h)
        avail = np.asarray(use, dtype=bool)
        burn = avail & (e != 0.0)
        cols = np.concatenate([np.flatnonzero(burn), n + np.flatnonzero(avail)])
        H = np.concatenate([(self.mu * e[:, None])[burn],
                            (self.mu * closed[:, None])[avail]]).T
        r = np.asarray(residual_B_rad_s, dtype=float)
        k_used = self.k
        lat_used = self.latency_s
        if lat:
            # z = thrust part + g (latency - nominal): g the thrust part's sensitivity.
            g = self.mu.T @ (k_used * np.where(avail, np.asarray(deff_dlat, float), 0.0))
            cols = np.concatenate([cols, [2 * n]])
            H = np.concatenate([H, g[:, None]], axis=1)
        big = np.linalg.norm(self.mu, axis=1) * e >= _MEASURABLE_SIGMA * math.sqrt(self.r_var)
        stamp = self.updates
        self.updates += 1
        for j in np.flatnonzero(burn & big):
            phi = self.mu[j] * e[j]
            hist = self._recent[j]
            hist.append((stamp, float(k_used[j] + phi @ r / (phi @ phi))))
            del hist[:-self.kept]
            if raw_B_rad_s is not None:
                hist = self._recent_raw[j]
                hist.append((stamp, float(k_used[j] + phi @ np.asarray(raw_B_rad_s, float)
                                          / (phi @ phi))))
                del hist[:-self.kept]
        one = _MEASURABLE_SIGMA**2 * self.r_var  # |mu_j eff_j|^2 of a measurable burn
        for j in np.flatnonzero(burn & ~big & (e > 0.0)):
            phi = self.mu[j] * e[j]
            w = float(phi @ phi)
            hist = self._burns[j]
            f = float(k_used[j] + phi @ r / w)
            hist.append((stamp, w, f))
            del hist[:-_SMALL_BURNS_KEPT]
            if self.chunk_small:
                # Consecutive small burns, together as heavy as one measurable burn, count as
                # one: their size-weighted fraction (the raw residual's too).
                fr = (float(k_used[j] + phi @ np.asarray(raw_B_rad_s, float) / w)
                      if raw_B_rad_s is not None else math.nan)
                c = self._chunk[j]
                c[0] += w
                c[1] += w * f
                c[2] += w * fr
                if c[0] >= one:
                    self._chunks[j].append((stamp, c[1] / c[0]))
                    del self._chunks[j][:-self.kept]
                    if raw_B_rad_s is not None:
                        self._chunks_raw[j].append((stamp, c[2] / c[0]))
                        del self._chunks_raw[j][:-self.kept]
                    self._chunk[j] = [0.0, 0.0, 0.0]
        if self.bound <= 0.0 or not learn:
            return  # learning off: only the measured fraction above
        d = np.diag_indices(len(self.x))
        self.P[d] = np.minimum(np.diag(self.P) + self.q, self.p0)
        z = r + self.mu.T @ (k_used * e)
        if lat:
            z = z + g * lat_used
        nu = z - H @ self.x[cols]
        S = H @ self.P[np.ix_(cols, cols)] @ H.T + self.r_var * np.eye(3)
        S_inv = np.linalg.inv(S)
        if float(nu @ S_inv @ nu) > _CHI2_RESET:
            # The thrust changed beyond the random walk (a fault, a first firing far from
            # nominal): the burning thrusters' theta and every leak restart from the prior.
            reset = np.concatenate([np.flatnonzero(burn), n + np.arange(n)])
            self.P[reset, :] = 0.0
            self.P[:, reset] = 0.0
            self.P[reset, reset] = self.p0[reset]
            S = H @ self.P[np.ix_(cols, cols)] @ H.T + self.r_var * np.eye(3)
            S_inv = np.linalg.inv(S)
        Pc = self.P[:, cols]                                     # (2N, C)
        K = Pc @ H.T @ S_inv                                     # (2N, 3)
        self.x = self.x + K @ nu
        self.P = self.P - K @ (H @ Pc.T)
        self.P = 0.5 * (self.P + self.P.T)
        # A leak is thrust of a closed valve: never negative. Without this, an opposite pair
        # "both leaking and both weaker" is the same data as neither (the leaks cancel).
        np.clip(self.x[n: 2 * n], 0.0, None, out=self.x[n: 2 * n])
        if self.latency_bound_s > 0.0:
            self.x[2 * n] = self.latency_s

    def weak(self, below: float, sigma: float, burns: int, use: np.ndarray,
             raw: bool = False, first: int = 0, small: bool = False) -> int | None:
        """Burn-fraction test: of the usable thrusters whose last ``burns`` measurable burns
        since the last ``restore`` average below ``below`` by ``sigma`` standard errors (the
        burns' own scatter), the one with the lowest upper bound; None when there is none.
        With ``raw``, the same burns' fractions from the raw residual must fall below too
        (a burn ``update`` was given no raw residual for counts as not short). Only the burns
        of update ``first`` and later are read. With ``small``, the small burns counted
        together (``chunk_small``) are read beside the measurable ones."""
        best: tuple[float, int] | None = None
        since = max(self._since, int(first))
        for j in np.flatnonzero(np.asarray(use, dtype=bool)):
            hist, hist_raw = self._hists(j, small)
            upper = self._upper(hist, sigma, burns, since)
            if raw and upper < float(below):
                stamps = {t for t, _ in hist if t >= since}
                tail = sorted(stamps)[-int(burns):]
                mine = [(t, f) for t, f in hist_raw if t >= tail[0] and t in stamps]
                upper = max(upper, self._upper(mine, sigma, burns, since)
                            if len(mine) == len(tail) else math.inf)
            if upper < float(below) and (best is None or upper < best[0]):
                best = (upper, int(j))
        return None if best is None else best[1]

    def _hists(self, j: int, small: bool) -> tuple[list[tuple[int, float]],
                                                    list[tuple[int, float]]]:
        """Thruster ``j``'s (burns, raw burns) in stamp order: the measurable ones, with
        ``small`` the small ones counted together too (a small burn closing a chunk and a
        measurable one never share a stamp: each update gives a thruster one burn)."""
        if not small:
            return self._recent[j], self._recent_raw[j]
        return (sorted(self._recent[j] + self._chunks[j]),
                sorted(self._recent_raw[j] + self._chunks_raw[j]))

    def burn_mean(self, j: int, burns: int, first: int = 0, small: bool = False) -> float:
        """Mean thrust over nominal of thruster ``j``'s last ``burns`` burns since the last
        ``restore`` and of update ``first`` or later (what ``weak`` read, with ``small`` as
        there), in [0, 1.5]; ``theta`` when there are fewer."""
        since = max(self._since, int(first))
        fr = [f for t, f in self._hists(j, small)[0] if t >= since][-int(burns):]
        value = float(np.mean(fr)) if len(fr) >= int(burns) else float(self.theta[j])
        return float(np.clip(value, 0.0, 1.5))

    def last_burn(self, j: int) -> tuple[float, float] | None:
        """Thruster ``j``'s measurable burn of the last update, (thrust over nominal on the
        innovation, on the raw residual: the innovation's when the update had none); None when
        it had none."""
        hist = self._recent[j]
        stamp = self.updates - 1
        if not hist or hist[-1][0] != stamp:
            return None
        f = hist[-1][1]
        raw = self._recent_raw[j]
        return f, (raw[-1][1] if raw and raw[-1][0] == stamp else f)

    def forget_burns(self) -> None:
        """``weak`` reads only the burns of the next updates (as after a ``restore``)."""
        self._since = self.updates
        self._chunk = [[0.0, 0.0, 0.0] for _ in range(self.n)]

    def _upper(self, hist: list[tuple[int, float]], sigma: float, burns: int,
               since: int) -> float:
        """Mean plus ``sigma`` standard errors of the last ``burns`` fractions of ``hist``
        from update ``since`` (infinity when there are fewer)."""
        fr = [f for t, f in hist if t >= since][-int(burns):]
        if len(fr) < int(burns):
            return math.inf
        return float(np.mean(fr)) + float(sigma) * float(np.std(fr, ddof=1)) / math.sqrt(len(fr))

    def rate_change_cov(self, eff_s: np.ndarray, use: np.ndarray,
                        deff_dlat: np.ndarray | None = None) -> np.ndarray:
        """(3, 3) covariance of the predicted rate change of the burning thrusters from the
        uncertainty of their thrust scales and, when the latency is learnt and ``deff_dlat``
        given, of the command latency: ``A P A^T``, ``A`` the columns ``mu_j eff_j`` of the
        burning, usable thrusters (and ``sum_j mu_j k_j deff_dlat_j``)."""
        use = np.asarray(use, dtype=bool)
        e = np.where(use, np.asarray(eff_s, dtype=float), 0.0)
        cols = list(np.flatnonzero(e != 0.0))
        A = [self.mu[j] * e[j] for j in cols]
        if self.latency_bound_s > 0.0 and deff_dlat is not None:
            cols.append(2 * self.n)
            A.append(self.mu.T @ (self.k * np.where(use, np.asarray(deff_dlat, float), 0.0)))
        if not cols:
            return np.zeros((3, 3))
        A = np.array(A).T
        return A @ self.P[np.ix_(cols, cols)] @ A.T

    def trust(self) -> None:
        self._trusted = (self.x.copy(), self.P.copy())

    def restore(self) -> None:
        """After a response: back to the last trusted estimate."""
        self.x, self.P = self._trusted[0].copy(), self._trusted[1].copy()
        self._since = self.updates
        self._chunk = [[0.0, 0.0, 0.0] for _ in range(self.n)]


def leak_or_deficit(y: np.ndarray, burn_i: np.ndarray, closed_j: np.ndarray) -> float:
    """Which of two hypotheses explains a residual better, over a window of ticks (seed 002:
    a leak shows on the ticks its thruster is not commanded; a weak thruster only on its own).

    ``y`` (W,) the residual along the failing candidate i's direction (negative when i gives
    less than predicted), ``burn_i`` (W,) i's commanded rate change ``|mu_i| eff_i``,
    ``closed_j`` (W,) the opposite candidate j's closed-valve rate change ``|mu_j| (h -
    eff_j)``. Each hypothesis is a one-parameter least-squares fit, ``y = -d burn_i`` (i
    degraded or failed) or ``y = -f closed_j`` (j stuck on): returns ``RSS_leak / RSS_deficit``
    (below 1: the leak fits better); 1 when the two regressors cannot be told apart (collinear
    over the window) or there is nothing to fit."""
    y = np.asarray(y, dtype=float)
    out = []
    for x in (np.asarray(burn_i, dtype=float), np.asarray(closed_j, dtype=float)):
        xx = float(x @ x)
        if xx <= 0.0:
            out.append(float(y @ y))
            continue
        c = float(x @ y) / xx
        out.append(float(((y - c * x) ** 2).sum()))
    rss_def, rss_leak = out
    b1, b2 = np.asarray(burn_i, float), np.asarray(closed_j, float)
    den = math.sqrt(float(b1 @ b1) * float(b2 @ b2))
    if den <= 0.0 or float(b1 @ b2) / den > 0.999 or max(rss_def, rss_leak) <= 0.0:
        return 1.0
    return rss_leak / max(rss_def, 1e-300)


class Detector:
    """Seed 000 / seed 003 detector over N thrusters.

    ``step(tick, dw_B_rad_s, active, available=None) -> DetectorOutput``; ``active`` (N,) bool:
    the thruster was commanded over the tick the residual covers.
    ``opposite_deg`` (default ``same_direction_deg``) decides which pairs are opposing.
    """

    def __init__(self, mu_B_rad_s2: np.ndarray, cfg: DetectorCfg,
                 names: tuple[str, ...] | None = None, opposite_deg: float | None = None,
                 hold_ticks: int = 2, effectiveness: Effectiveness | None = None) -> None:
        self.cfg = cfg
        self.effectiveness = effectiveness
        self.e_B = unit_directions(mu_B_rad_s2)
        n = len(self.e_B)
        self.names = tuple(names) if names else tuple(str(i) for i in range(n))
        self.groups = direction_groups(self.e_B, cfg.same_direction_deg)
        self.opposite = opposite_matrix(
            self.e_B, cfg.same_direction_deg if opposite_deg is None else opposite_deg)
        self.hold_ticks = int(hold_ticks)
        self.noise_ratio = 1.0  # sensor noise against its long-run level, set by the flight
        self.thresholds_on = np.full(n, float(cfg.threshold_on))
        self.thresholds_off = np.full(n, float(cfg.threshold_off))
        self.rho_on = np.zeros(n)
        self.rho_off = np.zeros(n)
        self.latched: Detection | None = None
        self._hold = 0

    @property
    def n(self) -> int:
        return len(self.e_B)

    def rebaseline(self, hold_ticks: int | None = None) -> None:
        """Zero every residual, clear the latch, skip the next ``hold_ticks`` ticks."""
        self.rho_on[:] = 0.0
        self.rho_off[:] = 0.0
        self.latched = None
        self._hold = self.hold_ticks if hold_ticks is None else int(hold_ticks)

    def in_ellipsoid(self, dw_B_rad_s: np.ndarray, commanded_rad_s: np.ndarray,
                     flex_sigma: np.ndarray | None = None) -> bool:
        """Ellipsoidal dead zone (``relative_dead_zone_across`` set): ``commanded_rad_s`` (N,)
        each thruster's commanded rate-change magnitude ``|mu_j| |k_j eff_j|``. The residual is
        inside when ``dw^T S^-1 dw < 1`` with ``S = dz^2 I + sum_j m_j^2 (a^2 e_j e_j^T + b^2
        (I - e_j e_j^T))``, ``a = relative_dead_zone``, ``b = relative_dead_zone_across``, plus
        ``diag(flex_sigma)^2`` (``flex_freq_dead_zone``, as in ``in_learnt_ellipsoid``)."""
        cfg = self.cfg
        m = np.abs(np.asarray(commanded_rad_s, dtype=float))
        a, b = cfg.relative_dead_zone, float(cfg.relative_dead_zone_across or 0.0)
        wa, wb = (m * a) ** 2, (m * b) ** 2
        S = (self.dead_zone_rad_s()**2 + float(wb.sum())) * np.eye(3) \
            + (self.e_B * (wa - wb)[:, None]).T @ self.e_B
        if flex_sigma is not None:
            S = S + np.diag(np.asarray(flex_sigma, dtype=float) ** 2)
        dw = np.asarray(dw_B_rad_s, dtype=float)
        if not np.any(dw):
            return True
        return float(dw @ np.linalg.solve(S, dw)) < 1.0

    def in_learnt_ellipsoid(self, dw_B_rad_s: np.ndarray, thrust_cov: np.ndarray,
                            flex_sigma: np.ndarray | None = None) -> bool:
        """Dead zone from the learning (``relative_dead_zone_sigma`` = kappa): inside when
        ``dw^T (dz^2 I + kappa^2 C + diag(k s)^2)^-1 dw < 1``, ``C`` (3, 3) the covariance of
        the burning thrusters' predicted rate change (``Effectiveness.rate_change_cov``),
        ``s`` (3,) the flex prediction's uncertainty per channel and ``k`` =
        ``flex_freq_dead_zone``."""
        cfg = self.cfg
        dw = np.asarray(dw_B_rad_s, dtype=float)
        if not np.any(dw):
            return True
        S = self.dead_zone_rad_s()**2 * np.eye(3) + \
            float(cfg.relative_dead_zone_sigma) ** 2 * np.asarray(thrust_cov, dtype=float)
        if flex_sigma is not None:
            S = S + np.diag(np.asarray(flex_sigma, dtype=float) ** 2)
        return float(dw @ np.linalg.solve(S, dw)) < 1.0

    def dead_zone_rad_s(self) -> float:
        """The absolute dead zone: ``dead_zone_rad_s`` times ``noise_ratio / NOISE_MARGIN``
        when that is over 1 (the gyro noisier than its long-run level, measured by the gyro
        check on quiet ticks)."""
        return self.cfg.dead_zone_rad_s * max(1.0, self.noise_ratio / NOISE_MARGIN)

    def project(self, dw_B_rad_s: np.ndarray, commanded_abs_rad_s: float = 0.0,
                inside: bool | None = None,
                extra_rad_s: float = 0.0) -> tuple[np.ndarray, float, bool]:
        """Steps 1-2: dead zone, normalisation and projections xi (N,).

        The dead zone is ``dead_zone_rad_s + relative_dead_zone * commanded_abs_rad_s +
        extra_rad_s`` (``commanded_abs_rad_s``: sum of the commanded thrusters' rate-change
        magnitudes; ``extra_rad_s``: the flex prediction's uncertainty,
        ``flex_freq_dead_zone``), unless ``inside`` was decided by the caller (the ellipsoid,
        ``in_ellipsoid``).
        """
        dw = np.asarray(dw_B_rad_s, dtype=float)
        norm = float(np.linalg.norm(dw))
        if inside is None:
            dz = (self.dead_zone_rad_s()
                  + self.cfg.relative_dead_zone * float(commanded_abs_rad_s) + extra_rad_s)
            inside = norm < dz
        if inside or norm == 0.0:
            return np.zeros(self.n), norm, True
        return self.e_B @ (dw / norm), norm, False

    def skip(self, dw_B_rad_s: np.ndarray) -> DetectorOutput:
        """A tick kept out of the evidence (gyro suspect): residuals unchanged, no decision."""
        norm = float(np.linalg.norm(np.asarray(dw_B_rad_s, dtype=float)))
        return self._out(np.zeros(self.n), norm, True, None, held=True)

    def quiet(self) -> bool:
        """Every residual below half its threshold (the evidence holds no suspicion)."""
        return bool(np.all(np.abs(self.rho_on) < 0.5 * self.thresholds_on)
                    and np.all(np.abs(self.rho_off) < 0.5 * self.thresholds_off))

    def step(self, tick: int, dw_B_rad_s: np.ndarray, active: np.ndarray,
             available: np.ndarray | None = None,
             commanded_abs_rad_s: float = 0.0, inside: bool | None = None) -> DetectorOutput:
        act = np.asarray(active, dtype=bool)
        avail = np.ones(self.n, dtype=bool) if available is None else np.asarray(available, bool)
        xi, norm, dz = self.project(dw_B_rad_s, commanded_abs_rad_s, inside)
        if self._hold > 0:
            self._hold -= 1
            return self._out(np.zeros(self.n), norm, dz, None, held=True)
        # Seed 000 tables 1-2: i commanded together with an opposite thruster -> skip rho_on,i.
        both = act & (self.opposite & act[None, :]).any(axis=1)
        on = act & avail & ~both
        off = ~act & avail
        self.rho_on = np.where(on, self.cfg.forgetting_on * self.rho_on + xi, self.rho_on)
        self.rho_off = np.where(off, self.cfg.forgetting_off * self.rho_off + xi, self.rho_off)
        self.rho_on[~avail] = 0.0
        self.rho_off[~avail] = 0.0
        detection = None
        if self.latched is None:
            detection = self._decide(tick, avail)
            self.latched = detection
        return self._out(xi, norm, dz, detection, held=False)

    def _decide(self, tick: int, avail: np.ndarray) -> Detection | None:
        r_fail = np.where(avail, -self.rho_on / self.thresholds_on, 0.0)
        r_stuck = np.where(avail, self.rho_off / self.thresholds_off, 0.0)
        cands = [(r_fail[i], 1, -i, i, FAIL_TO_FIRE) for i in np.flatnonzero(r_fail > 1.0)]
        cands += [(r_stuck[i], 0, -i, i, STUCK_ON) for i in np.flatnonzero(r_stuck > 1.0)]
        if not cands:
            return None
        _, _, _, i, kind = max(cands)
        i = int(i)
        eff = self.effectiveness
        if kind == FAIL_TO_FIRE and eff is not None and eff.bound > 0.0 \
                and eff.fraction_healthiest[i] >= 1.0 - eff.bound:
            # The thruster gives what the admitted thrust errors allow: the commanded evidence
            # ran ahead of the learning (a first firing), not a fault.
            return None
        group = tuple(j for j in self.groups[i] if avail[j])
        rho = float(self.rho_on[i] if kind == FAIL_TO_FIRE else self.rho_off[i])
        fraction = None
        if kind == FAIL_TO_FIRE and self.effectiveness is not None:
            # Commanded evidence against the learnt effectiveness: what is left of the thrust.
            fraction = float(self.effectiveness.fraction[i])
            if fraction >= self.cfg.fail_fraction:
                kind = DEGRADED
        return Detection(tick=tick, thruster=i, kind=kind, group=group,
                         names=tuple(self.names[j] for j in group), rho=rho, fraction=fraction)

    def _out(self, xi: np.ndarray, norm: float, dz: bool, det: Detection | None,
             held: bool) -> DetectorOutput:
        return DetectorOutput(xi=xi, rho_on=self.rho_on.copy(), rho_off=self.rho_off.copy(),
                              dw_norm_rad_s=norm, dead_zone=dz, detection=det, held=held)
