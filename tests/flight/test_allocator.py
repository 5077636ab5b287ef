"""Allocator (seed 004 section 3-4) against independent oracles.

* ``scipy.optimize.linprog`` (HiGHS) on >= 10,000 random and structured problems: the same
  optimal fuel within 1e-9 relative. To keep the run short, the feasible problems are checked in
  batches: K independent LPs stacked block-diagonally form one LP whose optimum restricted to
  block k is an optimum of problem k (the objective is separable).
* a closed form on the decoupled generic vehicle (one thruster per channel and sign);
* the quantiser's allowed set, its carried remainder and the prediction ``dw = sum mu tau_E``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import linprog

from flight.allocator import Allocator
from flight.lp import INFEASIBLE, OPTIMAL, dual_simplex, linprog_solve
from flight.quantise import PulseSet, Quantiser
from hil.config import VEHICLE_DIR, VehicleArrays, VehicleCfg, load_vehicle

ALLOWED_MS = {0, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120, 130, 140, 150, 160, 170, 200}


def synthetic_vehicle(n: int = 30, seed: int = 7, manifolds: int = 2) -> VehicleCfg:
    """``n`` thrusters at random positions and directions (fixed seed), 248 N, Orel-sized."""
    rng = np.random.default_rng(seed)
    thr = []
    for i in range(n):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        pos = rng.uniform([-3.0, -1.5, -1.5], [3.0, 1.5, 1.5])
        thr.append({
            "name": f"T{i + 1}", "position_m": pos.tolist(), "direction": d.tolist(),
            "thrust_n": float(rng.uniform(200.0, 260.0)), "isp_s": float(rng.uniform(250, 300)),
            "manifold": f"M{i % manifolds + 1}",
        })
    return VehicleCfg.model_validate({
        "name": f"synthetic{n}", "mass_kg": 14000.0,
        "inertia_B_kg_m2": [[20000.0, 300.0, 0.0], [300.0, 60000.0, 0.0], [0.0, 0.0, 65000.0]],
        "com_m": [0.0, 0.05, 0.05],
        "manifolds": [f"M{k + 1}" for k in range(manifolds)], "thrusters": thr,
        "flight": {"allocator": {"solver": "simplex"}},
    })


@pytest.fixture(scope="module")
def synth() -> VehicleCfg:
    return synthetic_vehicle()


@pytest.fixture(scope="module")
def generic() -> VehicleCfg:
    return load_vehicle("generic")


def vehicles_for_tests() -> list[VehicleCfg]:
    out = [synthetic_vehicle(), synthetic_vehicle(12, seed=3), load_vehicle("generic")]
    if (VEHICLE_DIR / "orel.yaml").exists():
        out.append(load_vehicle("orel"))
    return out


# --------------------------------------------------------------------------- problem streams


def random_problems(alloc: Allocator, count: int, seed: int, rows: int = 3):
    """Bounds (rows,) in physical units and availability masks: random and structured."""
    rng = np.random.default_rng(seed)
    N = alloc.n
    mu_scale = float(np.abs(alloc.mu).max()) * alloc.h_s
    a_scale = float(np.abs(alloc.acc).max()) * alloc.h_s
    scale = np.array([mu_scale] * 3 + [a_scale] * 3)[:rows]
    for k in range(count):
        centre = rng.normal(size=rows) * rng.choice([0.1, 0.3, 0.6, 1.0, 2.0, 5.0]) * scale
        half = rng.uniform(0.0, 0.6, size=rows) * scale
        lo, hi = centre - half, centre + half
        if rng.random() < 0.1:  # a channel left free
            j = rng.integers(rows)
            lo[j], hi[j] = -np.inf, np.inf
        av = np.ones(N, dtype=bool)
        kind = k % 5
        if kind == 1:
            av[rng.integers(N)] = False
        elif kind == 2:
            av[rng.choice(N, size=min(2, N - 1), replace=False)] = False
        elif kind == 3 and len(alloc.arrays.manifolds) > 1:
            av &= alloc.arrays.manifold_of != rng.integers(len(alloc.arrays.manifolds))
        yield lo, hi, av


def scaled_lp(alloc: Allocator, lo, hi, av, ub_s):
    """The allocator's LP in the scaled form given to the solvers (tau in ticks, rows normed)."""
    rows = len(lo)
    cols = np.flatnonzero(av)
    rs = alloc._row_scale6[:rows]
    A = alloc._A6[:rows][:, cols]
    return A, alloc._c[cols], lo / rs, hi / rs, np.full(len(cols), ub_s / alloc.h_s)


