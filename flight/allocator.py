"""Minimum-fuel thruster allocation by linear programming, PWM quantisation and prediction.

Seed 004 section 3, eqs. (3.1)-(3.2), for each tick::

    minimise    sum_n r_n tau_n                    (3.1)  r_n mass flow, kg/s
    subject to  dw_down <= sum_n mu_n tau_n <= dw_up (3.2)  mu_n = J^-1 (r_n x F_n), rad/s^2
                dv_down <= sum_n a_n tau_n  <= dv_up        (only when translation is commanded)
                0 <= tau_n <= tau_max,  tau_n = 0 for unavailable thrusters

``tau_n`` is the *effective* firing time (s). ``tau_max`` is the longest effective time of one tick
(197 ms: a continuous 200 ms command minus the 3 ms lag difference). The bound ``tau_n <= tau_max``
lets the LP spread a large demand over several thrusters so that it is met within this tick; only
when no solution within the bound exists is the LP solved without it and every duration scaled by
``tau_max / max tau`` (seed 004 section 3), which keeps the direction of the commanded rate change.
If the demand cannot be met at all (e.g. after failures) the allocator does its best: it minimises
the L1 violation of the bounds (rad/s and m/s), then fuel at that violation, and flags the tick
``feasible=False``.

Then (seed 004 section 4) the durations are quantised (``flight.quantise``: commanded =
effective + 3 ms, allowed set {0, 30, ..., 170, 200} ms, remainder carried per thruster) and the
rate change is predicted from the quantised commands: ``dw_pred = sum mu_n tau_E,n``,
``dv_pred = sum a_n tau_E,n`` with ``tau_E = tau - 3 ms``.

Orbit correction (seed 004 eqs. (3.3)-(3.4)) is :meth:`Allocator.allocate_burn`.

Solvers (``flight.allocator.solver``): ``simplex`` is a dense bounded dual simplex written for
these small problems (3-7 rows, up to ~40 columns): with every cost ``r_n >= 0`` the all-off start
is dual feasible, so no phase 1 is needed, and the basis is refined at the end by solving the
basic system from the original data. ``highs`` is a HiGHS model built once and warm-started
(row and column bounds changed each tick). ``linprog`` is ``scipy.optimize.linprog``. Any solver
that fails to converge falls back to ``linprog``. The core reads no clock: timing is the caller's.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from common.vehicle import VehicleArrays, VehicleCfg
from flight.quantise import PulseSet, Quantiser

OPTIMAL, ITERATION_LIMIT, INFEASIBLE = 0, 1, 2

_PRIMAL_TOL = 1e-10  # on rows normalised to a largest coefficient of 1, tau in units of the tick
_PIVOT_TOL = 1e-11
_MAX_ITER = 80
_REFACTOR_PIVOTS = 100


# --------------------------------------------------------------------------- dense dual simplex


@dataclass
class SimplexState:
    """Basis of a solved :func:`dual_simplex` problem, reusable while ``A`` and ``c`` stay.

    Only bounds change from tick to tick, so the final basis stays dual feasible and is the
    warm start of the next solve (usually zero to two pivots). Plain Python lists (the problems
    are a few rows by a few dozen columns, where list arithmetic is cheaper than numpy calls):
    ``T`` m rows of the tableau ``B^-1 [A, -I]`` (n+m each); ``d`` (n+m) reduced costs;
    ``basis`` (m) column indices; ``nonbasic``, ``at_upper`` (n+m) bools; ``pivots`` since the
    tableau was last computed from the basis (it is recomputed after ``_REFACTOR_PIVOTS``, so
    rounding does not build up over a long run).
    """

    T: list[list[float]]
    d: list[float]
    basis: list[int]
    nonbasic: list[bool]
    at_upper: list[bool]
    pivots: int = 0


def dual_simplex(
    A: np.ndarray,
    c: np.ndarray,
    row_lo: np.ndarray,
    row_hi: np.ndarray,
    col_ub: np.ndarray,
    max_iter: int = _MAX_ITER,
    start: SimplexState | None = None,
) -> tuple[int, np.ndarray, int, SimplexState | None]:
    """Solve ``min c x, row_lo <= A x <= row_hi, 0 <= x <= col_ub`` for ``c >= 0``.

    Bounded dual simplex on a dense tableau. Cold start: structural columns non-basic at 0 and
    the row activities ``s = A x`` basic; with ``c >= 0`` that basis is dual feasible, so no
    phase 1 is needed. Warm start: ``start`` from the previous solve with the same ``A`` and
    ``c`` (ignored when a non-basic variable sits at a bound that is now infinite); it is
    updated in place and returned (do not reuse it after ITERATION_LIMIT). Row bounds and
    ``col_ub`` may be infinite. The problem should be scaled (coefficients of order 1).

    Leaving row: the largest bound violation. Ratio test: the bound-flipping ("long-step")
    one: boxed candidates whose breakpoint is passed while the leaving row is still infeasible
    flip to their other bound instead of entering, so a demand that needs many thrusters at
    their upper bound takes a few pivots, not one per thruster. Ties go to the lower column.

    Shapes: A (m, n), c (n,), row_lo and row_hi (m,), col_ub (n,).
    Returns ``(status, x (n,), iterations, state)``; status OPTIMAL, INFEASIBLE or
    ITERATION_LIMIT; ``state`` is the final basis when OPTIMAL, else None.
    """
    m, n = A.shape
    nt = n + m
    lb = [0.0] * n + row_lo.tolist()
    ub = col_ub.tolist() + row_hi.tolist()
    inf = math.inf
    z: list[float] | None = None
    if start is not None:
        T, d, basis = start.T, start.d, start.basis
        nonbasic, at_upper = start.nonbasic, start.at_upper
        z = [(ub[j] if at_upper[j] else lb[j]) if nonbasic[j] else 0.0 for j in range(nt)]
        if max(z) == inf or min(z) == -inf:
            z = None
        else:
            nz = [(j, v) for j, v in enumerate(z) if v != 0.0]
            beta = [-sum([row[j] * v for j, v in nz]) for row in T]
            pivots = start.pivots
    if z is None:
        T = [[-v for v in row] + [1.0 if k == i else 0.0 for k in range(m)]
             for i, row in enumerate(A.tolist())]
        d = c.tolist() + [0.0] * m
        basis = list(range(n, nt))
        nonbasic = [True] * n + [False] * m
        at_upper = [False] * nt
        z = [0.0] * nt
        beta = [0.0] * m
        pivots = 0
    lbB = [lb[j] for j in basis]
    ubB = [ub[j] for j in basis]

    it = 0
    while True:
        r, worst, increase = -1, _PRIMAL_TOL, False
        for i in range(m):
            v = lbB[i] - beta[i]
            if v > worst:
                r, worst, increase = i, v, True
            v = beta[i] - ubB[i]
            if v > worst:
                r, worst, increase = i, v, False
        if r < 0:
            break
        if it >= max_iter:
            return ITERATION_LIMIT, np.zeros(n), it, None
        it += 1
        alpha = T[r]
        # Increasing the basic variable of row r: an entering variable at its lower bound
        # needs alpha < 0, one at its upper bound alpha > 0 (mirror for a decrease).
        cands = []
        for j in range(nt):
            if nonbasic[j] and ub[j] > lb[j]:  # fixed columns never enter
                a = alpha[j]
                sj = a if at_upper[j] == increase else -a
                if sj > _PIVOT_TOL:
                    cands.append((abs(d[j]) / sj, j, sj))
        if not cands:
            return INFEASIBLE, np.zeros(n), it, None
        cands.sort()
        slope = worst
        flips = []
        q = -1
        for _, j, sj in cands:
            g = sj * (ub[j] - lb[j])  # inf for an unbounded range
            if g < slope:
                slope -= g
                flips.append(j)
            else:
                q = j
                break
        if q < 0:  # every candidate flipped and the row is still infeasible
            return INFEASIBLE, np.zeros(n), it, None
        for j in flips:
            new = lb[j] if at_upper[j] else ub[j]
            dz = new - z[j]
            z[j] = new
            at_upper[j] = not at_upper[j]
            for i in range(m):
                beta[i] -= T[i][j] * dz
        a_rq = alpha[q]
        leave = basis[r]
        bound = lbB[r] if increase else ubB[r]
        delta = (beta[r] - bound) / a_rq
        for i in range(m):
            beta[i] -= T[i][q] * delta
        beta[r] = z[q] + delta
        f = d[q] / a_rq
        if f != 0.0:
            d[:] = [dj - f * aj for dj, aj in zip(d, alpha, strict=True)]
        d[q] = 0.0
        # Pivot on (r, q).
        prow = [v / a_rq for v in alpha]
        T[r] = prow
        for i in range(m):
            if i != r:
                f = T[i][q]
                if f != 0.0:
                    T[i] = [v - f * w for v, w in zip(T[i], prow, strict=True)]
                    T[i][q] = 0.0
        prow[q] = 1.0
        z[leave] = bound
        at_upper[leave] = not increase
        nonbasic[leave] = True
        nonbasic[q] = False
        at_upper[q] = False
        z[q] = 0.0
        basis[r] = q
        lbB[r] = lb[q]
        ubB[r] = ub[q]

    # The basic values from the tableau; checked against the original data, and recomputed from
    # it (a solve with the basis matrix) only when the tableau's rounding shows.
    zz = np.array(z)
    zz[basis] = beta
    x = zz[:n]
    act = A @ x
    tol = 1e-8
    worst = max(
        -x.min(), (x - col_ub).max(), (row_lo - act).max(), (act - row_hi).max()
    )
    pivots += it
    if worst > tol or pivots > _REFACTOR_PIVOTS:
        K = np.hstack((A, -np.eye(m)))
        try:
            zB = np.linalg.solve(K[:, basis], -(K @ np.array(z)))
            if pivots > _REFACTOR_PIVOTS:  # fresh tableau and reduced costs from the basis
                Tn = np.linalg.solve(K[:, basis], K)
                cf = np.concatenate((c, np.zeros(m)))
                dn = cf - cf[basis] @ Tn
                dn[basis] = 0.0
                T[:] = Tn.tolist()
                d[:] = dn.tolist()
                pivots = 0
        except np.linalg.LinAlgError:
            return ITERATION_LIMIT, np.zeros(n), it, None
        zz[basis] = zB
        x = zz[:n]
        act = A @ x
        if (
            np.any(x < -tol) or np.any(x > col_ub + tol)
            or np.any(act < row_lo - tol) or np.any(act > row_hi + tol)
        ):
            return ITERATION_LIMIT, np.zeros(n), it, None
    if start is not None and start.T is T:
        start.pivots = pivots
        state = start
    else:
        state = SimplexState(T=T, d=d, basis=basis, nonbasic=nonbasic, at_upper=at_upper,
                             pivots=pivots)
    return OPTIMAL, np.clip(x, 0.0, col_ub), it, state


def linprog_solve(
    A: np.ndarray, c: np.ndarray, row_lo: np.ndarray, row_hi: np.ndarray, col_ub: np.ndarray
) -> tuple[int, np.ndarray, int]:
    """Same contract as :func:`dual_simplex` through ``scipy.optimize.linprog`` (HiGHS)."""
    from scipy.optimize import linprog

    fin_hi = np.isfinite(row_hi)
    fin_lo = np.isfinite(row_lo)
    A_ub = np.vstack((A[fin_hi], -A[fin_lo]))
    b_ub = np.concatenate((row_hi[fin_hi], -row_lo[fin_lo]))
    bounds = [(0.0, None if not np.isfinite(u) else float(u)) for u in col_ub]
    res = linprog(
        c, A_ub=A_ub if len(b_ub) else None, b_ub=b_ub if len(b_ub) else None,
        bounds=bounds, method="highs",
        options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10},
    )
    if res.status == 0:
        return OPTIMAL, np.clip(res.x, 0.0, col_ub), int(getattr(res, "nit", 0))
    if res.status == 2:
        return INFEASIBLE, np.zeros(len(c)), 0
    return ITERATION_LIMIT, np.zeros(len(c)), 0


@contextlib.contextmanager
def _quiet_stdout():
    """Silence file descriptor 1 (C-level prints) for the duration of the block."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


