"""Test pulses (issue 12, ``DetectorCfg.pulse_test_below``): a thruster whose burn read short
is fired alone between two quiet ticks, and read on the raw residual against their mean.

Oracles: the thrust the synthetic residuals are built from (a linear drift of the rate, as a
slow structural mode gives over three ticks, cancels exactly); the fault the plant is given
(closed loop, one run of a shipped campaign in this process).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from flight.software import FlightSoftware
from hil.config import load_vehicle
from tests.flight.campaign_run import named_first_and_not_without


def _software(**detector) -> FlightSoftware:
    v = load_vehicle("orel")
    dc = v.flight.detector.model_copy(update=detector)
    v = v.model_copy(update={"flight": v.flight.model_copy(update={"detector": dc})})
    return FlightSoftware(v)


def _run_test(fs: FlightSoftware, j: int, theta: float, drift: np.ndarray,
              ticks: int, ring=lambda t: 0.0) -> list[np.ndarray]:
    """Drive ``fs``'s test of thruster ``j`` (actual thrust ``theta`` over nominal, the
    model's ``k`` 1) for ``ticks`` ticks: what the allocation commands each tick, and the raw
    residual of the next sample (the drift, ``ring(t)`` times ``j``'s acceleration, and the
    pulse's deficit)."""
    mu = fs.arrays.mu_B_rad_s2[j]
    fs.effectiveness.x[j] = 1.0
    fs._tick = 0
    fs._pulse_queue = [j]
    fs._pulse_next()
    commands = []
    for t in range(ticks):
        fs._tick = t
        # nothing to do for the controller: when the test ends, the allocation commands nothing
        fs._demand = SimpleNamespace(dw_down_B_rad_s=np.zeros(3), dw_up_B_rad_s=np.zeros(3))
        fs.stage_allocator()
        on = fs._on_ms.copy()
        commands.append(on)
        e = on[j] / 1000.0
        raw = drift * (t + 1) + ring(t) * mu + (theta - 1.0) * mu * e
        pred = SimpleNamespace(eff_s=np.where(np.arange(fs.n) == j, e, 0.0))
        fs._pulse_step(raw, pred, np.ones(fs.n, bool), raw, t + 1)
        if fs._pulse is None:
            break
    return commands


@pytest.mark.parametrize(("theta", "named"), [(0.0, True), (0.4, True), (0.72, False),
                                              (1.0, False)])
def test_a_pulse_between_quiet_ticks_reads_the_thrust_through_a_drift(theta, named) -> None:
    """A drift of the rate of 1e-4 rad/s a tick (a slow mode's slope, orel's dead zone) along
    every axis: the pulses read ``theta`` exactly; below 0.6 named with it, at the envelope's
    worst (0.72) or nominal not."""
    fs = _software(pulse_test_below=0.5)
    j = [t.name for t in fs.vehicle.thrusters].index("9")
    cmds = _run_test(fs, j, theta, np.full(3, 1e-4), 12)
    # quiet, quiet, pulse, quiet (, pulse, quiet): the thruster alone, for 100 ms
    assert [int(c.sum()) for c in cmds] == [0, 0, 100, 0, 100, 0][: len(cmds)]
    assert all(c[j] == c.sum() for c in cmds)
    if named:
        assert len(cmds) == 6 and fs._weak == j
        assert fs._pulse_frac == pytest.approx(theta, abs=1e-9)
    else:
        assert len(cmds) == 4 and fs._weak is None  # healthy on the first read
        assert fs._pulse_end[j] == 3


def test_a_pulse_between_quiet_samples_that_disagree_is_not_read() -> None:
    """A structure ringing along the thruster at a tick's period, its quiet samples before and
    after each pulse 1.2 pulses apart: no pulse is read, nothing is named though the thruster
    gives nothing, and the test ends without a verdict (the thruster may be tested again)."""
    fs = _software(pulse_test_below=0.5)
    j = [t.name for t in fs.vehicle.thrusters].index("9")
    cmds = _run_test(fs, j, 0.0, np.zeros(3), 20,
                     ring=lambda t: 0.1 * 0.6 * (1 if t % 4 < 2 else -1))
    assert fs._weak is None and fs._pulse is None
    assert j not in fs._pulse_end
    assert sum(int(c[j] > 0) for c in cmds) >= 2  # it pulsed, and read nothing


def test_pulse_length_is_whole_quanta_within_the_minimum_firing_and_the_tick() -> None:
    """At most the tick (200 ms) less the electrical delay (10) and the off lag (27), in
    whole 10 ms quanta: 160 ms."""
    assert _software(pulse_test_below=0.5, pulse_test_ms=100.0)._pulse_ms() == 100
    assert _software(pulse_test_below=0.5, pulse_test_ms=10.0)._pulse_ms() == 30
    assert _software(pulse_test_below=0.5, pulse_test_ms=500.0)._pulse_ms() == 160
    assert _software(pulse_test_below=0.5, pulse_test_ms=150.0)._pulse_ms() == 150
    assert _software(pulse_test_below=0.5, pulse_test_ms=75.0)._pulse_ms() == 70


def test_closed_loop_orel_fails_to_fire_commanded_on_four_ticks(tmp_path) -> None:
    """orel-fails run 244: 3 fails to fire at 8.9 s and the controller commands it on 4 ticks,
    in bursts with others: too few burns for the burn-fraction test (nothing named without
    the pulses); one burn read short, the pulses name it, fails to fire."""
    spec, det = named_first_and_not_without(tmp_path, "orel-fails", 244, "3", "fail_to_fire",
                                            12.0, off={"pulse_test_below": "null"})
    assert det["source"] == "pulse_test"


def test_closed_loop_orel_degraded_named_with_its_fraction(tmp_path) -> None:
    """orel-fails run 17: 9 degraded to 0.33 at 3.5 s, commanded on 4 ticks: named degraded by
    the pulses, the fraction within 0.1; nothing named without them."""
    spec, det = named_first_and_not_without(tmp_path, "orel-fails", 17, "9", "degraded",
                                            20.0, off={"pulse_test_below": "null"})
    assert det["source"] == "pulse_test"
    assert abs(det["fraction"] - spec.fault["fraction"]) < 0.1


@pytest.mark.parametrize(("theta", "pulses", "named"), [(0.5, 3, True), (0.8, 3, False),
                                                        (1.05, 1, False)])
def test_with_a_clear_level_the_test_judges_the_mean_of_its_reads(theta, pulses,
                                                                   named) -> None:
    """``pulse_test_clear`` 1.0 and three reads (iss_rs's setting): a read at 1.0 or above
    clears at once; below it the test goes on to three pulses and judges their mean against
    0.6 (a single read of 0.8, which clears with the default, does not end the test)."""
    fs = _software(pulse_test_below=0.5, pulse_test_count=3, pulse_test_clear=1.0)
    j = [t.name for t in fs.vehicle.thrusters].index("9")
    cmds = _run_test(fs, j, theta, np.full(3, 1e-4), 14)
    assert sum(int(c[j] > 0) for c in cmds) == pulses
    assert (fs._weak == j) is named
    if named:
        assert fs._pulse_frac == pytest.approx(theta, abs=1e-9)
    else:
        assert fs._pulse_end[j] == len(cmds) - 1


def test_closed_loop_iss_rs_degraded_suspected_from_its_small_burns(tmp_path) -> None:
    """iss_rs-fails run 73: SM+roll1_II degraded to 0.34 at 21.4 s; its burns are small (five
    summed chunks in 55 s), never 20 for the degraded tier nor 3 standard errors: nothing is
    named without the pulses. Its last four chunks average below half its thrust, it is
    tested, and the three pulses name it degraded with the fraction within 0.1."""
    spec, det = named_first_and_not_without(tmp_path, "iss_rs-fails", 73, "SM+roll1_II",
                                            "degraded", 38.0, off={"pulse_test_below": "null"})
    assert det["source"] == "pulse_test"
    assert abs(det["fraction"] - spec.fault["fraction"]) < 0.1


def test_closed_loop_iss_rs_fails_to_fire_suspected_from_its_small_burns(tmp_path) -> None:
    """iss_rs-fails run 182: P2-pitch_I fails to fire at 33.8 s; named fails to fire by the
    pulses within 10 s, nothing named in the run without them."""
    spec, det = named_first_and_not_without(tmp_path, "iss_rs-fails", 182, "P2-pitch_I",
                                            "fail_to_fire", 10.0,
                                            off={"pulse_test_below": "null"})
    assert det["source"] == "pulse_test"


@pytest.mark.parametrize(("fail_below", "kind"), [(None, "degraded"), (0.25, "fail_to_fire")])
def test_a_thruster_the_pulses_name_fails_to_fire_below_the_pulses_own_level(fail_below,
                                                                             kind) -> None:
    """Pulses that read 0.2: degraded against ``fail_fraction`` (0.15), failing against
    ``pulse_test_fail_below`` 0.25 (a dead thruster's three reads average up to 0.28 on
    iss_rs); the burn-fraction tiers' own findings keep ``fail_fraction``."""
    fs = _software(pulse_test_below=0.5, pulse_test_fail_below=fail_below)
    j = [t.name for t in fs.vehicle.thrusters].index("9")
    fs._pulse_frac = 0.2
    _, found = fs._weak_detection(j)
    assert (found.kind, found.source, found.fraction) == (kind, "pulse_test", 0.2)
    fs.effectiveness.x[j] = 0.2  # a tier's own finding at 0.2 (theta, no burns): degraded
    _, found = fs._weak_detection(j)
    assert (found.kind, found.source) == ("degraded", "effectiveness")
    assert found.fraction == pytest.approx(0.2)



def test_a_suspicion_level_without_the_suspicion_is_refused() -> None:
    """``pulse_test_suspect_below`` without ``pulse_test_suspect_burns`` would be accepted and
    ignored (the suspicion is off). The other pulse options stay accepted with
    ``pulse_test_below`` null: one setting switches the tests off."""
    from common.errors import ConfigError

    with pytest.raises(ConfigError, match=r"pulse_test_suspect_below: expected none without "
                                          r"pulse_test_suspect_burns.*got 0.7"):
        load_vehicle("generic", {"detector": {"pulse_test_below": 0.5,
                                              "pulse_test_suspect_below": 0.7}})
