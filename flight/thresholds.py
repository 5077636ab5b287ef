"""Detector thresholds from a required detection time and fault-free statistics
(docs/design.md 6.4 step 6).

Seed 000: for a constant projection ``xi`` the integral residual is an arithmetic-geometric
progression ``rho[n] = xi (1 - w^(n+1)) / (1 - w)`` (limit ``xi / (1 - w)``); a lone outlier
decays as ``xi w^n``. With the normalised residual (seed 000) a fault gives ``xi = 1`` on every
tick it acts (``xi_fault``, < 1 for a thruster seen at an angle).

For each candidate ``w`` the tool computes

* the fault curve ``F(w) = xi_fault (1 - w^(n+1)) / (1 - w)`` at ``n + 1 = floor(T / h)`` ticks
  (the residual reached within the required time ``T``);
* the fault-free maximum ``Z(w)``: by running the recursion over recorded ``xi`` sequences
  (T, N) when given, otherwise from the bound of a burst of ``run`` consecutive outliers of size
  ``xi_max`` on top of the stationary mean, ``xi_max (1 - w^run) / (1 - w) + xi_mean / (1 - w)``;

and, among the ``w`` whose threshold ``margin * Z(w)`` a constant fault crosses within ``T``
(``threshold < F(w)``), keeps the one with the largest ratio of the limit ``xi_fault / (1 - w)``
to the threshold: the time allowed is spent on robustness (a weaker or intermittent fault still
crosses). It returns the threshold, the ticks to detection
``n = ceil(log(1 - thr (1 - w) / xi_fault) / log w)`` and the reasoning as text lines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from flight.errors import ThresholdError


def progression(xi: float, w: float, n: int) -> float:
    """Seed 000: rho[n] for a constant xi from rho[-1] = 0: ``xi (1 - w^(n+1)) / (1 - w)``."""
    return xi * (1.0 - w ** (n + 1)) / (1.0 - w)


def ticks_to_reach(threshold: float, xi: float, w: float) -> int | None:
    """Ticks (count, >= 1) for the progression of ``xi`` to exceed ``threshold``; None if never."""
    if xi <= 0.0 or threshold >= xi / (1.0 - w) * (1.0 - 1e-12):
        return None
    if threshold < xi:
        return 1
    # rho[n] > thr  <=>  w^(n+1) < 1 - thr (1 - w) / xi
    n_plus_1 = math.log(1.0 - threshold * (1.0 - w) / xi) / math.log(w)
    return int(math.floor(n_plus_1)) + 1


def max_residual(xi_seq: np.ndarray, w: float) -> float:
    """Largest |rho| of the recursion ``rho = w rho + xi`` over sequences (T, N) (all ticks)."""
    xi = np.atleast_2d(np.asarray(xi_seq, dtype=float))
    rho = np.zeros(xi.shape[1])
    peak = 0.0
    for row in xi:
        rho = w * rho + row
        peak = max(peak, float(np.abs(rho).max(initial=0.0)))
    return peak


@dataclass
class Proposal:
    w: float
    threshold: float
    ticks: int
    detection_time_s: float
    limit: float
    no_fault_max: float
    reasoning: list[str] = field(default_factory=list)


def propose(detection_time_s: float, tick_s: float, *, xi_seq: np.ndarray | None = None,
            xi_mean: float = 0.02, xi_max: float = 1.0, run: int = 1, xi_fault: float = 1.0,
            margin: float = 1.5, w_grid: np.ndarray | None = None) -> Proposal:
    """Choose (w, threshold) as in the module doc. Raises ThresholdError (naming the
    parameter) on a bad argument or when nothing fits."""
    if detection_time_s <= 0:
        raise ThresholdError(f"detection_time_s: expected > 0 s, got {detection_time_s:g}")
    if tick_s <= 0:
        raise ThresholdError(f"tick_s: expected > 0 s, got {tick_s:g}")
    if not 0.0 < xi_fault <= 1.0:
        raise ThresholdError(f"xi_fault: expected in (0, 1], got {xi_fault:g}")
    if margin < 1.0:
        raise ThresholdError(f"margin: expected >= 1, got {margin:g}")
    if xi_mean < 0 or xi_max < 0 or run < 1:
        raise ThresholdError("xi_mean, xi_max: expected >= 0; run: expected >= 1")
    n_ticks = int(math.floor(detection_time_s / tick_s + 1e-9))
    if n_ticks < 1:
        raise ThresholdError(
            f"detection_time_s: expected at least one tick ({tick_s:g} s), "
            f"got {detection_time_s:g}")
    grid = np.round(np.arange(0.50, 0.951, 0.01), 2) if w_grid is None else np.asarray(w_grid)
    lines = [
        f"required detection time {detection_time_s:g} s = {n_ticks} tick(s) of {tick_s:g} s",
        f"fault projection xi_fault = {xi_fault:g}; margin over the no-fault maximum {margin:g}",
        "rho[n] = xi (1 - w^(n+1)) / (1 - w), limit xi / (1 - w) (seed 000)",
    ]
    best: Proposal | None = None
    for w in grid:
        w = float(w)
        if xi_seq is not None:
            z = max_residual(xi_seq, w)
        else:
            z = xi_max * (1.0 - w**run) / (1.0 - w) + xi_mean / (1.0 - w)
        f_at = progression(xi_fault, w, n_ticks - 1)
        thr = max(margin * z, 1e-9)
        if thr >= f_at:
            continue
        n = ticks_to_reach(thr, xi_fault, w)
        if n is None:
            continue
        cand = Proposal(w=w, threshold=thr, ticks=n, detection_time_s=n * tick_s,
                        limit=xi_fault / (1.0 - w), no_fault_max=z)
        # Use the time allowed for robustness: the largest limit / threshold ratio (a weaker
        # or intermittent fault still crosses), the fewer ticks on a tie.
        key = (cand.limit / cand.threshold, -cand.ticks)
        if best is None or key > (best.limit / best.threshold, -best.ticks):
            best = cand
    if best is None:
        raise ThresholdError(
            f"no forgetting factor in [{grid[0]:g}, {grid[-1]:g}] separates a fault within "
            f"{detection_time_s:g} s from the no-fault residual with margin {margin:g}: "
            "lower the margin, allow more time or widen the dead zone")
    lines += [
        f"no-fault maximum of |rho| with w = {best.w:g}: {best.no_fault_max:.4g}",
        f"threshold = margin x no-fault maximum = {best.threshold:.4g} "
        f"(limit xi_fault / (1 - w) = {best.limit:.4g})",
        f"a constant fault crosses after {best.ticks} tick(s) = {best.detection_time_s:g} s "
        f"(<= {detection_time_s:g} s required)",
        f"proposal: forgetting_on = forgetting_off = {best.w:g}, "
        f"threshold_on = threshold_off = {best.threshold:.3g}",
    ]
    best.reasoning = lines
    return best
