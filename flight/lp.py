"""Small dense linear programs: ``minimise c x`` subject to ``row_lo <= A x <= row_hi`` and
``0 <= x <= col_ub``, with ``c >= 0`` (every column costs), solved three ways behind one
contract (status, x, iterations):

* ``dual_simplex``: a dense bounded dual simplex written for these small problems (3-7 rows, up
  to ~40 columns): with every cost ``>= 0`` the all-at-lower-bound start is dual feasible, so no
  phase 1 is needed; warm-started from a ``SimplexState``; the basis is refined at the end by
  solving the basic system from the original data;
* ``HighsWarm``: a HiGHS model built once, only the bounds changed per solve (warm start);
* ``linprog_solve``: ``scipy.optimize.linprog`` (HiGHS), the reference and the fallback.

Nothing here knows thrusters; ``flight.allocator`` builds the problems (seed 004 section 3).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass

import numpy as np

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


class HighsWarm:
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
