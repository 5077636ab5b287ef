"""Allocator LP (seed 004 eqs. 3.1-3.2) against an LP built here from the vehicle YAML alone.

The oracle never reads the allocator's arrays: ``mu_n = J^-1 (r_n x F_n)`` with ``r_n`` the
thruster position minus the centre of mass, ``a_n = F_n / m``, ``r_n = F_n / (Isp g0)`` and
``tau_max = h - (on_lag - off_lag)`` (seed 004 section 4) come from ``hil.config.load_vehicle``'s
fields, and the problems are solved by ``scipy.optimize.linprog`` (HiGHS) in a scaling of our own
(tau in ticks, each row divided by its largest coefficient, costs by the largest mass flow).

Problems are built so that their class is known without asking any solver:

* (a) feasible within the tick: the bounds are a box around ``M tau*`` with
  ``0 <= tau* <= tau_max`` on available thrusters;
* (b) infeasible within the tick, feasible without the bound: the box lies beyond the support
  function ``max_{0<=tau<=tau_max} d.(M tau) = tau_max sum_n max(d.m_n, 0)`` along ``d`` but
  inside the cone ``{M tau, tau >= 0}`` (a non-negative combination of available columns);
* (c) infeasible at all: every available column has ``d.m_n <= 0`` and the whole box has
  ``d.y > 0`` (a separating direction), reached with failed thrusters and closed manifolds.

Feasible block LPs are solved stacked block-diagonally in one linprog call: the objective is
separable, so the optimum restricted to each block is that block's optimum.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import linprog

from flight.allocator import Allocator
from hil.config import load_vehicle

G0 = 9.80665  # standard gravity, m/s^2 (Isp in seconds)
LP_OPTS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
BATCH = 200
VEHICLES = ("orel", "generic")
SOLVERS = ("simplex", "highs")


class Geometry:
    """Independent arrays from the YAML fields. Shapes: N thrusters; ``M6`` (6, N)."""

    def __init__(self, name: str) -> None:
        v = load_vehicle(name)
        self.v = v
        J = np.array(v.inertia_B_kg_m2, dtype=float)
        com = np.array(v.com_m, dtype=float)
        pos = np.array([t.position_m for t in v.thrusters], dtype=float)
        d = np.array([t.direction for t in v.thrusters], dtype=float)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        F = np.array([t.thrust_n for t in v.thrusters], dtype=float)
        isp = np.array([t.isp_s for t in v.thrusters], dtype=float)
        torque = np.cross(pos - com, d * F[:, None])  # (N, 3), N m
        self.mu = np.linalg.solve(J, torque.T).T  # (N, 3), rad/s^2
        self.acc = d * F[:, None] / v.mass_kg  # (N, 3), m/s^2
        self.mdot = F / (isp * G0)  # (N,), kg/s
        self.M6 = np.vstack((self.mu.T, self.acc.T))
        self.h = float(v.timing.tick_s)
        lag_s = (v.thrust_profile.on_lag_ms - v.thrust_profile.off_lag_ms) / 1000.0
        self.tau_max = self.h - lag_s  # longest effective time of one tick (continuous command)
        self.n = len(F)
        self.manifold = np.array([v.manifolds.index(t.manifold) for t in v.thrusters])
        self.row_scale = np.abs(self.M6).max(axis=1) * self.h  # (6,) largest one-tick change

    def mask(self, disabled=(), closed=()) -> np.ndarray:
        av = np.ones(self.n, dtype=bool)
        av[list(disabled)] = False
        for k in closed:
            av &= self.manifold != k
        return av

    def violation(self, tau: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
        """L1 violation of the bounds by ``M tau`` in physical units (rad/s and m/s)."""
        y = self.M6[: len(lo)] @ tau
        return float(np.sum(np.maximum(lo - y, 0.0) + np.maximum(y - hi, 0.0)))


@pytest.fixture(scope="module", params=VEHICLES)
def geometry(request) -> Geometry:
    return Geometry(request.param)


@pytest.fixture(params=SOLVERS)
def case(geometry, request):
    """Each vehicle with each on-board solver (orel flies ``highs``, generic ``simplex``)."""
    return geometry, Allocator(geometry.v, solver=request.param)


# --------------------------------------------------------------------------- the oracle LPs


def _rows(g: Geometry, lo, hi, av, elastic: bool):
    """Scaled block: variables t = tau / h on available thrusters (+ p, q per row if elastic)."""
    m = len(lo)
    cols = np.flatnonzero(av)
    rs = g.row_scale[:m]
    A = g.M6[:m][:, cols] * g.h / rs[:, None]
    if elastic:
        A = np.hstack((A, np.eye(m), -np.eye(m)))
    lo_s, hi_s = lo / rs, hi / rs
    fh, fl = np.isfinite(hi_s), np.isfinite(lo_s)
    return np.vstack((A[fh], -A[fl])), np.concatenate((hi_s[fh], -lo_s[fl])), cols


def solve_blocks(blocks) -> tuple[np.ndarray, list[np.ndarray]]:
    """``blocks``: (c, A_ub, b_ub, ub) each; one linprog; returns (costs, solutions) per block."""
    res = linprog(
        np.concatenate([b[0] for b in blocks]),
        A_ub=sp.block_diag([sp.csr_matrix(b[1]) for b in blocks], format="csr"),
        b_ub=np.concatenate([b[2] for b in blocks]),
        bounds=np.concatenate([np.column_stack((np.zeros(len(b[3])), b[3])) for b in blocks]),
        method="highs", options=LP_OPTS,
    )
    assert res.status == 0, res.message
    costs, xs, k = [], [], 0
    for c, *_ in blocks:
        x = res.x[k:k + len(c)]
        costs.append(float(c @ x))
        xs.append(x)
        k += len(c)
    return np.array(costs), xs


def fuel_block(g: Geometry, lo, hi, av, bounded: bool):
    """Min fuel ``sum r_n tau_n`` block; cost in kg (the objective is in physical units)."""
    A, b, cols = _rows(g, lo, hi, av, elastic=False)
    c = g.mdot[cols] * g.h  # kg per tick of firing
    ub = np.full(len(cols), g.tau_max / g.h if bounded else np.inf)
    return c, A, b, ub


def elastic_blocks(g: Geometry, lo, hi, av):
    """Stage 1: min L1 violation (physical units); stage 2 built from its optimum."""
    m = len(lo)
    A, b, cols = _rows(g, lo, hi, av, elastic=True)
    rs = g.row_scale[:m]
    c1 = np.concatenate((np.zeros(len(cols)), rs, rs))  # p, q back to rad/s or m/s
    ub = np.concatenate((np.full(len(cols), g.tau_max / g.h), np.full(2 * m, np.inf)))
    return (c1, A, b, ub), cols


# --------------------------------------------------------------------------- problem builders


def random_mask(g: Geometry, rng, kind: int) -> tuple[np.ndarray, tuple, tuple]:
    """Availability: all, one or two failed, a closed manifold (if any), or both."""
    disabled: tuple = ()
    closed: tuple = ()
    if kind in (1, 4):
        disabled = tuple(int(i) for i in rng.choice(g.n, size=1 + (kind == 4), replace=False))
    if kind in (2, 4) and len(g.v.manifolds) > 1:
        closed = (int(rng.integers(len(g.v.manifolds))),)
    return g.mask(disabled, closed), disabled, closed


def available(alloc: Allocator, g: Geometry, disabled, closed) -> np.ndarray:
    """The allocator's mask, checked against ours from the YAML."""
    av = alloc.available_mask(disabled=list(disabled),
                              closed_manifolds=[g.v.manifolds[k] for k in closed])
    np.testing.assert_array_equal(av, g.mask(disabled, closed))
    return av


