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

Solvers (``flight.allocator.solver``; the generic LP code is ``flight.lp``): ``simplex`` is a
dense bounded dual simplex written for these small problems (3-7 rows, up to ~40 columns): with
every cost ``r_n >= 0`` the all-off start is dual feasible, so no phase 1 is needed, and the
basis is refined at the end by solving the basic system from the original data. ``highs`` is a
HiGHS model built once and warm-started (row and column bounds changed each tick). ``linprog``
is ``scipy.optimize.linprog``. Any solver that fails to converge falls back to ``linprog``. The
core reads no clock: timing is the caller's.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from common.vehicle import VehicleArrays, VehicleCfg
from flight.lp import (
    INFEASIBLE,
    ITERATION_LIMIT,
    OPTIMAL,
    HighsWarm,
    SimplexState,
    dual_simplex,
    linprog_solve,
)
from flight.quantise import PulseSet, Quantiser

# Halvings of the translation fraction in :meth:`Allocator.allocate_trim`: the tick's share of
# the remaining delta-v is found to 1/32 of the remainder (at most 7 LPs in a trim tick).
TRIM_STEPS = 5

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
        self._warm: dict[int, HighsWarm] = {}
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
                warm = self._warm[rows] = HighsWarm(A, self._c)
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

    def _scaled_bounds(self, dw_down_B_rad_s, dw_up_B_rad_s, available, dv_down_B_m_s,
                       dv_up_B_m_s) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """The LP's rows (3, or 6 with translation), its scaled bounds and its columns (the
        available thrusters), as :meth:`solve_lp` takes them."""
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
        return rows, lo / rs, hi / rs, cols

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
        rows, lo_s, hi_s, cols = self._scaled_bounds(dw_down_B_rad_s, dw_up_B_rad_s, available,
                                                     dv_down_B_m_s, dv_up_B_m_s)
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

    def allocate_trim(
        self,
        dw_down_B_rad_s: np.ndarray,
        dw_up_B_rad_s: np.ndarray,
        available: np.ndarray | None,
        dv_remaining_B_m_s: np.ndarray,
        tol_m_s: float,
        steps: int = TRIM_STEPS,
    ) -> Allocation:
        """Orbit correction's trim: what is left of the delta-v, with attitude first.

        Asked for the whole remainder in one tick (``rem +/- tol/2`` per axis), the 6-row LP is
        infeasible within the tick bound whenever the remainder is more than a tick can give,
        and its scaled solution (seed 004 section 3) keeps the direction of the combined
        demand: the rate demand shrinks with the translation's scale, and attitude goes unheld
        for as long as the trim lasts. Here each axis whose remainder is outside ``tol/2`` asks
        this tick for at least ``f`` times the axis's one-tick capacity ``c_i`` (every available
        thruster pushing that way for the whole tick; at most the remainder) and at most the
        remainder plus ``tol/2``; axes already within ``tol/2`` stay within it. ``f`` is the
        largest value in ``[0, 1]`` (bisection, ``steps`` halvings) whose LP meets the rate
        demand within the tick; the rest of the delta-v is left to the next ticks. At ``f = 0``
        the translation rows ask for nothing; when even that cannot be met, the attitude-only
        allocation of :meth:`allocate` (scaled or best effort as usual)."""
        av = self._all_on if available is None else np.asarray(available, dtype=bool)
        rem = np.asarray(dv_remaining_B_m_s, dtype=float)
        half = 0.5 * float(tol_m_s)
        sign = np.sign(rem)
        active = np.abs(rem) > half
        push = np.clip(sign[None, :] * self.acc[av], 0.0, None).sum(axis=0) * self.tau_max_s
        cap = np.where(active, np.minimum(push, np.abs(rem)), 0.0)
        far = np.where(active, rem + sign * half, rem + half)
        near_fixed = np.where(active, 0.0, rem - half)

        def solve(f: float) -> tuple[np.ndarray, str] | None:
            near = np.where(active, sign * f * cap, near_fixed)
            return self._within_tick(dw_down_B_rad_s, dw_up_B_rad_s, av,
                                     np.minimum(near, far), np.maximum(near, far))

        got = solve(1.0)
        if got is None:
            got = solve(0.0)
            if got is None:
                return self.allocate(dw_down_B_rad_s, dw_up_B_rad_s, av)
            lo_f, hi_f = 0.0, 1.0
            for _ in range(steps):
                mid = 0.5 * (lo_f + hi_f)
                trial = solve(mid)
                if trial is not None:
                    lo_f, got = mid, trial
                else:
                    hi_f = mid
        tau, solver = got
        return self._finish(tau, av, True, "optimal", 1.0, "translation", solver)

    def _within_tick(self, lo, hi, av: np.ndarray, dv_lo, dv_hi) -> tuple[np.ndarray, str] | None:
        """The 6-row LP of :meth:`solve_lp` within the tick bound only: the optimal effective
        times (N,) and the solver, or None when the bounds cannot be met within the tick (no
        scaled or best-effort solve: the caller only asks whether they can)."""
        rows, lo_s, hi_s, cols = self._scaled_bounds(lo, hi, av, dv_lo, dv_hi)
        st, x, _, used = self._solve_main(rows, lo_s, hi_s, self._ub_tick[: len(cols)], cols)
        if st != OPTIMAL:
            return None
        tau = np.zeros(self.n)
        tau[cols] = x * self.h_s
        return tau, used

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