def batched_linprog_costs(problems) -> np.ndarray:
    """Optimal cost of each (A, c, lo, hi, ub) through one block-diagonal linprog call."""
    blocks, costs, b_ub, bounds, sizes = [], [], [], [], []
    for A, c, lo, hi, ub in problems:
        fh, fl = np.isfinite(hi), np.isfinite(lo)
        blocks.append(sp.csr_matrix(np.vstack((A[fh], -A[fl]))))
        b_ub.append(np.concatenate((hi[fh], -lo[fl])))
        costs.append(c)
        bounds += [(0.0, float(u)) for u in ub]
        sizes.append(len(c))
    res = linprog(
        np.concatenate(costs), A_ub=sp.block_diag(blocks, format="csr"),
        b_ub=np.concatenate(b_ub), bounds=bounds, method="highs",
        options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10},
    )
    assert res.status == 0, res.message
    out, start = [], 0
    for c, n in zip(costs, sizes, strict=True):
        out.append(float(c @ res.x[start:start + n]))
        start += n
    return np.array(out)


# --------------------------------------------------------------------------- LP optimum


def test_lp_matches_linprog_on_10000_problems():
    """Req ALLOC-1: same optimum as linprog (1e-9 rel.) on >= 10,000 problems, all statuses."""
    plan = [(0, 3, 4000), (0, 6, 2000), (1, 3, 1500), (2, 3, 1500), (2, 6, 500)]
    vehicles = vehicles_for_tests()
    if len(vehicles) > 3:
        plan.append((3, 3, 1000))
    else:
        plan.append((0, 3, 1000))
    total = 0
    seen = {"optimal": 0, "scaled": 0, "best_effort": 0}
    for vi, rows, count in plan:
        alloc = Allocator(vehicles[vi], solver="simplex")
        feas, mine, checked = [], [], []
        for lo, hi, av in random_problems(alloc, count, seed=100 * vi + rows, rows=rows):
            dv = (lo[3:], hi[3:]) if rows == 6 else (None, None)
            res = alloc.solve_lp(lo[:3], hi[:3], av, *dv)
            total += 1
            seen[res.status] += 1
            tau = res.tau_eff_s
            assert np.all(tau[~av] == 0.0)
            assert tau.min() >= 0.0 and tau.max() <= alloc.tau_max_s * (1 + 1e-12)
            if res.status == "optimal":
                act = np.concatenate((alloc.mu.T @ tau, alloc.acc.T @ tau))[:rows]
                span = np.abs(alloc._M6[:rows]).max(axis=1) * alloc.h_s
                assert np.all(act >= lo - 1e-9 * span) and np.all(act <= hi + 1e-9 * span)
                feas.append(scaled_lp(alloc, lo, hi, av, alloc.tau_max_s))
                mine.append(res.fuel_kg / alloc._cost_scale)
            elif len(checked) < 60 or total % 17 == 0:
                checked.append(res.status)
                # No solution within one tick: linprog must agree.
                st, _, _ = linprog_solve(*scaled_lp(alloc, lo, hi, av, alloc.tau_max_s))
                assert st == INFEASIBLE
                st, x, _ = linprog_solve(*scaled_lp(alloc, lo, hi, av, np.inf))
                if res.status == "scaled":
                    assert st == OPTIMAL
                    assert res.scale < 1.0
                    c = scaled_lp(alloc, lo, hi, av, np.inf)[1]
                    ref = float(c @ x)
                    got = res.cost_unscaled_kg / alloc._cost_scale
                    assert abs(got - ref) <= 1e-9 * max(abs(ref), 1e-300) + 1e-15
                    assert res.tau_eff_s.max() == pytest.approx(alloc.tau_max_s, rel=1e-12)
                else:
                    assert st == INFEASIBLE
                    assert not res.feasible and res.violation > 0.0
        for i in range(0, len(feas), 400):
            ref = batched_linprog_costs(feas[i:i + 400])
            got = np.array(mine[i:i + 400])
            err = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-12)
            assert err.max() <= 1e-9, (vi, rows, err.max())
    assert total >= 10_000
    assert all(v > 0 for v in seen.values()), seen


