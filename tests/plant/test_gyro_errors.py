"""Gyro error model (seed 003 eq. 3; docs/design.md 5.3) against statistics and closed forms.

``w_meas = w_B + b(t) + n`` with ``n ~ N(0, noise_std^2)`` per axis, ``b(t) = bias + walk(t)``,
``walk`` a random walk with increments ``N(0, bias_walk^2 dt)``, then quantised to
``quantum_rad_s`` (``plant.gyro`` module doc).

Statistical bounds: every estimate is compared with the quantiles of its exact sampling law
(chi-square for sums of squares, normal for means) at a two-sided level of ``P_FAIL`` = 1e-6,
so a correct model fails a given check for fewer than one seed in a million; the seeds are
fixed, so each test is deterministic. With tens of thousands of samples the bounds are a few
per cent, tight enough to catch a wrong scale (e.g. a missing ``sqrt(dt)``, noise applied
after quantisation, a factor on the std).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import make_vehicle
from scipy.stats import chi2, norm

from hil.config import FaultSpec, GyroCfg, InitialCfg
from plant.core import Plant
from plant.faults import FaultState
from plant.gyro import Gyro

P_FAIL = 1e-6
Z = float(norm.ppf(1 - P_FAIL / 2))  # ~4.9: two-sided normal bound
# Spherical inertia: w x J w = 0, so any constant rate stays constant (torque-free).
J_SPHERE = [[200.0, 0.0, 0.0], [0.0, 200.0, 0.0], [0.0, 0.0, 200.0]]


def _chi2_ok(sum_sq_over_var: float, dof: int) -> bool:
    """``sum (x / sigma)^2`` within the two-sided ``P_FAIL`` quantiles of chi2(dof)."""
    lo, hi = chi2.ppf(P_FAIL / 2, dof), chi2.ppf(1 - P_FAIL / 2, dof)
    return bool(lo <= sum_sq_over_var <= hi)


def _plant_errors(gyro: dict, t_end_s: float, *, seed: int = 0, faults=(),
                  rate_deg_s=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run a torque-free spherical body with constant rate; return ``(t (K,), meas (K, 3),
    truth w (3,))`` for every gyro sample measured up to ``t_end_s``."""
    v = make_vehicle(inertia_B_kg_m2=J_SPHERE, gyro=gyro)
    plant = Plant(v, seed=seed, step_s=0.05,
                  initial=InitialCfg(rate_B_deg_s=rate_deg_s))
    for f in faults:
        plant.inject(f)
    plant.advance_to(t_end_s)
    s = plant.gyro_samples_until(t_end_s + 1.0)
    t = np.array([x.t_meas_s for x in s])
    meas = np.array([x.rate_B_rad_s for x in s])
    return t, meas, plant.truth.omega_B_rad_s


def test_white_noise_std_matches_configured_value() -> None:
    """Errors (measured - true, constant true rate) have zero mean and the configured std:
    ``sum e^2 / sigma^2 ~ chi2(n)`` per axis (n = 5001 samples: variance within ~ +/-10 %;
    pooled over the axes ~ +/-6 %)."""
    sigma = 2.0e-5
    t, meas, w = _plant_errors({"noise_std_rad_s": sigma, "rate_hz": 100.0}, 50.0,
                               seed=3, rate_deg_s=(0.3, -0.2, 0.1))
    assert w == pytest.approx(np.radians([0.3, -0.2, 0.1]), abs=1e-15)  # torque-free, constant
    e = meas - w
    n = e.shape[0]
    assert n == 5001
    for k in range(3):
        assert _chi2_ok(float(np.sum((e[:, k] / sigma) ** 2)), n), f"axis {k}: std {e[:, k].std()}"
        assert abs(e[:, k].mean()) < Z * sigma / math.sqrt(n)
    assert _chi2_ok(float(np.sum((e / sigma) ** 2)), e.size)
    # A 5 % error in the std would fail the pooled bound: it is that tight.
    assert not _chi2_ok(float(np.sum((e / (1.05 * sigma)) ** 2)), e.size)
    assert not _chi2_ok(float(np.sum((e / (0.95 * sigma)) ** 2)), e.size)
    # Independent axes (different draws), no sample-to-sample correlation (white).
    for a, b in ((0, 1), (1, 2), (0, 2)):
        assert abs(np.corrcoef(e[:, a], e[:, b])[0, 1]) < Z / math.sqrt(n)
    assert abs(np.corrcoef(e[:-1, 0], e[1:, 0])[0, 1]) < Z / math.sqrt(n)