def problem_within_tick(g: Geometry, rng, rows: int, av: np.ndarray):
    """(a): a box around M tau* with 0 <= tau* <= tau_max on available thrusters."""
    tau = np.where(av & (rng.random(g.n) < rng.uniform(0.1, 0.6)),
                   rng.uniform(0.0, g.tau_max, g.n), 0.0)
    y = g.M6[:rows] @ tau
    s = g.row_scale[:rows]
    lo = y - rng.uniform(1e-3, 0.3, rows) * s
    hi = y + rng.uniform(1e-3, 0.3, rows) * s
    if rng.random() < 0.15:
        j = rng.integers(rows)
        lo[j], hi[j] = (-np.inf, np.inf) if rng.random() < 0.5 else (lo[j], np.inf)
    return lo, hi


def problem_scaled(g: Geometry, rng, av: np.ndarray):
    """(b), rotation rows: beyond the tick's support function, inside the cone."""
    cols = np.flatnonzero(av)
    mu = g.mu[cols]
    while True:
        k = rng.integers(1, 4)
        w = np.zeros(len(cols))
        w[rng.choice(len(cols), size=min(k, len(cols)), replace=False)] = rng.uniform(0.2, 1.0, k)
        x = mu.T @ w
        if np.linalg.norm(x) == 0.0:
            continue
        d = x / np.linalg.norm(x)
        support = g.tau_max * np.clip(mu @ d, 0.0, None).sum()
        x *= rng.uniform(1.1, 4.0) * support / (d @ x)  # d.x beyond what one tick can give
        half = rng.uniform(0.0, 0.05) * (d @ x - support) / np.abs(d).sum() * np.ones(3)
        lo, hi = x - half, x + half
        # Still beyond the support over the whole box (corner nearest to the origin).
        assert d @ x - np.abs(d) @ half > support
        return lo, hi