class _HighsWarm:
    """A HiGHS model with fixed matrix and costs; bounds change per solve (warm start)."""

    def __init__(self, A: np.ndarray, c: np.ndarray) -> None:
        import highspy

        self._hs = highspy
        m, n = A.shape
        with _quiet_stdout():  # highspy >= 1.16 prints its banner in the constructor
            h = highspy.Highs()
        h.setOptionValue("output_flag", False)
        h.setOptionValue("presolve", "off")
        h.setOptionValue("solver", "simplex")
        h.setOptionValue("primal_feasibility_tolerance", 1e-10)
        h.setOptionValue("dual_feasibility_tolerance", 1e-10)
        lp = highspy.HighsLp()
        lp.num_col_ = n
        lp.num_row_ = m
        lp.col_cost_ = np.asarray(c, dtype=float)
        lp.col_lower_ = np.zeros(n)
        lp.col_upper_ = np.zeros(n)
        lp.row_lower_ = np.zeros(m)
        lp.row_upper_ = np.zeros(m)
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = np.arange(0, m * n + 1, m, dtype=np.int32)
        lp.a_matrix_.index_ = np.tile(np.arange(m, dtype=np.int32), n)
        lp.a_matrix_.value_ = np.asarray(A, dtype=float).T.reshape(-1)
        h.passModel(lp)
        self.h = h
        self.inf = highspy.kHighsInf
        self.rows = np.arange(m, dtype=np.int32)
        self.cols = np.arange(n, dtype=np.int32)
        self.zeros = np.zeros(n)

    def solve(self, row_lo, row_hi, col_ub) -> tuple[int, np.ndarray, int]:
        inf = self.inf
        h = self.h
        ub = np.where(np.isfinite(col_ub), col_ub, inf)
        h.changeColsBounds(len(self.cols), self.cols, self.zeros, ub)
        h.changeRowsBounds(
            len(self.rows), self.rows,
            np.where(np.isfinite(row_lo), row_lo, -inf), np.where(np.isfinite(row_hi), row_hi, inf),
        )
        h.run()
        st = h.getModelStatus()
        ms = self._hs.HighsModelStatus
        if st == ms.kOptimal:
            x = np.asarray(h.getSolution().col_value)
            return OPTIMAL, np.clip(x, 0.0, col_ub), int(h.getInfo().simplex_iteration_count)
        if st in (ms.kInfeasible, ms.kUnboundedOrInfeasible):
            return INFEASIBLE, np.zeros(len(col_ub)), 0
        return ITERATION_LIMIT, np.zeros(len(col_ub)), 0


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class LpResult:
    """Solution of one tick's LP before quantisation (effective times, s).

    ``tau_eff_s`` (N,) after scaling; ``status``: ``optimal`` (met within the tick),
    ``scaled`` (met only with longer firings: scaled by ``scale`` < 1, seed 004 section 3) or
    ``best_effort`` (no solution: L1 violation ``violation`` minimised, then fuel);
    ``fuel_kg`` = sum r_n tau_n of ``tau_eff_s``; ``cost_unscaled_kg`` the LP optimum before
    scaling (equal to ``fuel_kg`` unless scaled); ``iterations`` of the solver.
    """

    tau_eff_s: np.ndarray
    status: str
    scale: float
    fuel_kg: float
    cost_unscaled_kg: float
    violation: float
    iterations: int
    solver: str

    @property
    def feasible(self) -> bool:
        return self.status != "best_effort"