def test_static_bias_is_the_mean_offset() -> None:
    """Configured bias appears as the mean error per axis (within Z sigma / sqrt(n)); the
    spread about it is still the configured noise (chi2 with n - 1 dof, mean estimated)."""
    sigma, bias = 1.0e-5, (3.0e-4, -1.0e-4, 5.0e-5)
    t, meas, w = _plant_errors({"noise_std_rad_s": sigma, "bias_rad_s": bias, "rate_hz": 50.0},
                               60.0, seed=5)
    e = meas - w
    n = e.shape[0]
    assert e.mean(axis=0) == pytest.approx(bias, abs=Z * sigma / math.sqrt(n))
    for k in range(3):
        dev = e[:, k] - e[:, k].mean()
        assert _chi2_ok(float(np.sum((dev / sigma) ** 2)), n - 1)


def _walk_gyro(seed: int, walk: float, rate_hz: float) -> tuple[Gyro, FaultState]:
    """A bare sensor with only the bias walk (rngs spawned as the plant does, one per seed)."""
    cfg = GyroCfg(bias_walk_rad_s_sqrt_s=walk, rate_hz=rate_hz)
    rngs = tuple(np.random.Generator(np.random.PCG64(s))
                 for s in np.random.SeedSequence(seed).spawn(3))
    return Gyro(cfg, rngs), FaultState(make_vehicle())


def _walk_series(seed: int, walk: float, rate_hz: float, k_samples: int) -> np.ndarray:
    """Measured rates (k_samples, 3) of a sensor at rest with bias walk only: ``b(t_k)``."""
    g, fs = _walk_gyro(seed, walk, rate_hz)
    z = np.zeros(3)
    return np.array([g.measure(k / rate_hz, z, z, z, z, fs).rate_B_rad_s
                     for k in range(k_samples)])


def test_bias_walk_variance_grows_as_sigma2_t_across_realisations() -> None:
    """Random walk from b(0) = 0: ``Var b(t) = s^2 t``. 300 seeds x 3 axes = 900 independent
    realisations per time; ``sum b^2 / (s^2 t) ~ chi2(900)`` (bound about +/-25 %). The law is
    checked at t = 1, 4, 10 s: a variance growing as t^2, or per sample without the dt, fails
    by factors of 4 to 10."""
    s, rate_hz = 3.0e-6, 10.0
    runs = np.array([_walk_series(seed, s, rate_hz, 101) for seed in range(300)])  # (R, K, 3)
    assert np.all(runs[:, 0, :] == 0.0)  # the walk starts at zero: no step before sample 1
    for t in (1.0, 4.0, 10.0):
        b = runs[:, int(round(t * rate_hz)), :].ravel()
        assert _chi2_ok(float(np.sum(b**2) / (s**2 * t)), b.size), (t, b.var(), s**2 * t)


def test_bias_walk_increments_are_independent_with_variance_sigma2_dt() -> None:
    """One long run (20000 samples at 10 Hz, 3 axes): the one-sample increments have variance
    ``s^2 dt`` (chi2, bound ~ +/-3 %) and no lag-1 correlation (|r| < Z / sqrt(n)); the
    10 s increments of disjoint windows have variance ``s^2 * 10 s`` (chi2(5997), ~ +/-12 %).
    Stationary independent increments are what makes Var b(t) = s^2 t for every t."""
    s, rate_hz = 3.0e-6, 10.0
    b = _walk_series(11, s, rate_hz, 20_001)
    d = np.diff(b, axis=0)
    assert _chi2_ok(float(np.sum(d**2) / (s**2 / rate_hz)), d.size)
    for k in range(3):
        r = np.corrcoef(d[:-1, k], d[1:, k])[0, 1]
        assert abs(r) < Z / math.sqrt(d.shape[0])
    w10 = b[::100]
    d10 = np.diff(w10, axis=0)
    assert _chi2_ok(float(np.sum(d10**2) / (s**2 * 10.0)), d10.size)