def test_highs_and_linprog_backends_agree_with_simplex(synth):
    """The three solvers give the same optimum on the same problems."""
    allocs = {s: Allocator(synth, solver=s) for s in ("simplex", "highs", "linprog")}
    for lo, hi, av in random_problems(allocs["simplex"], 300, seed=5):
        costs = {s: a.solve_lp(lo, hi, av) for s, a in allocs.items()}
        st = {r.status for r in costs.values()}
        assert len(st) == 1
        ref = costs["linprog"].cost_unscaled_kg
        for r in costs.values():
            assert r.cost_unscaled_kg == pytest.approx(ref, rel=1e-9, abs=1e-15)


def test_warm_start_equals_cold_start(synth):
    """A warm-started solve reaches the same optimum as a cold one on a slowly varying stream."""
    warm = Allocator(synth, solver="simplex")
    rng = np.random.default_rng(11)
    d = np.zeros(3)
    for _ in range(300):
        d = 0.9 * d + rng.normal(size=3) * 2e-4
        lo, hi = d - 5e-4, d + 5e-4
        r_w = warm.solve_lp(lo, hi)
        A, c, lo_s, hi_s, ub = scaled_lp(warm, lo, hi, np.ones(warm.n, bool), warm.tau_max_s)
        st, x, _, _ = dual_simplex(A, c, lo_s, hi_s, ub)
        if r_w.status == "optimal":
            assert st == OPTIMAL
            assert r_w.fuel_kg / warm._cost_scale == pytest.approx(float(c @ x), rel=1e-9)


def test_decoupled_vehicle_closed_form(generic):
    """Generic vehicle: one thruster per channel and sign, so tau = dw_down / mu exactly."""
    alloc = Allocator(generic, solver="simplex")
    mu = alloc.mu
    lo = np.array([1e-3, -4e-4, 2e-4])
    hi = lo + 5e-4
    res = alloc.solve_lp(lo, hi)
    expect = np.zeros(alloc.n)
    for ch in range(3):
        n = int(np.argmax(mu[:, ch]))  # the positive thruster of the channel
        assert np.count_nonzero(np.abs(mu[n]) > 1e-12) == 1
        if lo[ch] > 0:
            expect[n] = lo[ch] / mu[n, ch]
    # Channel y (lo < 0 < hi): nothing fires.
    assert res.tau_eff_s == pytest.approx(expect, rel=1e-12, abs=1e-15)


def test_infeasible_best_effort_minimises_violation(generic):
    """Positive roll with the only +roll thruster failed: best effort, nothing useless fires."""
    alloc = Allocator(generic, solver="simplex")
    plus_x = int(np.argmax(alloc.mu[:, 0]))
    av = alloc.available_mask(disabled=[plus_x])
    lo = np.array([1e-3, -1e-4, -1e-4])
    hi = np.array([2e-3, 1e-4, 1e-4])
    res = alloc.solve_lp(lo, hi, av)
    assert res.status == "best_effort" and not res.feasible
    assert res.violation == pytest.approx(1e-3, rel=1e-9)
    assert np.all(res.tau_eff_s == 0.0)
    a = alloc.allocate(lo, hi, av)
    assert not a.feasible and a.on_ms[plus_x] == 0