@dataclass(frozen=True)
class Allocation:
    """One tick's thruster commands and their predicted effect (seed 004 sections 3-4).

    Shapes: N thrusters. ``tau_eff_lp_s`` (N,) LP effective times after scaling, s;
    ``on_ms`` (N,) int commanded on-times, each in the allowed set; ``tau_eff_s`` (N,) effective
    times of ``on_ms`` (``on - 3 ms``, 0 when off), s; ``dw_pred_B_rad_s`` (3,) and
    ``dv_pred_B_m_s`` (3,) predicted from ``tau_eff_s``; ``feasible`` false when the bounds
    could not be met (best effort); ``status`` as :class:`LpResult` (or ``burn`` and
    ``burn_best_effort`` in orbit-correction mode); ``fuel_kg`` of the quantised commands; ``mode``
    ``attitude``, ``translation`` or ``burn``.
    """

    tau_eff_lp_s: np.ndarray
    on_ms: np.ndarray
    tau_eff_s: np.ndarray
    dw_pred_B_rad_s: np.ndarray
    dv_pred_B_m_s: np.ndarray
    feasible: bool
    status: str
    scale: float
    fuel_kg: float
    mode: str
    solver: str


# --------------------------------------------------------------------------- allocator


class Allocator:
    """Seed 004 allocator for one vehicle: LP, scaling, quantisation with carry, prediction.

    ``Allocator(vehicle)``; optional ``arrays`` (a :class:`VehicleArrays`, e.g. with a thrust
    table other than nominal) and ``solver`` (overrides ``vehicle.flight.allocator.solver``).
    Stateful only through the quantiser's carry (:meth:`reset` clears it).
    """

    def __init__(
        self,
        vehicle: VehicleCfg,
        arrays: VehicleArrays | None = None,
        solver: str | None = None,
    ) -> None:
        self.vehicle = vehicle
        self.arrays = arrays if arrays is not None else VehicleArrays.from_vehicle(vehicle)
        acfg = vehicle.flight.allocator
        self.solver = solver or acfg.solver
        if self.solver not in ("simplex", "highs", "linprog"):
            raise ValueError(
                f"allocator solver: expected simplex, highs or linprog, got {self.solver!r}"
            )
        self.pulses = PulseSet.from_config(vehicle.timing, vehicle.thrust_profile)
        self.tau_max_s = self.pulses.max_eff_s
        self.h_s = float(vehicle.timing.tick_s)
        ar = self.arrays
        self.n = len(ar.names)
        self.mu = np.asarray(ar.mu_B_rad_s2, dtype=float)  # (N, 3)
        self.acc = np.asarray(ar.accel_B_m_s2, dtype=float)  # (N, 3)
        self.r = np.asarray(ar.mdot_kg_s, dtype=float)  # (N,)
        self.quantiser = Quantiser(self.pulses, self.n, carry=acfg.carry_remainder)
        # Scaled LP data: tau in units of the tick, rows normalised, costs normalised.
        self._M6 = np.vstack((self.mu.T, self.acc.T))  # (6, N)
        self._row_scale6 = np.maximum(np.abs(self._M6).max(axis=1) * self.h_s, 1e-300)
        self._cost_scale = max(float(self.r.max()) * self.h_s, 1e-300)
        self._c = self.r * self.h_s / self._cost_scale
        self._A6 = self._M6 * self.h_s / self._row_scale6[:, None]
        self._warm: dict[int, _HighsWarm] = {}
        self._states: dict[tuple, SimplexState] = {}
        self._sub: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}  # (A, c) of a column subset
        self._all_cols = np.arange(self.n)
        self._ub_tick = np.full(self.n, self.tau_max_s / self.h_s)  # read only
        self._ub_tick.setflags(write=False)
        self._all_on = np.ones(self.n, dtype=bool)
        self._all_on.setflags(write=False)
        self.roll_pairs = [
            (vehicle.thruster_index(a), vehicle.thruster_index(b)) for a, b in acfg.roll_pairs
        ]

    # ------------------------------------------------------------------ helpers

    def reset(self) -> None:
        """Forget the quantisation remainders."""
        self.quantiser.reset()

    def available_mask(
        self, disabled: Iterable[str | int] = (), closed_manifolds: Iterable[str | int] = ()
    ) -> np.ndarray:
        """(N,) bool: thrusters not disabled (by name or index) and not on a closed manifold."""
        av = np.ones(self.n, dtype=bool)
        for t in disabled:
            av[t if isinstance(t, int) else self.vehicle.thruster_index(t)] = False
        for mf in closed_manifolds:
            k = mf if isinstance(mf, int) else self.arrays.manifolds.index(mf)
            av &= self.arrays.manifold_of != k
        return av

    def _solve_scaled(self, A, c, lo, hi, ub, key=None) -> tuple[int, np.ndarray, int, str]:
        """Solve a scaled LP with the configured solver; ``key`` names a warm-start slot."""
        if self.solver == "linprog":
            st, x, it = linprog_solve(A, c, lo, hi, ub)
            return st, x, it, "linprog"
        start = self._states.get(key) if key is not None else None
        st, x, it, state = dual_simplex(A, c, lo, hi, ub, start=start)
        if key is not None:
            if state is not None:
                if len(self._states) > 64:
                    self._states.clear()
                self._states[key] = state
            elif st == ITERATION_LIMIT:  # the warm start was updated in place: forget it
                self._states.pop(key, None)
        if st == ITERATION_LIMIT:
            st, x, it = linprog_solve(A, c, lo, hi, ub)
            return st, x, it, "linprog"
        return st, x, it, "simplex"

    def _solve_main(self, rows: int, lo, hi, ub, cols) -> tuple[int, np.ndarray, int, str]:
        A = self._A6[:rows]
        if self.solver == "highs":
            warm = self._warm.get(rows)
            if warm is None:
                warm = self._warm[rows] = _HighsWarm(A, self._c)
            ub_full = np.zeros(self.n)
            ub_full[cols] = ub
            st, x, it = warm.solve(lo, hi, ub_full)
            if st != ITERATION_LIMIT:
                return st, x[cols], it, "highs"
            st, x, it = linprog_solve(A[:, cols], self._c[cols], lo, hi, ub)
            return st, x, it, "linprog"
        ck = (rows, cols.tobytes())
        sub = self._sub.get(ck)
        if sub is None:
            if len(self._sub) > 64:
                self._sub.clear()
            sub = self._sub[ck] = (np.ascontiguousarray(A[:, cols]), self._c[cols].copy())
        key = (ck, bool(ub[0] < np.inf) if len(ub) else True)  # ub: all tau_max or all inf
        return self._solve_scaled(sub[0], sub[1], lo, hi, ub, key)

    # ------------------------------------------------------------------ LP

    def solve_lp(
        self,
        dw_down_B_rad_s: np.ndarray,
        dw_up_B_rad_s: np.ndarray,
        available: np.ndarray | None = None,
        dv_down_B_m_s: np.ndarray | None = None,
        dv_up_B_m_s: np.ndarray | None = None,
    ) -> LpResult:
        """Seed 004 eqs. (3.1)-(3.2) with the tick bound, scaling and best effort (module doc).

        Bounds (3,) each, rad/s and m/s, may be infinite; ``available`` (N,) bool (all if None).
        Translation rows are added when ``dv_down`` or ``dv_up`` is given.
        """
        lo = np.asarray(dw_down_B_rad_s, dtype=float)
        hi = np.asarray(dw_up_B_rad_s, dtype=float)
        rows = 3
        if dv_down_B_m_s is not None or dv_up_B_m_s is not None:
            rows = 6
            dvl = np.full(3, -np.inf) if dv_down_B_m_s is None else np.asarray(dv_down_B_m_s, float)
            dvh = np.full(3, np.inf) if dv_up_B_m_s is None else np.asarray(dv_up_B_m_s, float)
            lo = np.concatenate((lo, dvl))
            hi = np.concatenate((hi, dvh))
        if (lo > hi).any():
            raise ValueError(f"allocator: expected lower bounds <= upper bounds, got {lo} and {hi}")
        if available is None or (av := np.asarray(available, dtype=bool)).all():
            cols = self._all_cols
        else:
            cols = np.flatnonzero(av)
        rs = self._row_scale6[:rows]
        lo_s, hi_s = lo / rs, hi / rs
        tmax = self.tau_max_s / self.h_s
        ub = self._ub_tick[: len(cols)]
        N = self.n
        tau = np.zeros(N)
        st, x, it, used = self._solve_main(rows, lo_s, hi_s, ub, cols)
        status, scale, violation = "optimal", 1.0, 0.0
        if st == INFEASIBLE:
            no_ub = np.full(len(cols), np.inf)
            st2, x2, it2, used = self._solve_main(rows, lo_s, hi_s, no_ub, cols)
            it += it2
            if st2 == OPTIMAL and x2.max(initial=0.0) > 0.0:
                scale = min(1.0, tmax / x2.max())
                x = x2
                status = "scaled"
            else:
                x, violation, it3 = self._best_effort(rows, lo_s, hi_s, ub, cols)
                it += it3
                status = "best_effort"
        tau[cols] = x * self.h_s
        cost_unscaled = float(self.r @ tau)
        tau *= scale
        return LpResult(
            tau_eff_s=tau, status=status, scale=scale, fuel_kg=float(self.r @ tau),
            cost_unscaled_kg=cost_unscaled, violation=violation, iterations=it, solver=used,
        )

    def _best_effort(self, rows, lo_s, hi_s, ub, cols) -> tuple[np.ndarray, float, int]:
        """Minimise the L1 violation (physical units), then fuel at that violation."""
        A = self._A6[:rows][:, cols]
        m, k = A.shape
        rs = self._row_scale6[:rows]
        # Elastic columns p (adds) and q (subtracts) per row, weighted back to physical units.
        Ae = np.hstack((A, np.eye(m), -np.eye(m)))
        w = np.concatenate((rs, rs))
        w_n = w / w.max()
        ube = np.concatenate((ub, np.full(2 * m, np.inf)))
        c1 = np.concatenate((np.zeros(k), w_n))
        st, z1, it1, _ = self._solve_scaled(Ae, c1, lo_s, hi_s, ube)
        if st != OPTIMAL:  # cannot happen for a bounded elastic problem; stay safe: fire nothing
            return np.zeros(k), float("nan"), it1
        v = float(c1 @ z1)
        A2 = np.vstack((Ae, c1))
        lo2 = np.concatenate((lo_s, [-np.inf]))
        hi2 = np.concatenate((hi_s, [v * (1.0 + 1e-9) + 1e-13]))
        c2 = np.concatenate((self._c[cols], np.zeros(2 * m)))
        st, z2, it2, _ = self._solve_scaled(A2, c2, lo2, hi2, ube)
        z = z2 if st == OPTIMAL else z1
        return z[:k], v * float(w.max()), it1 + it2

    # ------------------------------------------------------------------ allocation

    def _finish(self, lp_tau: np.ndarray, av: np.ndarray, feasible: bool, status: str,
                scale: float, mode: str, solver: str) -> Allocation:
        on, tau_e = self.quantiser.step_eff(lp_tau, av)
        return Allocation(
            tau_eff_lp_s=lp_tau, on_ms=on, tau_eff_s=tau_e,
            dw_pred_B_rad_s=self.mu.T @ tau_e, dv_pred_B_m_s=self.acc.T @ tau_e,
            feasible=feasible, status=status, scale=scale, fuel_kg=float(self.r @ tau_e),
            mode=mode, solver=solver,
        )

    def allocate(
        self,
        dw_down_B_rad_s: np.ndarray,
        dw_up_B_rad_s: np.ndarray,
        available: np.ndarray | None = None,
        dv_down_B_m_s: np.ndarray | None = None,
        dv_up_B_m_s: np.ndarray | None = None,
    ) -> Allocation:
        """One tick: LP (:meth:`solve_lp`), quantisation with carry, prediction."""
        av = self._all_on if available is None else np.asarray(available, dtype=bool)
        lp = self.solve_lp(dw_down_B_rad_s, dw_up_B_rad_s, av, dv_down_B_m_s, dv_up_B_m_s)
        mode = "attitude" if dv_down_B_m_s is None and dv_up_B_m_s is None else "translation"
        return self._finish(lp.tau_eff_s, av, lp.feasible, lp.status, lp.scale, mode, lp.solver)

    # ------------------------------------------------------------------ orbit correction

    def lateral_table(self, available: np.ndarray, exclude: Sequence[int] = ()) -> dict:
        """Seed 004: lateral (+/-Y, +/-Z) translation thrusters "from tables".

        For each body axis 1, 2 and sign, the available thrusters (not in ``exclude``) whose
        acceleration has that sign on the axis, best first: largest share of the acceleration
        along the axis, then smallest angular acceleration (the middle belt, near the centre of
        mass). Returns ``{(axis, sign): [index, ...]}``.
        """
        table = {}
        ex = set(int(i) for i in exclude)
        for axis in (1, 2):
            for sign in (1, -1):
                cand = [
                    i for i in range(self.n)
                    if available[i] and i not in ex and sign * self.acc[i, axis] > 0
                ]
                def key(i: int, axis: int = axis, sign: int = sign) -> tuple[float, float]:
                    share = sign * self.acc[i, axis] / np.linalg.norm(self.acc[i])
                    return (-round(share, 6), float(np.linalg.norm(self.mu[i])))
                table[(axis, sign)] = sorted(cand, key=key)
        return table

    def allocate_burn(
        self,
        dw_down_B_rad_s: np.ndarray,
        dw_up_B_rad_s: np.ndarray,
        burn: Sequence[int | str],
        available: np.ndarray | None = None,
        dv_remaining_B_m_s: np.ndarray | None = None,
    ) -> Allocation:
        """Orbit correction: continuous burn with attitude held by off-times (seed 004 (3.3)-(3.4)).

        ``burn``: the thrusters that burn for delta-v (seed 004: 4, 6 or 8 of the aft or front
        belt). ``dv_remaining_B_m_s`` (3,): delta-v still to give, body axes, m/s (None: burn
        the whole tick, no lateral firing). Steps, in the seed's order:

        1. base effective on-time of the burn set: the whole tick (``tau_max``), or less when the
           remaining delta-v along the set's acceleration needs less;
        2. lateral channels (+/-Y, +/-Z) from :meth:`lateral_table`: the best thruster per
           channel fires for ``dv / a`` (at most ``tau_max``);
        3. eq. (3.4): off-times ``t_n`` of the burn thrusters, ``0 <= t_n <= base``, minimising
           ``sum r_n t_n`` subject to the pitch and yaw bounds (roll is left out of this LP, as in
           the seed); the predicted angular effect of step 2 is included;
        4. eq. (3.3): roll from the pair table (``flight.allocator.roll_pairs``), both thrusters
           of one pair for the same time ``dw_x / (eps_a + eps_b)`` to the nearest dead-zone
           boundary; the pair whose roll acceleration has the needed sign and the best roll per
           fuel is chosen.

        The off-time LP falls back to best effort (L1 violation, then fuel) when the bounds cannot
        be met. Quantisation and prediction as in :meth:`allocate`.
        """
        av = np.ones(self.n, dtype=bool) if available is None else np.asarray(available, dtype=bool)
        idx = [b if isinstance(b, int) else self.vehicle.thruster_index(b) for b in burn]
        bset = np.array([i for i in idx if av[i]], dtype=int)
        lo = np.asarray(dw_down_B_rad_s, dtype=float)
        hi = np.asarray(dw_up_B_rad_s, dtype=float)
        tmax = self.tau_max_s
        tau = np.zeros(self.n)
        # 1. base burn time
        base = tmax
        if len(bset) and dv_remaining_B_m_s is not None:
            a_sum = self.acc[bset].sum(axis=0)
            na = float(np.linalg.norm(a_sum))
            need = float(np.asarray(dv_remaining_B_m_s, float) @ a_sum) / na if na > 0 else 0.0
            base = min(tmax, max(0.0, need / na)) if na > 0 else 0.0
        if len(bset) == 0 or base <= 0.0:
            return self.allocate(lo, hi, av)
        tau[bset] = base
        # 2. lateral channels from the table
        roll_members = {i for p in self.roll_pairs for i in p}
        if dv_remaining_B_m_s is not None:
            rem = np.asarray(dv_remaining_B_m_s, float) - self.acc[bset].sum(axis=0) * base
            table = self.lateral_table(av, exclude=list(bset) + sorted(roll_members))
            for axis in (1, 2):
                if abs(rem[axis]) < 1e-9:
                    continue
                sign = 1 if rem[axis] > 0 else -1
                cands = table[(axis, sign)]
                if not cands:
                    continue
                i = cands[0]
                t = min(tmax - tau[i], rem[axis] / self.acc[i, axis])
                if t > 0:
                    tau[i] += t
                    rem -= self.acc[i] * t
        # 3. off-times for pitch and yaw (eq. 3.4)
        dw_full = self.mu.T @ tau
        rows = [1, 2]
        M = self.mu[bset][:, rows].T  # (2, k)
        lo_off = dw_full[rows] - hi[rows]
        hi_off = dw_full[rows] - lo[rows]
        rs = np.maximum(np.abs(M).max(axis=1) * self.h_s, 1e-300)
        A = M * self.h_s / rs[:, None]
        c = self.r[bset] * self.h_s / self._cost_scale
        ub = np.full(len(bset), base / self.h_s)
        st, x, _, used = self._solve_scaled(A, c, lo_off / rs, hi_off / rs, ub)
        feasible = st == OPTIMAL
        if not feasible:
            Ae = np.hstack((A, np.eye(2), -np.eye(2)))
            w = np.concatenate((rs, rs))
            c1 = np.concatenate((np.zeros(len(bset)), w / w.max()))
            ube = np.concatenate((ub, np.full(4, np.inf)))
            st1, z1, _, used = self._solve_scaled(Ae, c1, lo_off / rs, hi_off / rs, ube)
            x = z1[: len(bset)] if st1 == OPTIMAL else np.zeros(len(bset))
        tau[bset] = base - x * self.h_s
        # 4. roll from the pair table (eq. 3.3)
        if self.roll_pairs:
            dwx = float(self.mu[:, 0] @ tau)
            need = lo[0] - dwx if dwx < lo[0] else (hi[0] - dwx if dwx > hi[0] else 0.0)
            if need != 0.0:
                best, best_eff = None, 0.0
                for a, b in self.roll_pairs:
                    if not (av[a] and av[b]) or tau[a] > 0 or tau[b] > 0:
                        continue
                    eps = self.mu[a, 0] + self.mu[b, 0]
                    if eps * need <= 0:
                        continue
                    eff = abs(eps) / (self.r[a] + self.r[b])
                    if eff > best_eff:
                        best, best_eff = (a, b, eps), eff
                if best is not None:
                    a, b, eps = best
                    t = min(tmax, need / eps)
                    tau[a] = tau[b] = t
        status = "burn" if feasible else "burn_best_effort"
        return self._finish(tau, av, feasible, status, 1.0, "burn", used)