def test_quantisation_deterministic_rounds_to_nearest_step() -> None:
    """No noise: the output is the true rate rounded to the nearest multiple of q."""
    q = 1.0e-4
    w = np.array([0.4 * q, 0.6 * q, -3.3 * q])
    t, meas, w_true = _plant_errors({"quantum_rad_s": q, "rate_hz": 10.0}, 2.0,
                                    rate_deg_s=tuple(np.degrees(w)))
    assert w_true == pytest.approx(w, rel=1e-12)
    assert np.array_equal(meas, np.tile([0.0, q, -3 * q], (meas.shape[0], 1)))


def test_quantisation_after_noise_is_unbiased_with_sheppard_variance() -> None:
    """Noise sigma = q before the quantiser (docs/design.md 5.3 order: noise, then quantisation):
    the output mean is the true rate, not its rounded value, and the variance is
    ``sigma^2 + q^2 / 12`` (Sheppard; exact to ~1e-8 relative for sigma >= q). Had the
    quantiser come first, the mean would sit 0.4 q away and the variance would be sigma^2."""
    q = 1.0e-4
    sigma = q
    w = np.array([0.4 * q, 0.4 * q, 0.4 * q])
    t, meas, w_true = _plant_errors({"quantum_rad_s": q, "noise_std_rad_s": sigma,
                                     "rate_hz": 100.0}, 50.0, seed=2,
                                    rate_deg_s=tuple(np.degrees(w)))
    assert np.allclose(meas / q, np.round(meas / q), rtol=0, atol=1e-9)
    n = meas.shape[0]
    var = sigma**2 + q**2 / 12
    for k in range(3):
        assert meas[:, k].mean() == pytest.approx(w_true[k], abs=Z * math.sqrt(var / n))
        dev = meas[:, k] - w_true[k]
        assert _chi2_ok(float(np.sum(dev**2) / var), n)


def test_integrating_gyro_increments_are_multiples_of_the_angle_quantum() -> None:
    """Seed 002 pulse counter: each increment is a whole number of angle quanta q / f, and the
    counted total stays within half a quantum of the true angle w t."""
    q, f = 1.0e-4, 5.0
    w = 2.37e-3
    t, meas, _ = _plant_errors({"kind": "integrating", "quantum_rad_s": q, "rate_hz": f},
                               20.0, rate_deg_s=(math.degrees(w), 0.0, 0.0))
    inc = meas[1:, 0] / f  # rate of an integrating sample = increment / interval
    qa = q / f
    assert np.allclose(inc / qa, np.round(inc / qa), rtol=0, atol=1e-6)
    total = np.cumsum(inc)
    assert np.all(np.abs(total - w * t[1:]) <= qa / 2 + 1e-12)


