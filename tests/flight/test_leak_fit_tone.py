"""The leak fits beside the observer's flex tones (``detector.leak_fit_tone``, iss_rs).

Pulsing in step with a flex tone (S003-flex's programme of turns) leaves the tone's ringing on
the quiet ticks at the same few phases of its period, so their mean is not zero and a leak's
fit takes it in. With the tones the adaptive observer identifies fitted beside the leak (a sine
and a cosine per axis at each), the ringing is no leak, and a real leak stays one.

Oracles: the synthetic window's own truth (a tone of known frequency, a leak of known size),
``numpy.linalg.lstsq`` of the leak alone on the same ticks (the fit the test guards), and
``scipy.stats`` for the leak-alone fit's significance.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from flight.software import FlightSoftware
from hil.config import AttitudeCfg, load_vehicle

H = 0.2
NOISE = 2.8e-7  # iss_rs's tick-to-tick gyro noise (sqrt(2) x 2e-7 rad/s)


def _flight(tone: bool) -> FlightSoftware:
    fs = FlightSoftware(load_vehicle("iss_rs", {"detector": {"leak_fit_tone": tone}}),
                        initial_attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=0.0))
    # the observer's identified tones: torsion on roll, bending on yaw and pitch (iss_rs.yaml)
    fs.observer.freq_hz = lambda: np.array([0.31, 0.16, 0.16])
    return fs


def _window(fs: FlightSoftware, j: int, leak: float, seed: int):
    """A long window whose quiet ticks lie only at the phases that pulsing in step with the
    0.16 Hz bending tone leaves quiet (the first 40 % of each period), with the tone's change
    per tick along thruster j's direction (its yaw and pitch, where the tone rings), noise,
    and thruster j's leak of ``leak`` of its thrust."""
    rng = np.random.default_rng(seed)
    mu = fs.arrays.mu_B_rad_s2
    var = (fs.detector.dead_zone_rad_s() / 3.0) ** 2
    f, amp = 0.16, 1.5e-5
    u = mu[j] / np.linalg.norm(mu[j])
    rows = []
    k = 0
    while len(rows) < fs.detector.cfg.leak_fit_long_ticks:
        t = k * H
        quiet = (t * f + 0.3) % 1.0 < 0.6
        eff = np.zeros(fs.n)
        if not quiet:
            eff[(k * 7) % fs.n] = H
        ring = amp * (np.sin(2 * np.pi * f * t) - np.sin(2 * np.pi * f * (t - H)))
        raw = NOISE * rng.standard_normal(3) + ring * u
        raw = raw + leak * mu[j] * (H - eff[j])
        rows.append((raw, eff, var, k))
        k += 1
    fs._leak_window.extend(rows)
    return rows, mu


def _long(fs: FlightSoftware):
    det = None
    for _ in range(fs.detector.cfg.leak_fit_hold):
        det = fs._leak_fit_long(fs.fdir.available) or det
    return det


@pytest.mark.parametrize("seed", range(3))
def test_a_tone_rung_in_step_is_a_leak_to_the_fit_alone_and_none_beside_the_tones(
        seed: int) -> None:
    fs = _flight(tone=False)
    j = list(fs.arrays.names).index("SM+roll2_I")
    rows, mu = _window(fs, j, 0.0, seed)
    # the trap: on the quiet ticks the ringing's mean along the roll thruster is far from 0
    quiet = [r for r in rows if not r[1].any()]
    x = np.concatenate([H * mu[j] for _ in quiet])
    y = np.concatenate([r[0] for r in quiet])
    c = float(x @ y / (x @ x))
    resid = y - c * x
    se = float(np.sqrt(resid @ resid / (len(y) - 1) / (x @ x)))
    assert stats.norm.sf(c / se) < 1e-9 and c > 0.08
    named = _long(fs)
    assert named is not None and named.thruster == j       # the leak alone names it
    fs2 = _flight(tone=True)
    _window(fs2, j, 0.0, seed)
    assert _long(fs2) is None                               # beside the tones: nothing


@pytest.mark.parametrize("seed", range(3))
def test_a_leak_stays_a_leak_beside_the_tones(seed: int) -> None:
    fs = _flight(tone=True)
    j = list(fs.arrays.names).index("SM+roll2_I")
    _window(fs, j, 0.3, seed)
    det = _long(fs)
    assert det is not None and det.thruster == j and det.rho == pytest.approx(0.3, abs=0.1)


@pytest.mark.parametrize("seed", range(3))
def test_a_leak_beside_tones_ringing_at_every_phase_is_named_as_by_the_fit_alone(
        seed: int) -> None:
    """Quiet ticks at every phase of the tone (pulses on a random third of the ticks): the
    joint fit leaves a 30 % leak its size, so the check keeps the leak-alone fit's finding
    (whose significance it does not re-test: the tones' twelve parameters would widen it).
    Oracle: the same window through the fit without the check, and the leak's truth."""
    rng = np.random.default_rng(100 + seed)
    found = []
    for tone in (False, True):
        fs = _flight(tone=tone)
        j = list(fs.arrays.names).index("SM+roll2_I")
        mu = fs.arrays.mu_B_rad_s2
        var = (fs.detector.dead_zone_rad_s() / 3.0) ** 2
        noise = np.random.default_rng(seed)
        busy = rng.random(fs.detector.cfg.leak_fit_long_ticks) < 1 / 3
        u = mu[j] / np.linalg.norm(mu[j])
        for k, b in enumerate(busy):
            t = k * H
            eff = np.zeros(fs.n)
            if b:
                eff[(k * 7) % fs.n] = H
            ring = 5e-6 * (np.sin(2 * np.pi * 0.16 * t) - np.sin(2 * np.pi * 0.16 * (t - H)))
            raw = NOISE * noise.standard_normal(3) + ring * u + 0.3 * mu[j] * (H - eff[j])
            fs._leak_window.append((raw, eff, var, k))
        found.append(_long(fs))
        rng = np.random.default_rng(100 + seed)  # the same pulses for the second flight
    alone, beside = found
    assert alone is not None and alone.thruster == j
    assert beside is not None and beside.thruster == j
    assert beside.rho == pytest.approx(alone.rho, abs=0.05)
    assert beside.rho == pytest.approx(0.3, abs=0.05)


def test_the_rigid_observer_has_no_tones_to_fit() -> None:
    fs = FlightSoftware(load_vehicle("iss_rs", {"detector": {"leak_fit_tone": True},
                                                "observer": {"kind": "rigid"}}),
                        initial_attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=0.0))
    j = list(fs.arrays.names).index("SM+roll2_I")
    rows, _ = _window(fs, j, 0.0, 0)
    s = np.array([H if not r[1].any() else 0.0 for r in rows])
    assert fs._beside_tones(np.zeros((len(rows), 3)), s, j, np.ones(len(rows)),
                            [r[3] for r in rows], 0.5) == 0.0
