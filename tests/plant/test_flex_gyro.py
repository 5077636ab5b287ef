"""Flex modes (seed 003 eq. 2), gyro (seed 003 eq. 3; seed 002), gyro faults, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import make_vehicle
from scipy.linalg import expm

from hil.config import FaultSpec
from plant.core import Plant
from plant.flex import transition

FREQ_HZ, DELTA = 0.5, 0.1
FLEX = [{"name": "panel", "freq_hz": FREQ_HZ, "log_decrement": DELTA,
         "gyro_phi": [1.0e-2, 0.0, 0.0], "default": {"f": [0.0, 0.0, 0.0],
                                                    "phi": [1.0e-2, 0.0, 0.0]}}]


@pytest.mark.parametrize("h", [0.001, 0.01, 0.0137, 0.2])
def test_transition_matches_expm(h: float) -> None:
    """Closed-form Phi, Gamma against the matrix exponential of the augmented system."""
    w = 2 * math.pi * FREQ_HZ
    A = np.array([[0.0, 1.0, 0.0], [-w * w, -2 * DELTA * FREQ_HZ, 1.0], [0.0, 0.0, 0.0]])
    E = expm(A * h)
    (p11, p12, p21, p22), (g1, g2) = transition(FREQ_HZ, DELTA, h)
    assert np.array([[p11, p12], [p21, p22]]) == pytest.approx(E[:2, :2], rel=1e-10, abs=1e-14)
    assert np.array([g1, g2]) == pytest.approx(E[:2, 2], rel=1e-10, abs=1e-16)


def test_struck_mode_rings_at_damped_frequency_with_decrement() -> None:
    """One X+ pulse, then free ringing seen by a fast noiseless gyro: zero crossings give the
    damped frequency, successive peaks the decrement (per damped period)."""
    v = make_vehicle(flex_modes=FLEX, gyro={"noise_std_rad_s": 0.0, "rate_hz": 200.0})
    plant = Plant(v, step_s=0.005)
    plant.apply_command(0, 0.0, np.array([50, 0, 0, 0, 0, 0]))
    plant.apply_command(1, 0.2, np.zeros(6))
    plant.advance_to(1.0)
    rigid = plant.truth.omega_B_rad_s[0]
    plant.gyro_samples_until(1.0)
    plant.advance_to(21.0)
    s = plant.gyro_samples_until(21.0)
    t = np.array([x.t_meas_s for x in s])
    y = np.array([x.rate_B_rad_s[0] for x in s]) - rigid  # the flex part of the reading
    # Zero crossings (linear interpolation), both directions.
    idx = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
    tz = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    half_periods = np.diff(tz)
    zeta = DELTA / (2 * math.pi)
    fd = FREQ_HZ * math.sqrt(1 - zeta**2)
    assert 1.0 / (2 * half_periods.mean()) == pytest.approx(fd, rel=1e-4)
    # Peaks: amplitude ratio over one damped period -> decrement delta / sqrt(1 - zeta^2).
    pk = [i for i in range(1, len(y) - 1) if y[i] > y[i - 1] and y[i] >= y[i + 1] and y[i] > 0]
    amp = np.array([y[i] for i in pk])
    dec = np.log(amp[:-1] / amp[1:])
    assert dec.mean() == pytest.approx(DELTA / math.sqrt(1 - zeta**2), rel=2e-3)


def test_flex_excited_by_pulse_with_expected_amplitude() -> None:
    """Impulse I on the mode gives q' = b I right after (b = phi . (r x d) per newton)."""
    v = make_vehicle(flex_modes=FLEX)
    plant = Plant(v, step_s=0.001)
    plant.apply_command(0, 0.0, np.array([30, 0, 0, 0, 0, 0]))
    plant.apply_command(1, 0.2, np.zeros(6))
    plant.advance_to(0.2)
    # Energy-free check: the mode's velocity amplitude ~ b * impulse (pulse << period).
    b = 1.0e-2 * 1.0  # phi_x * (r x d)_x
    q, qd = plant.truth.flex_q[0], plant.truth.flex_qdot[0]
    w = 2 * math.pi * FREQ_HZ
    amp = math.hypot(qd, w * q)
    assert amp == pytest.approx(b * plant.truth.impulse_Ns[0], rel=0.05)


def _gyro_run(seed: int, faults=(), **gyro) -> list:
    cfg = {"noise_std_rad_s": 1e-5, "rate_hz": 10.0, "bias_walk_rad_s_sqrt_s": 1e-6}
    cfg.update(gyro)
    plant = Plant(make_vehicle(gyro=cfg), seed=seed, step_s=0.01)
    for f in faults:
        plant.inject(f)
    plant.apply_command(0, 0.0, np.array([100, 0, 0, 0, 50, 0]))
    plant.advance_to(3.0)
    return plant.gyro_samples_until(3.0)