def _accel_run(faults=(), clear_at: float | None = None, kind: str = "rate",
               t_end_s: float = 3.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Noiseless 10 Hz gyro on a body spun up by a constant disturbance torque about x:
    w_x(t) = a t exactly (spherical inertia). Returns ``(t, meas_x, a)``."""
    torque = 0.02
    v = make_vehicle(inertia_B_kg_m2=J_SPHERE, gyro={"kind": kind, "rate_hz": 10.0},
                     disturbance={"constant_torque_B_Nm": [torque, 0.0, 0.0]})
    plant = Plant(v, step_s=0.01)
    for f in faults:
        plant.inject(f)
    if clear_at is not None:
        plant.advance_to(clear_at)
        plant.clear_faults()
    plant.advance_to(t_end_s)
    s = plant.gyro_samples_until(t_end_s)
    return (np.array([x.t_meas_s for x in s]), np.array([x.rate_B_rad_s[0] for x in s]),
            torque / 200.0)


def test_frozen_output_repeats_last_value_and_clearing_restores_live_output() -> None:
    """Frozen over [1.05, 2.0): samples 11..19 repeat sample 10 (a * 1.0 s); from sample 20
    (the clear time, half-open window) the output is live again: a * t."""
    t, y, a = _accel_run([FaultSpec(kind="gyro_frozen", t_s=1.05, clear_t_s=2.0)])
    assert y[:11] == pytest.approx(a * t[:11], rel=1e-12, abs=1e-18)
    assert np.all(y[11:20] == y[10])
    assert y[20:] == pytest.approx(a * t[20:], rel=1e-12)


def test_frozen_output_cleared_by_command_restores_live_output() -> None:
    """The same freeze with no clear time, cleared by ``Plant.clear_faults()`` at 1.45 s
    (between samples): frozen through sample 14, live from sample 15 (1.5 s) on."""
    t, y, a = _accel_run([FaultSpec(kind="gyro_frozen", t_s=1.05)], clear_at=1.45)
    assert np.all(y[11:15] == y[10])
    assert y[15:] == pytest.approx(a * t[15:], rel=1e-12)


def test_frozen_integrating_gyro_loses_the_angle_while_frozen() -> None:
    """Integrating gyro: zero increments while frozen (the counter stops); after the clear the
    increments are the true angle increments again, 0.5 a (t_k^2 - t_{k-1}^2); the angle
    turned during the freeze is never reported (plant.gyro doc: the counter stopped)."""
    t, y, a = _accel_run([FaultSpec(kind="gyro_frozen", t_s=1.05, clear_t_s=2.0)],
                         kind="integrating")
    inc = y[1:] * 0.1  # increment of sample k = rate * interval
    true_inc = 0.5 * a * (t[1:] ** 2 - t[:-1] ** 2)
    assert inc[:10] == pytest.approx(true_inc[:10], rel=1e-9)
    assert np.all(inc[10:19] == 0.0)  # samples 11..19
    assert inc[19:] == pytest.approx(true_inc[19:], rel=1e-9)
    assert inc.sum() == pytest.approx(0.5 * a * t[-1] ** 2 - true_inc[10:19].sum(), rel=1e-9)


def test_noise_increase_fault_adds_configured_std_in_quadrature() -> None:
    """``gyro_noise`` (plant.faults doc) adds independent white noise of std ``m`` on its axis
    while active: the std there becomes ``sqrt(sigma^2 + m^2)`` (here sqrt(10) sigma); before,
    after and on the other axes it stays ``sigma``. chi2 bounds per window. (The fault adds a
    std in quadrature; it does not multiply the configured std by a factor.)"""
    sigma, m = 1.0e-5, 3.0e-5
    fault = FaultSpec(kind="gyro_noise", t_s=10.0, clear_t_s=30.0, magnitude_rad_s=m, axis=1)
    t, meas, w = _plant_errors({"noise_std_rad_s": sigma, "rate_hz": 100.0}, 40.0, seed=9,
                               faults=[fault])
    e = meas - w
    inside = (t >= 10.0) & (t < 30.0)
    assert inside.sum() == 2000
    assert _chi2_ok(float(np.sum(e[inside, 1] ** 2) / (sigma**2 + m**2)), int(inside.sum()))
    assert _chi2_ok(float(np.sum(e[~inside, 1] ** 2) / sigma**2), int((~inside).sum()))
    for k in (0, 2):
        assert _chi2_ok(float(np.sum(e[:, k] ** 2) / sigma**2), e.shape[0])
    # Same seed without the fault: the base noise draws are the same stream (independent
    # fault-noise generator), so the difference is the fault's noise alone, std m.
    _, base, _ = _plant_errors({"noise_std_rad_s": sigma, "rate_hz": 100.0}, 40.0, seed=9)
    d = meas - base
    assert np.all(d[~inside] == 0.0) and np.all(d[:, [0, 2]] == 0.0)
    assert _chi2_ok(float(np.sum(d[inside, 1] ** 2) / m**2), int(inside.sum()))
