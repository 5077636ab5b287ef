"""The gyro's noise test through a fit of the thrusters' errors (``detector.gyro_noise_fit``;
kalman_cube and orel).

Oracles: by construction, the raw residual of a rate gyro with white noise of sigma is
``n(k) - n(k-1)`` plus the thrusters' errors; errors that are a fixed linear function of the
tick's regressors (a thruster's scale, direction and timing) are fitted out exactly, so the
leftover's lag-one autocovariance is ``sigma^2`` (its expected value), whatever the firing
pattern. A limit cycle that alternates opposite thrusters makes the raw residual's own lag-one
autocovariance read the errors, not the sensor (computed here directly: the lag test on the raw
residual has nothing to take them out with). A structure's ringing that an adaptive observer
follows is in the raw residual and not in the observer's innovation, which the test reads where
there is one. The closed loop: campaign runs whose truth the plant was given.
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.gyro_check import _FIT_TICKS, _FIT_WARMUP, _FIT_WINDOW, NOISE, GyroCheck
from tests.flight.campaign_run import campaign_run

SPEC = 1e-5  # kalman_cube's gyro noise_std_rad_s
LEVEL = 3.5 * SPEC  # kalman_cube's gyro_noise_fit x SPEC
START = 3  # the check's start-up ticks (suspect by design)
N_THR = 6


def _check(level: float | None = LEVEL, innovation: bool = False) -> GyroCheck:
    return GyroCheck(jump_rad_s=1.0, noise_floor_rad_s=np.sqrt(18) * SPEC,
                     fit_noise_rad_s=level, fit_innovation=innovation)


def _limit_cycle(n: int, seed: int) -> np.ndarray:
    """(n, 6) per-tick regressors of three opposite pairs firing in turn (a bang-bang limit
    cycle: the + thruster of a pair on one tick, the - one on the next), random widths."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n, N_THR))
    width = rng.uniform(0.05, 0.2, (n, 3))
    for k in range(n):
        for p in range(3):
            x[k, 2 * p + (k + p) % 2] = width[k, p]
    return x