def test_same_seed_same_gyro_sequence_different_seed_different() -> None:
    a, b, c = _gyro_run(7), _gyro_run(7), _gyro_run(8)
    assert a == b
    assert [s.rate_B_rad_s for s in a] != [s.rate_B_rad_s for s in c]
    assert [s.seq for s in a] == list(range(31))
    assert [s.t_meas_s for s in a] == pytest.approx([k * 0.1 for k in range(31)])


def test_latency_and_quantisation() -> None:
    s = _gyro_run(1, latency_ms=20.0, quantum_rad_s=1e-4)
    assert all(x.t_avail_s == pytest.approx(x.t_meas_s + 0.02) for x in s)
    assert s[-1].t_meas_s == pytest.approx(2.9)  # the 3.0 s sample is not out yet
    r = np.array([x.rate_B_rad_s for x in s])
    assert np.allclose(r / 1e-4, np.round(r / 1e-4), atol=1e-9)


def _rates_minus(a: list, b: list) -> np.ndarray:
    return np.array([np.subtract(x.rate_B_rad_s, y.rate_B_rad_s) for x, y in zip(a, b,
                                                                                 strict=True)])


def test_gyro_faults() -> None:
    base = _gyro_run(3, noise_std_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0)
    spike = _gyro_run(3, [FaultSpec(kind="gyro_spike", t_s=1.05, magnitude_rad_s=0.1, axis=2)],
                      noise_std_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0)
    diff = _rates_minus(spike, base)
    bad = np.flatnonzero(np.any(diff != 0, axis=1))
    assert bad.tolist() == [11]  # the first sample at or after 1.05 s, only that one
    assert diff[11] == pytest.approx([0, 0, 0.1])
    step = _gyro_run(3, [FaultSpec(kind="gyro_bias_step", t_s=1.0, clear_t_s=2.0,
                                   magnitude_rad_s=0.01)],
                     noise_std_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0)
    d = _rates_minus(step, base)
    assert np.allclose(d[10:20], 0.01) and np.allclose(d[:10], 0) and np.allclose(d[20:], 0)
    frozen = _gyro_run(3, [FaultSpec(kind="gyro_frozen", t_s=0.5)])
    assert len({x.rate_B_rad_s for x in frozen[5:]}) == 1
    assert frozen[5].rate_B_rad_s == frozen[4].rate_B_rad_s
    noisy = _gyro_run(3, [FaultSpec(kind="gyro_noise", t_s=0.0, magnitude_rad_s=1e-2)],
                      noise_std_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0)
    d = _rates_minus(noisy, base)
    assert 3e-3 < d.std() < 3e-2


def test_integrating_gyro_increments_sum_to_rotation_angle() -> None:
    """Seed 002 integrating gyro: the sum of increments = the rotation angle (single axis)."""
    v = make_vehicle(gyro={"kind": "integrating", "noise_std_rad_s": 0.0, "rate_hz": 5.0,
                           "quantum_rad_s": 1e-5})
    plant = Plant(v, step_s=0.01)
    plant.apply_command(0, 0.0, np.array([150, 0, 0, 0, 0, 0]))
    plant.advance_to(10.0)
    s = plant.gyro_samples_until(10.0)
    assert s[0].status.name == "NO_DATA" and all(x.status.name == "OK" for x in s[1:])
    total = np.sum([x.delta_angle_B_rad for x in s[1:]], axis=0)
    q = plant.truth.q_BO
    angle = 2 * math.atan2(q[1], q[0])  # rotation about x only
    assert total[0] == pytest.approx(angle, abs=1e-5 * 0.2)  # within one angle quantum
    assert s[-1].rate_B_rad_s[0] == pytest.approx(plant.truth.omega_B_rad_s[0], rel=1e-3)


def test_plant_is_deterministic_bit_for_bit() -> None:
    v = make_vehicle(flex_modes=FLEX, gyro={"noise_std_rad_s": 1e-5, "rate_hz": 5.0},
                     disturbance={"random_torque_std_Nm": 0.01})

    def once():
        p = Plant(v, seed=11, step_s=0.01)
        p.inject(FaultSpec(kind="stuck_on", t_s=1.0, thruster="Y+", fraction=0.5))
        rng = np.random.default_rng(0)
        for n in range(20):
            p.advance_to(n * 0.2)
            p.apply_command(n, n * 0.2 + 0.004, rng.choice([0, 30, 70, 200], 6))
        p.advance_to(4.0)
        return p.truth, p.gyro_samples_until(4.0)

    (t1, s1), (t2, s2) = once(), once()
    assert s1 == s2
    for name in ("q_BI", "omega_B_rad_s", "flex_q", "flex_qdot", "v_O_m_s", "impulse_Ns"):
        assert np.array_equal(getattr(t1, name), getattr(t2, name))


def test_core_modules_touch_no_clock_or_io() -> None:
    """docs/style.md habit 1: the plant core imports no clock, socket, thread or process module."""
    import ast
    from pathlib import Path

    import plant

    banned = {"time", "socket", "threading", "multiprocessing", "subprocess", "asyncio", "can"}
    for path in Path(plant.__file__).parent.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module.split(".")[0]]
            assert not banned & set(names), f"{path.name} imports {banned & set(names)}"
