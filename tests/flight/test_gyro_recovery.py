"""After a gyro fault: the jump into a frozen output is not thruster evidence, and the thruster
evidence restarts with the estimators and waits for them to settle.

Oracles: synthetic samples whose truth is known by construction (a live sensor never repeats
its sample exactly on three axes; the jump into the freeze is the sensor's); the closed loop
against what the plant was given (kalman_cube-gyro runs with a frozen gyro and no thruster
fault, which named a thruster after the freeze before).
"""

from __future__ import annotations

import numpy as np

from flight.gyro_check import FROZEN, GyroCheck

NOISE_STD = 5e-6


def _quiet(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 1e-4 + NOISE_STD * rng.standard_normal((n, 3))


def test_the_jump_into_a_frozen_output_is_dropped_not_committed() -> None:
    """An integrating gyro's counter stops at tick 20: the sample falls to exact zeros (a jump
    of the whole rate, held as unexplained), then repeats. The held jump is dropped on the
    first repeat (never evidence) and the freeze named on the second."""
    ys = _quiet(40)
    ys[20:] = 0.0
    chk = GyroCheck(jump_rad_s=1e-5, noise_floor_rad_s=np.sqrt(18) * NOISE_STD)
    v = [chk.step(y, np.zeros(3), 0.0) for y in ys]
    assert v[20].hold and v[20].suspect
    assert v[21].drop_previous and v[21].suspect and v[21].fault is None
    assert v[22].fault == FROZEN
    assert [k for k, x in enumerate(v) if x.fault] == [22]


def test_a_jump_a_failing_thruster_explained_taints_the_evidence_when_the_output_freezes() -> None:
    """The jump into the freeze is what one thruster failing to fire would give (it was evidence
    at once): the first repeat taints that tick (the evidence restarts)."""
    u = np.zeros((40, 1, 3))
    u[:, 0, 0] = 3e-4  # one thruster commanded every tick, +x
    # the model expects +3e-4 a tick; at tick 20 the output stops moving along x (last live
    # sample), from tick 21 it repeats tick 20's exactly
    ys = 1e-4 + np.cumsum(np.full(40, 3e-4))[:, None] * np.array([1.0, 0.0, 0.0]) \
        + NOISE_STD * np.random.default_rng(2).standard_normal((40, 3))
    ys[20, 0] = ys[19, 0] + NOISE_STD
    ys[21:] = ys[20]
    chk = GyroCheck(jump_rad_s=1e-4, noise_floor_rad_s=np.sqrt(18) * NOISE_STD)
    v = [chk.step(ys[k], u[k].sum(axis=0), 3e-4, u[k]) for k in range(40)]
    # tick 20: the residual is -3e-4 along the thruster, its failure explains it: evidence now
    assert not v[20].suspect and v[20].defer_learning
    assert v[21].taint_previous and v[21].suspect and v[21].fault is None
    assert v[22].fault == FROZEN


def _campaign_run(tmp_path, campaign: str, run: int):
    from hil.campaign.expansion import expand_run, write_run
    from hil.campaign.load import load_campaign
    from hil.config import CONFIG_DIR
    from hil.sim import simulate

    spec = expand_run(load_campaign(CONFIG_DIR / "campaigns" / f"{campaign}.yaml"), run)
    return spec, simulate(write_run(spec, tmp_path))


def test_no_thruster_is_named_after_a_freeze(tmp_path) -> None:
    """kalman_cube-gyro runs 6 and 18: the output frozen for 4.7 and 2.5 s, no thruster fault.
    Before these changes run 18 named Y- stuck on 1.8 s after the output came back (the jump
    into the freeze committed as evidence), run 6 Z+ by the Kalman leak test 1.0 s after (the
    filter restarted on the first live sample while the craft was turning). Now: the freeze
    alone."""
    for run in (6, 18):
        spec, r = _campaign_run(tmp_path / str(run), "kalman_cube-gyro", run)
        assert spec.fault["kind"] == "gyro_frozen"
        assert [(d["type"], d["thruster"]) for d in r.summary["detections"]] == [
            ("gyro_fault", None)], (run, r.summary["detections"])
