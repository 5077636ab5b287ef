"""A held jump is named a gyro fault (spike, bias step) only when the observer's one-step
prediction missed it too (flight.gyro_check._observer_surprised).

Oracle, by construction: the raw residual is the measured rate change minus the onboard
model's rigid increment; a flex mode ringing off that rigid prediction puts its swing into the
raw residual while an observer that follows the mode predicts it (small innovation), and its
swing back to zero a tick later looks like "a jump followed by nothing". A sensor's step is
news to every estimator: the innovation carries all of it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from flight.gyro_check import _INNOVATION_SHARE, BIAS_STEP, SPIKE, GyroCheck
from tests.flight.campaign_run import campaign_run

NOISE_STD = 5e-6


def _run(jump: np.ndarray, innovation_share: float, after: np.ndarray,
         swing: np.ndarray | None = None) -> list:
    """40 quiet ticks of noise, then a tick whose residual is ``jump`` with an innovation of
    ``innovation_share`` of it, then a tick whose residual is ``after``; ``swing``: the raw
    residual of the last 10 quiet ticks swings by +/- it (a mode ringing while the observer's
    innovation stays at noise level)."""
    rng = np.random.default_rng(3)
    chk = GyroCheck(jump_rad_s=5e-4, noise_floor_rad_s=np.sqrt(18) * NOISE_STD)
    y = np.full(3, 1e-4)
    out = []
    for k in range(40):
        y = y + NOISE_STD * rng.standard_normal(3) * 0.1
        if swing is not None and k >= 30:
            y = y + swing * (1 if k % 2 else -1)
        out.append(chk.step(y.copy(), np.zeros(3), 0.0, np.zeros((4, 3)),
                            NOISE_STD * rng.standard_normal(3)))
    y = y + jump
    out.append(chk.step(y.copy(), np.zeros(3), 0.0, np.zeros((4, 3)), innovation_share * jump))
    y = y + after + NOISE_STD * rng.standard_normal(3) * 0.1  # a live sensor never repeats
    out.append(chk.step(y.copy(), np.zeros(3), 0.0, np.zeros((4, 3)), after))
    return out


@pytest.mark.parametrize("share", [1.0, 0.8, _INNOVATION_SHARE + 0.01])
def test_a_step_the_observer_did_not_predict_is_a_bias_step(share: float) -> None:
    out = _run(np.array([0.0, 8e-4, 0.0]), share, np.zeros(3))
    assert out[-2].hold and out[-1].fault == BIAS_STEP


@pytest.mark.parametrize("share", [1.0, 0.7])
def test_a_spike_the_observer_did_not_predict_is_a_spike(share: float) -> None:
    jump = np.array([6e-4, -6e-4, 0.0])
    out = _run(jump, share, -jump)
    assert out[-1].fault == SPIKE


@pytest.mark.parametrize("share", [0.04, 0.2, _INNOVATION_SHARE - 0.01, -0.3])
def test_a_swing_the_observer_predicted_is_held_and_dropped_without_a_name(share: float) -> None:
    """orel-envelope run 70, tick 106: raw residual 6.0e-4 rad/s on pitch, the adaptive
    observer's innovation 0.26e-4 (4 %), the next tick's raw residual 0.5e-4: named a bias
    step before. Now held (kept out of the thruster evidence), dropped, and never named."""
    out = _run(np.array([0.0, 6.0e-4, 0.0]), share, np.array([0.0, 0.5e-4, 0.0]))
    assert out[-2].hold
    assert out[-1].fault is None and out[-1].drop_previous
    assert all(v.fault is None for v in out)


def test_without_an_innovation_every_unexplained_step_is_named_as_before() -> None:
    chk = GyroCheck(jump_rad_s=5e-4, noise_floor_rad_s=np.sqrt(18) * NOISE_STD)
    y = np.full(3, 1e-4)
    for k in range(10):
        chk.step(y + 1e-7 * (k % 2), np.zeros(3), 0.0)
    chk.step(y + np.array([0.0, 8e-4, 0.0]), np.zeros(3), 0.0)
    v = chk.step(y + np.array([1e-7, 8e-4, 0.0]), np.zeros(3), 0.0)
    assert v.fault == BIAS_STEP


@pytest.mark.parametrize("run", [70, 187])
def test_orel_array_ringing_is_not_named_a_gyro_bias_step(run: int) -> None:
    """orel-envelope runs 70 and 187 (fault-free; in-plane mode at 0.92 Hz, 1.15 times its
    ground estimate): named a gyro bias step at 21.4 and 27.4 s before; nothing now."""
    with tempfile.TemporaryDirectory() as tmp:
        _, sim = campaign_run(Path(tmp), "orel-envelope", run)
    assert sim.summary["detections"] == []


def test_a_jump_out_of_a_swinging_raw_residual_is_no_bias_step() -> None:
    """orel-envelope-3 run 365 (fault-free; roll mode at 1.33 times its prior, not yet followed
    by the observer): the raw residual swung 5-9e-4 rad/s along the jump on the ticks before
    it while the innovation was quiet, then a 1.4e-3 jump the innovation carried (1.1e-3) and
    0.3e-3 after: named a bias step at 6.6 s before. Here: a 4.5e-4 swing (under the jump
    threshold), a 1.0e-3 jump, 0.2e-3 after. A sensor's step comes out of a calm raw
    residual as well as a calm innovation; out of a swing it is held, dropped and not named.
    The same jump out of a calm raw residual (the oracle) is a bias step."""
    jump = np.array([0.0, 1.0e-3, 0.0])
    out = _run(jump, 0.8, 0.2 * jump, swing=np.array([0.0, 4.5e-4, 0.0]))
    assert out[-2].hold
    assert all(v.fault is None for v in out)
    assert _run(jump, 0.8, 0.2 * jump)[-1].fault == BIAS_STEP


def test_orel_held_out_run_365_names_no_gyro_fault() -> None:
    """orel-envelope-3 run 365 (fault-free): a gyro bias step named at 6.6 s before the raw
    residual had to be calm too; nothing now."""
    with tempfile.TemporaryDirectory() as tmp:
        _, sim = campaign_run(Path(tmp), "orel-envelope-3", 365)
    assert sim.summary["detections"] == []
