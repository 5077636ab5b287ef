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


@dataclass(frozen=True)
class Detection:
    """A detected thruster fault.

    ``thruster`` the index whose residual crossed; ``group`` every thruster with the same
    direction (indices, sorted, includes ``thruster``); ``kind`` ``stuck_on`` or
    ``fail_to_fire``; ``rho`` the residual value at the crossing; ``source`` ``residual``
    (seed 000/003) or ``kalman`` (seed 002 leak test).
    """

    tick: int
    thruster: int
    kind: str
    group: tuple[int, ...]
    names: tuple[str, ...]
    rho: float
    source: str = "residual"

    @property
    def ambiguous(self) -> bool:
        return len(self.group) > 1

    def describe(self) -> str:
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


class Detector:
    """Seed 000 / seed 003 detector over N thrusters.

    ``step(tick, dw_B_rad_s, active, available=None) -> DetectorOutput``; ``active`` (N,) bool:
    the thruster was commanded over the tick the residual covers.
    ``opposite_deg`` (default ``same_direction_deg``) decides which pairs are opposing.
    """

    def __init__(self, mu_B_rad_s2: np.ndarray, cfg: DetectorCfg,
                 names: tuple[str, ...] | None = None, opposite_deg: float | None = None,
                 hold_ticks: int = 2) -> None:
        self.cfg = cfg
        self.e_B = unit_directions(mu_B_rad_s2)
        n = len(self.e_B)
        self.names = tuple(names) if names else tuple(str(i) for i in range(n))
        self.groups = direction_groups(self.e_B, cfg.same_direction_deg)
        self.opposite = opposite_matrix(
            self.e_B, cfg.same_direction_deg if opposite_deg is None else opposite_deg)
        self.hold_ticks = int(hold_ticks)
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

    def project(self, dw_B_rad_s: np.ndarray,
                commanded_abs_rad_s: float = 0.0) -> tuple[np.ndarray, float, bool]:
        """Steps 1-2: dead zone, normalisation and projections xi (N,).

        The dead zone is ``dead_zone_rad_s + relative_dead_zone * commanded_abs_rad_s``
        (``commanded_abs_rad_s``: sum of the commanded thrusters' rate-change magnitudes).
        """
        dw = np.asarray(dw_B_rad_s, dtype=float)
        norm = float(np.linalg.norm(dw))
        dz = self.cfg.dead_zone_rad_s + self.cfg.relative_dead_zone * float(commanded_abs_rad_s)
        if norm < dz or norm == 0.0:
            return np.zeros(self.n), norm, True
        return self.e_B @ (dw / norm), norm, False

    def step(self, tick: int, dw_B_rad_s: np.ndarray, active: np.ndarray,
             available: np.ndarray | None = None,
             commanded_abs_rad_s: float = 0.0) -> DetectorOutput:
        act = np.asarray(active, dtype=bool)
        avail = np.ones(self.n, dtype=bool) if available is None else np.asarray(available, bool)
        xi, norm, dz = self.project(dw_B_rad_s, commanded_abs_rad_s)
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
        group = tuple(j for j in self.groups[i] if avail[j])
        rho = float(self.rho_on[i] if kind == FAIL_TO_FIRE else self.rho_off[i])
        return Detection(tick=tick, thruster=i, kind=kind, group=group,
                         names=tuple(self.names[j] for j in group), rho=rho)

    def _out(self, xi: np.ndarray, norm: float, dz: bool, det: Detection | None,
             held: bool) -> DetectorOutput:
        return DetectorOutput(xi=xi, rho_on=self.rho_on.copy(), rho_off=self.rho_off.copy(),
                              dw_norm_rad_s=norm, dead_zone=dz, detection=det, held=held)
