"""The opposite isolation's own pairs and residual (issue 12, ``detector.isolation_opposite_deg``
and ``detector.isolation_raw``). On iss_rs P2+pitch_II and P2-pitch_II are 176.7 deg apart:
the detector's 2-deg opposite test does not pair them, so a stuck P2-pitch_II fought by
P2+pitch_II on every tick was named as P2+pitch_II failing. Paired, the adaptive observer's
residual still lost the leak within a few ticks (it takes the step in), and the probe read a
deficit; the gyro's raw residual keeps it.

Oracles: the angles between the thrusters' acceleration directions computed here with
``arccos``, and the plant's truth in the closed-loop run (the fault it was given).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flight.detector import STUCK_ON
from flight.software import FlightSoftware
from hil.config import AttitudeCfg, load_vehicle
from tests.flight.campaign_run import campaign_run


def test_the_isolation_pairs_thrusters_within_its_angle_of_opposite() -> None:
    v = load_vehicle("iss_rs")
    dc = v.flight.detector
    assert dc.isolation_opposite_deg is not None and dc.isolation_raw
    fs = FlightSoftware(v, initial_attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=0.0))
    mu = fs.arrays.mu_B_rad_s2
    e = mu / np.linalg.norm(mu, axis=1)[:, None]
    angle = np.degrees(np.arccos(np.clip(e @ e.T, -1.0, 1.0)))
    np.testing.assert_array_equal(fs._iso_opposite, angle >= 180.0 - dc.isolation_opposite_deg)
    # the detector's own pairs (burns together skip the commanded evidence) keep their angle
    np.testing.assert_array_equal(fs.detector.opposite, angle >= 180.0 - dc.same_direction_deg)
    names = list(fs.arrays.names)
    i, j = names.index("P2+pitch_II"), names.index("P2-pitch_II")
    assert fs._iso_opposite[i, j] and not fs.detector.opposite[i, j]


def test_a_stuck_thruster_fought_by_its_near_opposite_is_named(tmp_path: Path) -> None:
    """iss_rs-faults run 69: P2-pitch_II stuck on 100 % at 35.24 s. Named within about a
    second; with the detector's pairs and residual it was P2+pitch_II (fails to fire, then
    degraded after the probe) first."""
    quiet = {"pulse_test_below": "null"}  # the isolation alone (test pulses off)
    spec, sim = campaign_run(tmp_path, "iss_rs-faults", 69, quiet)
    d = sim.summary["detections"][0]
    assert d["thruster"] == spec.fault["thruster"] == "P2-pitch_II" and d["type"] == STUCK_ON
    assert d["t_s"] - spec.fault["t_s"] < 1.2
    _, off = campaign_run(tmp_path / "off", "iss_rs-faults", 69,
                          {**quiet, "isolation_opposite_deg": "null",
                           "isolation_raw": "false"})
    assert off.summary["detections"][0]["thruster"] == "P2+pitch_II"


def test_a_failing_orel_thruster_is_not_named_as_its_near_opposite_stuck(
        tmp_path: Path) -> None:
    """orel-fails run 198: thruster 10 fails to fire at 3.1 s and is commanded at once; 13 is
    3.5 deg from its opposite (the detector's 2-deg test does not pair them). Named right
    within 2 s of the fault; with the detector's pairs, 13 stuck on. Without orel's test
    pulses (with them, the pulses name 10 before either pairing is asked), and without the
    dead zone's flex-frequency term (with it and no pulses, 13 stuck on is named at 5.8 s;
    with both, the pulses name 10 at 6.2 s)."""
    quiet = {"pulse_test_below": "null", "flex_freq_dead_zone": "null"}
    spec, sim = campaign_run(tmp_path, "orel-fails", 198, quiet)
    assert spec.fault["kind"] == "fail_to_fire"
    d = sim.summary["detections"][0]
    assert d["thruster"] == spec.fault["thruster"] == "10" and d["type"] == "fail_to_fire"
    assert d["t_s"] - spec.fault["t_s"] < 2.0
    _, off = campaign_run(tmp_path / "off", "orel-fails", 198,
                          {**quiet, "isolation_opposite_deg": "null"})
    d = off.summary["detections"][0]
    assert (d["thruster"], d["type"]) == ("13", STUCK_ON)


def test_off_by_default() -> None:
    dc = load_vehicle("generic").flight.detector
    assert dc.isolation_opposite_deg is None and not dc.isolation_raw