def test_closed_manifold_and_failed_thrusters_stay_off(synth):
    alloc = Allocator(synth)
    av = alloc.available_mask(disabled=["T3"], closed_manifolds=["M2"])
    assert not av[2] and not av[alloc.arrays.manifold_of == 1].any()
    for lo, hi, _ in random_problems(alloc, 200, seed=9):
        a = alloc.allocate(lo, hi, av)
        assert np.all(a.on_ms[~av] == 0)
        assert np.all(a.tau_eff_lp_s[~av] == 0.0)


# --------------------------------------------------------------------------- quantisation


def test_quantised_outputs_in_allowed_set_and_prediction(synth):
    """Req ALLOC-2: on_ms in the allowed set; dw_pred = sum mu (on - 3 ms); scaling <= tau_max."""
    alloc = Allocator(synth)
    for lo, hi, av in random_problems(alloc, 1000, seed=3, rows=6):
        a = alloc.allocate(lo[:3], hi[:3], av, lo[3:], hi[3:])
        assert set(a.on_ms.tolist()) <= ALLOWED_MS
        assert a.tau_eff_lp_s.max() <= alloc.tau_max_s * (1 + 1e-12)
        tau_e = np.where(a.on_ms > 0, a.on_ms - 3.0, 0.0) / 1000.0
        assert a.tau_eff_s == pytest.approx(tau_e, abs=1e-15)
        assert a.dw_pred_B_rad_s == pytest.approx(alloc.mu.T @ tau_e, rel=1e-12, abs=1e-18)
        assert a.dv_pred_B_m_s == pytest.approx(alloc.acc.T @ tau_e, rel=1e-12, abs=1e-18)
        assert a.fuel_kg == pytest.approx(float(alloc.r @ tau_e), rel=1e-12)


def test_pulse_set_from_timing(generic):
    ps = PulseSet.from_config(generic.timing, generic.thrust_profile)
    assert set(ps.on_ms.tolist()) == ALLOWED_MS
    assert ps.max_eff_s == pytest.approx(0.197)
    assert ps.effective_s(np.array([0, 30, 200])) == pytest.approx([0.0, 0.027, 0.197])


@pytest.mark.parametrize("seed", range(5))
def test_carry_keeps_long_run_mean(generic, seed):
    """Req ALLOC-3: over n ticks the mean command equals the LP mean within 15 ms / n."""
    ps = PulseSet.from_config(generic.timing, generic.thrust_profile)
    rng = np.random.default_rng(seed)
    n_thr, ticks = 8, 2000
    q = Quantiser(ps, n_thr, carry=True)
    level = rng.uniform(0.0005, 0.197, size=n_thr)
    demand = np.clip(level + rng.normal(size=(ticks, n_thr)) * 0.01, 1e-4, 0.197)
    demand[:, 0] = 0.004  # well below the shortest pulse (27 ms effective)
    eff = np.zeros((ticks, n_thr))
    av = np.ones(n_thr, dtype=bool)
    for k in range(ticks):
        on = q.step(demand[k], av)
        assert set(on.tolist()) <= ALLOWED_MS
        eff[k] = ps.effective_s(on)
    err = np.abs(eff.mean(axis=0) - demand.mean(axis=0))
    assert np.all(err <= 0.015 / ticks + 1e-12)
    assert np.all(np.abs(q.carry_ms) <= 15.0 + 1e-9)