def problem_infeasible(g: Geometry, rng, rows: int, closed: tuple):
    """(c): a direction d with d.m_n <= 0 for every available column, box with d.y > 0."""
    M = g.M6[:rows]
    s = g.row_scale[:rows]
    while True:
        d = rng.normal(size=rows) / s  # balanced over the rows' units
        base = g.mask((), closed)
        bad = np.flatnonzero(base & (d @ M > 0.0))
        av = base.copy()
        av[bad] = False
        if not av.any():
            continue
        # A reachable part plus a push along d; the box must stay on the far side of d.y = 0.
        tau = np.where(av & (rng.random(g.n) < 0.5), rng.uniform(0.0, 2 * g.tau_max, g.n), 0.0)
        x = M @ tau
        x += (rng.uniform(0.05, 1.0) * np.abs(d) @ s - d @ x) * d / (d @ d)
        half = rng.uniform(0.0, 0.3, rows) * s
        if d @ x - np.abs(d) @ half <= 1e-6 * (np.abs(d) @ s):
            continue
        return x - half, x + half, tuple(int(i) for i in bad)


def _physical_check(g: Geometry, res, av: np.ndarray) -> None:
    """Unavailable thrusters off; every firing time within [0, tau_max]."""
    tau = res.tau_eff_s
    assert np.all(tau[~av] == 0.0)
    assert tau.min() >= 0.0 and tau.max() <= g.tau_max * (1 + 1e-12)


# --------------------------------------------------------------------------- (a) optimal


def test_within_tick_same_fuel_as_linprog(case) -> None:
    """(a) 600 problems per vehicle and solver: ``optimal``, bounds met, fuel within 1e-9 rel."""
    g, alloc = case
    assert alloc.tau_max_s == pytest.approx(g.tau_max, abs=1e-12)
    rng = np.random.default_rng(20240 + g.n)
    blocks, mine = [], []
    for k in range(600):
        rows = 6 if k % 4 == 3 else 3
        av, dis, cl = random_mask(g, rng, k % 5)
        av = available(alloc, g, dis, cl)
        lo, hi = problem_within_tick(g, rng, rows, av)
        dv = (lo[3:], hi[3:]) if rows == 6 else (None, None)
        res = alloc.solve_lp(lo[:3], hi[:3], av, *dv)
        assert res.status == "optimal" and res.scale == 1.0, (k, res.status)
        _physical_check(g, res, av)
        tol = 1e-9 * g.row_scale[:rows]
        y = g.M6[:rows] @ res.tau_eff_s
        assert np.all(y >= lo - tol) and np.all(y <= hi + tol), k
        assert res.fuel_kg == pytest.approx(float(g.mdot @ res.tau_eff_s), rel=1e-12)
        blocks.append(fuel_block(g, lo, hi, av, bounded=True))
        mine.append(res.fuel_kg)
    ref = np.concatenate([solve_blocks(blocks[i:i + BATCH])[0]
                          for i in range(0, len(blocks), BATCH)])
    mine = np.array(mine)
    err = np.abs(mine - ref) / np.maximum(ref, 1e-300)
    assert np.all(err[ref > 0] <= 1e-9), float(err.max())
    assert np.all(mine[ref == 0] == 0.0)
    assert np.count_nonzero(ref > 0) > 420  # most problems need a firing


# --------------------------------------------------------------------------- (b) scaled


