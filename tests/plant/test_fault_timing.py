"""Fault timing (docs/design.md 5.6; plant.faults): onset at ``t_s``, end at ``clear_t_s``, levels.

A thruster fault changes the thruster's *target* at its own time, with no electrical delay
(the valve itself fails; plant.thruster module doc), and the thrust then follows seed 004
eq. 4.1 from the level reached: a rise ``B (1 - exp(-k1 x^n1))`` (origin shifted when it starts
from a non-zero level) or a decay ``B + (A - B) exp(-k2 x^n2)``. The oracles below write those
curves out from the calibrated constants (checked against quadrature in test_thruster.py) and
integrate them with ``scipy.integrate.quad``. Times are deliberately off the 10 ms step grid:
the exact impulse per step makes the onset exact, not rounded to a step.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import make_vehicle
from scipy.integrate import quad

from hil.config import FaultSpec, ThrustProfileCfg
from plant.core import Plant
from plant.thruster import ThrustProfile

P_N = 10.0
I_XX = 100.0  # X+ gives 10 N m per 10 N about x (lever 1 m); J_xx = 100
PROF = ThrustProfile.calibrate(ThrustProfileCfg())
K1, N1, K2, N2, T_R = PROF.k1, PROF.n1, PROF.k2, PROF.n2, PROF.t_r_s


def _rise(x: float) -> float:
    return 0.0 if x <= 0 else 1.0 - math.exp(-K1 * x**N1)


def _decay(x: float) -> float:
    return 1.0 if x <= 0 else math.exp(-K2 * x**N2)


def _area(fn, a: float, b: float) -> float:
    return quad(fn, a, b, limit=400, epsabs=1e-15, epsrel=1e-13)[0]


# Missing area of a full rise and added area of a full decay (no electrical delay), seconds.
E_RISE = _area(lambda x: 1.0 - _rise(x), 0.0, 1.0)
E_DECAY = _area(_decay, 0.0, 2.0)


def _on_ticks(plant: Plant, j: int, ticks: range, on_ms: int = 200) -> None:
    for n in ticks:
        on = np.zeros(6)
        on[j] = on_ms
        plant.apply_command(n, n * 0.2, on)


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.15])
def test_stuck_on_acts_exactly_from_t_s_until_clear_t_s(fraction: float) -> None:
    """Leak on a thruster never commanded, window [1.2345, 3.4567): nothing before t_s; a rise
    from t_s; ``f P`` held; a decay from clear_t_s; afterwards no more impulse. Total impulse
    ``f P ((t_c - t_s) - E_rise + E_decay)``, and the rate follows it exactly (w = r I / J)."""
    t_s, t_c = 1.2345, 3.4567
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.inject(FaultSpec(kind="stuck_on", t_s=t_s, clear_t_s=t_c, thruster="X+",
                           fraction=fraction))
    fp = fraction * P_N
    plant.advance_to(t_s - 1e-4)
    assert plant.truth.impulse_Ns[0] == 0.0 and plant.thrust_now_n()[0] == 0.0
    assert np.all(plant.truth.omega_B_rad_s == 0.0)
    plant.advance_to(t_s + 0.03)
    assert plant.thrust_now_n()[0] == pytest.approx(fp * _rise(0.03), rel=1e-12)
    early = fp * _area(_rise, 0.0, 0.03)
    assert plant.truth.impulse_Ns[0] == pytest.approx(early, rel=1e-9)
    assert plant.truth.omega_B_rad_s[0] == pytest.approx(early / I_XX, rel=1e-9)
    plant.advance_to(t_c - 1e-4)
    assert plant.thrust_now_n()[0] == pytest.approx(fp, rel=1e-12)
    plant.advance_to(t_c + 0.02)
    assert plant.thrust_now_n()[0] == pytest.approx(fp * _decay(0.02), rel=1e-12)
    plant.advance_to(t_c + 2.0)
    total = fp * ((t_c - t_s) - E_RISE + E_DECAY)
    assert plant.truth.impulse_Ns[0] == pytest.approx(total, rel=1e-9)
    assert plant.truth.omega_B_rad_s[0] == pytest.approx(total / I_XX, rel=1e-9)
    i_end = plant.truth.impulse_Ns[0]
    plant.advance_to(t_c + 6.0)
    assert plant.truth.impulse_Ns[0] == i_end  # the fault no longer acts
    assert plant.thrust_now_n()[0] == 0.0
    assert plant.truth.faults == ()


def test_half_stuck_on_gives_half_thrust_commanded_off_and_full_commanded_on() -> None:
    """50 % residual (docs/design.md 5.6): commanded off, 0.5 P; commanded on (ticks 5..9), P; after
    the off command the thrust decays from P toward 0.5 P (``0.5 + 0.5 exp(-k2 x)`` from
    t_off + T_R), then holds: 2 s of it give 0.5 P x 2 s and ``dw = 0.5 P r 2 s / J``."""
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.inject(FaultSpec(kind="stuck_on", t_s=0.0, thruster="X+", fraction=0.5))
    _on_ticks(plant, 0, range(5, 10))
    plant.apply_command(10, 2.0, np.zeros(6))
    plant.advance_to(0.9)
    assert plant.thrust_now_n()[0] == pytest.approx(0.5 * P_N, rel=1e-12)
    plant.advance_to(1.9)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N, rel=1e-9)
    plant.advance_to(2.0 + T_R + 0.015)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N * (0.5 + 0.5 * _decay(0.015)),
                                                    rel=1e-12)
    plant.advance_to(3.0)
    i0, w0 = plant.truth.impulse_Ns[0], plant.truth.omega_B_rad_s[0]
    plant.advance_to(5.0)
    assert plant.truth.impulse_Ns[0] - i0 == pytest.approx(0.5 * P_N * 2.0, rel=1e-9)
    assert plant.truth.omega_B_rad_s[0] - w0 == pytest.approx(0.5 * P_N * 2.0 / I_XX, rel=1e-9)


def _degraded_oracle(d: float, t_s: float, t_c: float, t_cmd_off: float) -> float:
    """Normalised impulse of a firing commanded on from 0 to ``t_cmd_off`` with a ``degraded``
    fault of fraction ``d`` over [t_s, t_c) (eq. 4.1 pieces, module doc)."""
    rise0 = _area(lambda t: _rise(t - T_R), T_R, t_s)
    l_s = _rise(t_s - T_R)
    mid = _area(lambda t: d + (l_s - d) * _decay(t - t_s), t_s, t_c)
    l_c = d + (l_s - d) * _decay(t_c - t_s)
    x0 = (-math.log1p(-l_c) / K1) ** (1.0 / N1)  # rise origin through the level l_c
    t_e = t_cmd_off + T_R
    rise1 = _area(lambda t: _rise(t - t_c + x0), t_c, t_e)
    l_e = _rise(t_e - t_c + x0)
    return rise0 + mid + rise1 + l_e * E_DECAY


def test_degraded_fraction_and_window_mid_firing() -> None:
    """Degraded 0.4 over [0.5123, 1.3071) while X+ is commanded on 0-2 s: P before t_s exactly,
    decay toward 0.4 P from t_s (no electrical delay), 0.4 P held, rise back to P from the
    clear time; total impulse by quadrature of those pieces."""
    d, t_s, t_c = 0.4, 0.5123, 1.3071
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.inject(FaultSpec(kind="degraded", t_s=t_s, clear_t_s=t_c, thruster="X+", fraction=d))
    _on_ticks(plant, 0, range(0, 10))
    plant.apply_command(10, 2.0, np.zeros(6))
    plant.advance_to(t_s - 1e-4)
    level_s = _rise(t_s - 1e-4 - T_R)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N * level_s, rel=1e-12)
    plant.advance_to(t_s + 0.01)
    l_s = _rise(t_s - T_R)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N * (d + (l_s - d) * _decay(0.01)),
                                                    rel=1e-12)
    plant.advance_to(t_c - 1e-3)
    assert plant.thrust_now_n()[0] == pytest.approx(d * P_N, rel=1e-9)  # the configured share
    plant.advance_to(t_c + 0.02)
    x0 = (-math.log1p(-d) / K1) ** (1.0 / N1)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N * _rise(0.02 + x0), rel=1e-9)
    plant.advance_to(1.9)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N, rel=1e-12)
    plant.advance_to(4.0)
    expected = P_N * _degraded_oracle(d, t_s, t_c, 2.0)
    assert plant.truth.impulse_Ns[0] == pytest.approx(expected, rel=1e-9)
    # Against the fault-free firing the deficit is about (1 - d) P (t_c - t_s).
    nominal = P_N * (_area(lambda t: _rise(t - T_R), T_R, 2.0 + T_R) + _rise(2.0) * E_DECAY)
    assert nominal - expected == pytest.approx((1 - d) * P_N * (t_c - t_s), rel=0.02)


@pytest.mark.parametrize("kind, fraction", [("degraded", 0.25), ("fail_to_fire", None)])
def test_onset_mid_firing_is_at_t_s_not_at_the_next_step(kind: str, fraction) -> None:
    """A fault at 0.7777 s (between steps) during a lit pulse: full thrust 0.1 ms before, and
    0.3 ms after the thrust is already on the decay curve from t_s toward the faulty level."""
    t_s = 0.7777
    g = 0.0 if fraction is None else fraction
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.inject(FaultSpec(kind=kind, t_s=t_s, thruster="X+", fraction=fraction))
    _on_ticks(plant, 0, range(0, 10))
    plant.advance_to(t_s - 1e-4)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N, rel=1e-12)
    for dt in (3e-4, 0.004, 0.05):
        plant.advance_to(t_s + dt)
        assert plant.thrust_now_n()[0] == pytest.approx(P_N * (g + (1 - g) * _decay(dt)),
                                                        rel=1e-12)


def test_clear_command_for_a_future_time_equals_clear_t_s() -> None:
    """``Plant.clear_faults(thruster, t_s)`` issued early for a later time ends the fault at
    that time, exactly as a ``clear_t_s`` in the fault would (same impulse and rate)."""
    t_s, t_c = 1.2345, 3.4567
    a = Plant(make_vehicle(), step_s=0.01)
    a.inject(FaultSpec(kind="stuck_on", t_s=t_s, clear_t_s=t_c, thruster="Y-", fraction=0.5))
    b = Plant(make_vehicle(), step_s=0.01)
    b.inject(FaultSpec(kind="stuck_on", t_s=t_s, thruster="Y-", fraction=0.5))
    b.advance_to(2.0)
    assert [e.spec.thruster for e in b.clear_faults("Y-", t_s=t_c)] == ["Y-"]
    for p in (a, b):
        p.advance_to(6.0)
    assert b.truth.impulse_Ns[3] == pytest.approx(a.truth.impulse_Ns[3], rel=1e-12)
    assert b.truth.omega_B_rad_s == pytest.approx(a.truth.omega_B_rad_s, rel=1e-12)
    assert a.truth.impulse_Ns[3] == pytest.approx(
        0.5 * P_N * ((t_c - t_s) - E_RISE + E_DECAY), rel=1e-9)


def test_fault_with_past_start_time_starts_now() -> None:
    """Injected at 2.0 s with t_s = 0.5 s: it starts at 2.0 s (no retroactive impulse)."""
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.advance_to(2.0)
    entry = plant.inject(FaultSpec(kind="stuck_on", t_s=0.5, thruster="Z+"))
    assert entry.t_on_s == 2.0
    plant.advance_to(2.05)
    assert plant.truth.impulse_Ns[4] == pytest.approx(P_N * _area(_rise, 0.0, 0.05), rel=1e-9)


def _gyro_run(faults) -> np.ndarray:
    v = make_vehicle(gyro={"noise_std_rad_s": 0.0, "rate_hz": 10.0})
    plant = Plant(v, step_s=0.01)
    for f in faults:
        plant.inject(f)
    plant.advance_to(3.0)
    return np.array([s.rate_B_rad_s for s in plant.gyro_samples_until(3.0)])


def test_gyro_fault_window_off_sample_times() -> None:
    """Bias step over [1.05, 1.95) at 10 Hz: exactly samples 11..19 (1.1..1.9 s) carry it, on
    the configured axis only (the first sample at or after t_s, the last before clear_t_s)."""
    y = _gyro_run([FaultSpec(kind="gyro_bias_step", t_s=1.05, clear_t_s=1.95,
                             magnitude_rad_s=0.01, axis=0)])
    hit = np.flatnonzero(y[:, 0] != 0.0)
    assert hit.tolist() == list(range(11, 20))
    assert np.all(y[hit, 0] == 0.01) and np.all(y[:, 1:] == 0.0)