def test_small_demand_rule(generic):
    """< 30 ms: below half the shortest pulse the demand waits in the carry, then fires 30."""
    ps = PulseSet.from_config(generic.timing, generic.thrust_profile)
    q = Quantiser(ps, 1)
    av = np.ones(1, dtype=bool)
    out = [int(q.step(np.array([0.006]), av)[0]) for _ in range(9)]
    # Targets 6, 12 -> 0; 18 -> 30 (carry -9); -3 -> 0 ... the mean stays 6 ms effective.
    assert out[:3] == [0, 0, 30]
    assert sum(ps.effective_s(np.array(out))) == pytest.approx(9 * 0.006, abs=0.0135)
    # No demand this tick: the thruster stays off and the remainder is dropped.
    assert q.step(np.array([0.0]), av)[0] == 0 and q.carry_ms[0] == 0.0
    # Unavailable: off, remainder dropped.
    q.step(np.array([0.01]), av)
    assert q.step(np.array([0.05]), np.zeros(1, bool))[0] == 0 and q.carry_ms[0] == 0.0


def test_without_carry_rounds_each_tick(generic):
    ps = PulseSet.from_config(generic.timing, generic.thrust_profile)
    q = Quantiser(ps, 4, carry=False)
    on = q.step(np.array([0.010, 0.0145, 0.180, 0.183]), np.ones(4, bool))
    # 180 ms effective is nearer 167 (170 commanded) than 197 (200); 183 is nearer 197.
    assert on.tolist() == [0, 30, 170, 200]


# --------------------------------------------------------------------------- orbit correction


def burn_vehicle() -> VehicleCfg:
    """Orel-like: 8 aft +X thrusters, 4 roll pairs, 8 lateral, offset centre of mass."""
    thr = []
    for k in range(8):  # aft belt, thrust +X, canted to give pitch/yaw torque
        ang = 2 * np.pi * k / 8
        pos = [-4.0, 1.2 * np.cos(ang), 1.2 * np.sin(ang)]
        d = np.array([1.0, 0.15 * np.cos(ang), 0.15 * np.sin(ang)])
        thr.append({"name": f"A{k + 1}", "position_m": pos,
                    "direction": (d / np.linalg.norm(d)).tolist(),
                    "thrust_n": 248.0, "manifold": "M1" if k % 2 == 0 else "M2"})
    for k in range(4):  # roll pairs: tangential couples at the front
        ang = np.pi / 2 * k
        for s in (1, -1):
            pos = [2.0, 1.5 * np.cos(ang) * s, 1.5 * np.sin(ang) * s]
            tang = [0.0, -np.sin(ang) * s, np.cos(ang) * s]
            sign = 1 if k % 2 == 0 else -1
            thr.append({"name": f"R{k + 1}{'ab'[s < 0]}", "position_m": pos,
                        "direction": [t * sign for t in tang], "thrust_n": 248.0,
                        "manifold": "M1" if k < 2 else "M2"})
    for k, d in enumerate([(0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)] * 2):
        thr.append({"name": f"L{k + 1}", "position_m": [0.3 * (1 if k < 4 else -1), 0.0, 0.0],
                    "direction": list(map(float, d)), "thrust_n": 248.0,
                    "manifold": "M1" if k < 4 else "M2"})
    pairs = [[f"R{k + 1}a", f"R{k + 1}b"] for k in range(4)]
    return VehicleCfg.model_validate({
        "name": "burn_test", "mass_kg": 14000.0,
        "inertia_B_kg_m2": [[20000.0, 0.0, 0.0], [0.0, 60000.0, 0.0], [0.0, 0.0, 60000.0]],
        "com_m": [0.0, 0.04, 0.03], "manifolds": ["M1", "M2"], "thrusters": thr,
        "flight": {"allocator": {"solver": "simplex", "roll_pairs": pairs}},
    })