def _samples(x: np.ndarray, seed: int, sensor: np.ndarray,
             error_rad_s: float = 10.0 * SPEC) -> np.ndarray:
    """Rate samples whose raw residual (model change 0) is ``n(k) - n(k-1) + E x(k) + c``:
    each thruster's fixed error vector ``E[:, j]`` (``error_rad_s`` per unit of its regressor,
    random direction: scale and direction errors), a constant torque ``c``, sensor noise
    ``sensor`` (3,) sigma."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((3, x.shape[1]))
    e *= error_rad_s / np.linalg.norm(e, axis=0) / 0.2
    c = 3.0 * SPEC * rng.standard_normal(3)
    true = np.cumsum(x @ e.T + c, axis=0)
    return 1e-3 + true + sensor * rng.standard_normal((len(x), 3))


def _run(chk: GyroCheck, ys: np.ndarray, x: np.ndarray,
         innovation: np.ndarray | None = None) -> list:
    return [chk.step(y, np.zeros(3), 1e-6, regressors=x[k],
                     innovation=None if innovation is None else innovation[k])
            for k, y in enumerate(ys)]


def test_the_fit_reads_the_sensor_where_the_raw_residual_reads_the_thrusters() -> None:
    """Thrusters' errors of 10 x SPEC per full tick in a limit cycle, the sensor at SPEC: the
    fit's level is the sensor's sigma (per axis, the square root of its mean square over
    windows within 10 % of sigma: the fit takes its unknowns' share of the noise out too, low
    by up to 8 % here); the raw residual's
    own lag-one level, which the lag test reads, is several times it."""
    x = _limit_cycle(4000, 1)
    ys = _samples(x, 2, np.full(3, SPEC))
    chk = _check(level=1.0)  # never named: only read the level
    levels = []
    for k, y in enumerate(ys):
        chk.step(y, np.zeros(3), 1e-6, regressors=x[k])
        if k > _FIT_WARMUP * _FIT_WINDOW:
            levels.append(chk.fit_lag2)
    assert np.sqrt(np.mean(levels, axis=0)) == pytest.approx(np.full(3, SPEC), rel=0.1)
    r = np.diff(ys, axis=0)
    raw = np.sqrt(np.abs(np.mean(r[1:] * r[:-1], axis=0)))
    assert raw.max() > 3.0 * SPEC, raw


def test_a_steady_sensor_is_never_noise() -> None:
    """The sensor at its specification under the limit cycle's errors, 10 seeds of 3,000
    ticks (10 min each): no noise named, no tick suspect."""
    for seed in range(10):
        x = _limit_cycle(3000, 10 + seed)
        v = _run(_check(), _samples(x, 30 + seed, np.full(3, SPEC)), x)
        assert not any(t.fault for t in v) and not any(t.suspect for t in v[START:]), seed


@pytest.mark.parametrize("factor", [4.0, 10.0])
def test_a_noise_increase_is_named_and_stays_suspect(factor) -> None:
    """Sensor noise up by ``factor`` on y from tick 600, 10 seeds: named NOISE on every seed,
    never before the increase, within one and a half windows and the dwell after it (the
    window must fill with noisy ticks), and suspect on every tick after the name."""
    for seed in range(10):
        x = _limit_cycle(900, 50 + seed)
        ys = _samples(x, 70 + seed, np.full(3, SPEC))
        rng = np.random.default_rng(90 + seed)
        ys[600:, 1] += SPEC * np.sqrt(factor**2 - 1.0) * rng.standard_normal(300)
        v = _run(_check(), ys, x)
        named = [k for k, t in enumerate(v) if t.fault]
        assert len(named) == 1 and v[named[0]].fault == NOISE, (seed, named)
        assert 600 + _FIT_TICKS <= named[0] <= 600 + 1.5 * _FIT_WINDOW + _FIT_TICKS, (seed, named)
        assert all(t.suspect for t in v[named[0]:]), seed
        assert not any(t.suspect for t in v[START:600]), seed


def test_a_bias_step_is_left_to_the_jump_tests() -> None:
    """A bias step of 30 x SPEC on x at tick 500 (one large residual tick): the fit's level
    rises for a few ticks, but it neither names noise nor makes a tick suspect before its
    dwell (the jump tests must see the ticks around a jump untouched)."""
    x = _limit_cycle(900, 5)
    ys = _samples(x, 6, np.full(3, SPEC))
    ys[500:, 0] += 30.0 * SPEC
    v = _run(_check(), ys, x)
    assert not any(t.fault for t in v) and not any(t.suspect for t in v[START:])


def test_the_fit_reads_the_adaptive_observer_innovation() -> None:
    """A 0.3 Hz ringing of 20 x SPEC on y in the samples (orel's roll and in-plane modes ring
    at 0.2-0.9 Hz), which an adaptive observer follows, and the sensor's noise up 4 times on y
    from tick 600, 10 seeds. Read on the innovation (``fit_innovation``; here the raw residual
    less the ringing's change) the noise is named after the increase and never before it; on
    the raw residual (the default, and what a check given the same innovation without the
    option reads) never (the ringing's ticks are correlated, so its lag-one level reads
    negative: not white)."""
    for seed in range(10):
        x = _limit_cycle(900, 150 + seed)
        ys = _samples(x, 170 + seed, np.full(3, SPEC))
        rng = np.random.default_rng(190 + seed)
        ys[600:, 1] += SPEC * np.sqrt(15.0) * rng.standard_normal(300)
        t = np.arange(len(ys)) * 0.2
        ring = np.zeros_like(ys)
        ring[:, 1] = 20.0 * SPEC * np.sin(2 * np.pi * 0.3 * t + seed)
        r_inn = np.diff(ys, axis=0)  # the residual of the samples without the ringing
        for chk in (_check(), _check(innovation=True)):
            v = _run(chk, ys[:1] + ring[:1], x[:1])  # the first tick: no previous sample
            v += _run(chk, (ys + ring)[1:], x[1:], innovation=r_inn)
            if not chk.fit_innovation:
                assert not any(q.fault for q in v), seed
        named = [k for k, q in enumerate(v) if q.fault]
        assert len(named) == 1 and v[named[0]].fault == NOISE, (seed, named)
        assert 600 + _FIT_TICKS <= named[0] <= 600 + 1.5 * _FIT_WINDOW + _FIT_TICKS, (seed, named)


def test_off_by_default() -> None:
    """Without the level (the other vehicles), no noise is read from the fit."""
    x = _limit_cycle(600, 7)
    ys = _samples(x, 8, np.array([SPEC, 10.0 * SPEC, SPEC]))
    v = _run(_check(level=None), ys, x)
    assert not any(t.fault for t in v)


@pytest.mark.parametrize("campaign, run", [("kalman_cube-gyro", 7), ("orel-gyro", 71)])
def test_a_noisy_gyro_is_named_as_the_gyro(tmp_path, campaign, run) -> None:
    """kalman_cube-gyro run 7: noise of 8.4e-5 rad/s (8.4 x its SPEC) on x from 40.2 s, the
    cube firing on every tick. orel-gyro run 71: noise of 3.5e-5 rad/s (7 x orel's 5e-6) on x
    from 5.2 s, through a slew and the hold after it, the flex modes ringing in the raw
    residual (read on the observer's innovation). Each named a gyro fault, and nothing else;
    without the fit test the same run names nothing (the oracle: the test can fail)."""
    spec, r = campaign_run(tmp_path, campaign, run)
    assert spec.fault["kind"] == "gyro_noise"
    dets = r.summary["detections"]
    assert [d["type"] for d in dets] == ["gyro_fault"], dets
    assert dets[0]["t_s"] > spec.fault["t_s"], dets
    _, r0 = campaign_run(tmp_path / "off", campaign, run, {"gyro_noise_fit": "null"})
    assert r0.summary["detections"] == [], r0.summary["detections"]


def test_an_orbit_correction_is_not_a_noisy_gyro(tmp_path, monkeypatch) -> None:
    """orel-burn run 0: a fault-free orbit correction, the front belt burning whole ticks from
    10 s to 117 s. No detection; with the burn's ticks given to the fit test, it names a gyro
    noise increase (the oracle: the exclusion is what keeps it quiet)."""
    import flight.software

    spec, r = campaign_run(tmp_path, "orel-burn", 0)
    assert spec.fault is None
    assert r.summary["detections"] == [], r.summary["detections"]
    monkeypatch.setattr(flight.software, "_FIT_SKIP_BURN", 2.0)
    _, r1 = campaign_run(tmp_path / "fed", "orel-burn", 0)
    assert [d["type"] for d in r1.summary["detections"]][:1] == ["gyro_fault"], \
        r1.summary["detections"]