def test_beyond_the_tick_scaled_from_the_unbounded_optimum(case) -> None:
    """(b) 250 problems per vehicle and solver: ``scaled``; cost = the unbounded linprog optimum
    (1e-9 rel); fuel = that cost times the scale; scale = tau_max / max(tau) of the unscaled
    solution."""
    g, alloc = case
    rng = np.random.default_rng(777 + g.n)
    blocks, got = [], []
    for k in range(250):
        av, dis, cl = random_mask(g, rng, k % 5)
        av = available(alloc, g, dis, cl)
        lo, hi = problem_scaled(g, rng, av)
        res = alloc.solve_lp(lo, hi, av)
        assert res.status == "scaled", (k, res.status)
        _physical_check(g, res, av)
        assert 0.0 < res.scale < 1.0
        tau_u = res.tau_eff_s / res.scale  # the unscaled LP solution
        assert res.tau_eff_s.max() == pytest.approx(g.tau_max, rel=1e-12)
        assert res.scale == pytest.approx(g.tau_max / tau_u.max(), rel=1e-12)
        # The unscaled solution meets the bounds (it is the solution without the tick bound).
        # Its firing times reach ~15 ticks; HiGHS leaves row violations up to ~1e-8 of the row
        # scale there (seen: 2.4e-11 rad/s), far below any wrong answer's.
        tol = 1e-7 * g.row_scale[:3]
        y = g.mu.T @ tau_u
        assert np.all(y >= lo - tol) and np.all(y <= hi + tol), k
        blocks.append(fuel_block(g, lo, hi, av, bounded=False))
        got.append((res.cost_unscaled_kg, res.fuel_kg, res.scale, float(g.mdot @ tau_u)))
    ref = np.concatenate([solve_blocks(blocks[i:i + BATCH])[0]
                          for i in range(0, len(blocks), BATCH)])
    for (cost_u, fuel, scale, own), r in zip(got, ref, strict=True):
        assert cost_u == pytest.approx(r, rel=1e-9)
        assert own == pytest.approx(r, rel=1e-9)
        assert fuel == pytest.approx(scale * r, rel=1e-9)


# --------------------------------------------------------------------------- (c) best effort


def test_infeasible_best_effort_minimises_l1_violation_then_fuel(case) -> None:
    """(c) 250 problems per vehicle and solver (failed thrusters, closed manifolds, 3 and 6 rows):
    ``best_effort``; violation = elastic linprog optimum; fuel = min fuel at that violation."""
    g, alloc = case
    rng = np.random.default_rng(4242 + g.n)
    probs = []
    for k in range(250):
        rows = 6 if k % 3 == 2 else 3
        closed = ((int(rng.integers(len(g.v.manifolds))),)
                  if len(g.v.manifolds) > 1 and k % 2 else ())
        lo, hi, bad = problem_infeasible(g, rng, rows, closed)
        av = available(alloc, g, bad, closed)
        dv = (lo[3:], hi[3:]) if rows == 6 else (None, None)
        res = alloc.solve_lp(lo[:3], hi[:3], av, *dv)
        assert res.status == "best_effort" and not res.feasible, (k, res.status)
        _physical_check(g, res, av)
        probs.append((lo, hi, av, res))
    # Stage 1: minimum violation.
    stage1 = [elastic_blocks(g, lo, hi, av) for lo, hi, av, _ in probs]
    v_ref = np.concatenate([solve_blocks([b for b, _ in stage1[i:i + BATCH]])[0]
                            for i in range(0, len(stage1), BATCH)])
    # Stage 2: minimum fuel with the violation at most v_ref (strict), and with the violation
    # allowed 2e-9 relative above it (the allocator's second stage keeps the violation within
    # 1e-9 relative of its stage-1 optimum, and this trade can be steep: fuel ~1e-5 rel. lower).
    f_ref = {}
    for slack in (1e-12, 2e-9):
        blocks2 = []
        for ((c1, A, b, ub), cols), vr in zip(stage1, v_ref, strict=True):
            c2 = np.concatenate((g.mdot[cols] * g.h, np.zeros(len(c1) - len(cols))))
            A2 = np.vstack((A, c1 / c1.max()))
            b2 = np.concatenate((b, [vr / c1.max() * (1 + slack)]))
            blocks2.append((c2, A2, b2, ub))
        f_ref[slack] = np.concatenate([solve_blocks(blocks2[i:i + BATCH])[0]
                                       for i in range(0, len(blocks2), BATCH)])
    for (lo, hi, _, res), vr, f_strict, f_slack in zip(
        probs, v_ref, f_ref[1e-12], f_ref[2e-9], strict=True
    ):
        assert vr > 0.0
        assert res.violation == pytest.approx(vr, rel=1e-9)
        own = g.violation(res.tau_eff_s, lo, hi)  # measured on the returned firing times
        assert vr * (1 - 1e-10) <= own <= vr * (1 + 2e-9)
        # Fuel: no more than the strict lexicographic optimum, no less than with the slack.
        assert f_slack * (1 - 1e-9) - 1e-15 <= res.fuel_kg <= f_strict * (1 + 1e-9) + 1e-15