def test_burn_holds_pitch_yaw_with_min_off_time():
    v = burn_vehicle()
    alloc = Allocator(v)
    burn = [f"A{k + 1}" for k in range(8)]
    bidx = [v.thruster_index(b) for b in burn]
    lo = np.array([-2e-3, -2e-3, -2e-3])
    hi = -lo
    a = alloc.allocate_burn(lo, hi, burn, dv_remaining_B_m_s=np.array([10.0, 0.0, 0.0]))
    assert a.mode == "burn" and a.feasible
    tau = a.tau_eff_lp_s
    assert np.all(tau[bidx] <= alloc.tau_max_s + 1e-15)
    dw = alloc.mu.T @ tau
    assert np.all(dw[1:] >= lo[1:] - 1e-12) and np.all(dw[1:] <= hi[1:] + 1e-12)
    # Off-time LP against linprog: min sum r_n t_off subject to the pitch/yaw bounds.
    M = alloc.mu[bidx][:, 1:].T
    full = M @ np.full(8, alloc.tau_max_s)
    res = linprog(alloc.r[bidx], A_ub=np.vstack((M, -M)),
                  b_ub=np.concatenate((full - lo[1:], -(full - hi[1:]))),
                  bounds=[(0, alloc.tau_max_s)] * 8, method="highs")
    off = alloc.tau_max_s - tau[bidx]
    assert float(alloc.r[bidx] @ off) == pytest.approx(res.fun, rel=1e-7, abs=1e-12)
    assert set(a.on_ms.tolist()) <= ALLOWED_MS


def test_burn_roll_pair_and_lateral_table():
    v = burn_vehicle()
    alloc = Allocator(v)
    burn = [f"A{k + 1}" for k in range(8)]
    lo = np.array([5e-4, -2e-3, -2e-3])  # needs positive roll
    hi = np.array([2e-3, 2e-3, 2e-3])
    a = alloc.allocate_burn(lo, hi, burn, dv_remaining_B_m_s=np.array([5.0, -0.01, 0.005]))
    pairs = alloc.roll_pairs
    fired = [(i, j) for i, j in pairs if a.tau_eff_lp_s[i] > 0]
    assert len(fired) == 1
    i, j = fired[0]
    assert a.tau_eff_lp_s[i] == a.tau_eff_lp_s[j]
    assert alloc.mu[i, 0] + alloc.mu[j, 0] > 0
    lat = [v.thruster_index(f"L{k + 1}") for k in range(8)]
    lat_fired = [k for k in lat if a.tau_eff_lp_s[k] > 0]
    assert any(alloc.acc[k, 1] < 0 for k in lat_fired)
    assert any(alloc.acc[k, 2] > 0 for k in lat_fired)


def test_burn_reconfigures_without_a_manifold():
    v = burn_vehicle()
    alloc = Allocator(v)
    av = alloc.available_mask(closed_manifolds=["M2"])
    burn = [f"A{k + 1}" for k in range(8)]
    a = alloc.allocate_burn(np.full(3, -2e-3), np.full(3, 2e-3), burn, av)
    assert np.all(a.on_ms[~av] == 0)
    assert np.count_nonzero(a.on_ms[[v.thruster_index(b) for b in burn]]) >= 1


def test_orel_vehicle_if_present():
    if not (VEHICLE_DIR / "orel.yaml").exists():
        pytest.skip("configs/vehicles/orel.yaml not written yet")
    v = load_vehicle("orel")
    ar = VehicleArrays.from_vehicle(v)
    alloc = Allocator(v)
    assert alloc.n == 30
    for mf in ar.manifolds:  # each manifold alone controls all three axes (seed 004)
        av = alloc.available_mask(closed_manifolds=[m for m in ar.manifolds if m != mf])
        for ch in range(3):
            for s in (1, -1):
                lo = np.full(3, -1e-5)
                hi = np.full(3, 1e-5)
                lo[ch], hi[ch] = (1e-4, 2e-4) if s > 0 else (-2e-4, -1e-4)
                assert alloc.solve_lp(lo, hi, av).status != "best_effort", (mf, ch, s)
