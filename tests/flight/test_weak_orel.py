"""orel's burn-fraction test (issue 12, ``flight.detector.DetectorCfg.weak_below``): a thruster
that fails to fire while the controller pulses it on many ticks, each deficit inside the
relative dead zone that the other thrusters' burns in the same ticks widen, is named.

Oracles: the thrust the synthetic burns are built from; the fault the plant is given (closed
loop, one run of a shipped campaign in this process).
"""

from __future__ import annotations

import numpy as np
import pytest

from common.vehicle import VehicleArrays
from flight.detector import Effectiveness
from hil.config import load_vehicle
from tests.flight.campaign_run import campaign_run, named_first_and_not_without

H = 0.2
# The closed loops read the burn-fraction test itself: without orel's test pulses, which judge
# what it names (docs/design.md 6.5; tests/flight/test_pulse_test.py).
NO_PULSES = {"pulse_test_below": "null"}


def _named(theta: np.ndarray, n_ticks: int, seed: int) -> set[int]:
    """orel's thrusters pulsing at random with actual thrust ``theta`` (over nominal) and the
    gyro-size noise of the residual; every thruster orel's test names over ``n_ticks``."""
    v = load_vehicle("orel")
    dc = v.flight.detector
    mu = VehicleArrays.from_vehicle(v).mu_B_rad_s2
    n = len(mu)
    rng = np.random.default_rng(seed)
    eff = Effectiveness(mu, bound=dc.effectiveness_bound, r_var=dc.dead_zone_rad_s**2, tick_s=H,
                        common_share=dc.effectiveness_common_share)
    eff.kept = max(eff.kept, dc.weak_burns)
    named = set()
    use = np.ones(n, bool)
    for _ in range(n_ticks):
        e = np.where(rng.random(n) < 0.15, rng.uniform(0.03, H, n), 0.0)
        r = mu.T @ ((theta - eff.k) * e) + 3e-5 * rng.standard_normal(3)
        eff.update(r, e, use)
        j = eff.weak(dc.weak_below, dc.weak_sigma, dc.weak_burns, use)
        if j is not None:
            named.add(int(j))
    return named


@pytest.mark.parametrize("seed", range(3))
def test_a_thruster_that_fails_to_fire_is_named_and_none_at_the_envelope_edge(seed) -> None:
    """Thruster 20 gives nothing: named, and only it. Every thruster at the envelope's worst
    (0.85 x 0.85 = 0.72, DESIGN 10): none named in 600 ticks."""
    v = load_vehicle("orel")
    assert v.flight.detector.weak_below is not None
    i = [t.name for t in v.thrusters].index("20")
    theta = np.full(len(v.thrusters), 0.72)
    theta[i] = 0.0
    assert _named(theta, 300, seed) == {i}
    assert _named(np.full(len(v.thrusters), 0.72), 600, seed + 10) == set()


def test_closed_loop_orel_fails_to_fire_pulsed_inside_the_dead_zone(tmp_path) -> None:
    """orel-fails run 278: 20 fails to fire at 13.9 s; the controller pulses it for 27 ms on
    most ticks while 10 burns the whole tick, so each deficit (3.7e-4 rad/s) lies inside the
    relative dead zone (2.2e-3). Named fails to fire within 5 s; with the test off nothing is
    named in the run (the oracle: the test can fail)."""
    named_first_and_not_without(tmp_path, "orel-fails", 278, "20", "fail_to_fire", 5.0,
                                off={"weak_below": "null", "weak_degraded_below": "null"},
                                on=NO_PULSES)


def test_the_raw_burns_must_fall_short_too() -> None:
    """``weak_raw``: a thruster whose innovation reads a deficit while the raw residual shows
    its burns whole (the adaptive observer lending an earlier deficit to the next thruster
    fired along it: orel-faults run 55) is not named; short on both, it is."""
    v = load_vehicle("orel")
    dc = v.flight.detector
    assert dc.weak_raw
    mu = VehicleArrays.from_vehicle(v).mu_B_rad_s2
    n = len(mu)
    use = np.ones(n, bool)
    rng = np.random.default_rng(7)
    i = [t.name for t in v.thrusters].index("15")
    for raw_short in (False, True):
        eff = Effectiveness(mu, bound=dc.effectiveness_bound, r_var=dc.dead_zone_rad_s**2,
                            tick_s=H)
        eff.kept = max(eff.kept, dc.weak_burns)
        got_eps, got_both = set(), set()
        for _ in range(3 * dc.weak_burns):
            e = np.zeros(n)
            e[i] = 0.05
            short = -mu[i] * eff.k[i] * e[i] + 1e-5 * rng.standard_normal(3)
            whole = 1e-5 * rng.standard_normal(3)
            eff.update(short, e, use, raw_B_rad_s=short if raw_short else whole)
            for out, raw in ((got_eps, False), (got_both, True)):
                j = eff.weak(dc.weak_below, dc.weak_sigma, dc.weak_burns, use, raw=raw)
                if j is not None:
                    out.add(int(j))
        assert got_eps == {i}
        assert got_both == ({i} if raw_short else set())


def test_closed_loop_no_burn_fraction_names_during_an_orbit_correction(tmp_path,
                                                                      monkeypatch) -> None:
    """orel-burn-faults run 14 (5 degraded at 72.7 s, never commanded after it): no thruster is
    named. With the test reading the burn too, a healthy middle-belt 23, holding the attitude
    against the burn's residual torque on every tick, was named failing at 19.6 s (the oracle:
    the test can fail)."""
    import flight.software

    spec, r = campaign_run(tmp_path, "orel-burn-faults", 14)
    assert (spec.fault["kind"], spec.fault["thruster"]) == ("degraded", "5")
    assert r.summary["detections"] == [], r.summary["detections"]
    monkeypatch.setattr(flight.software.FlightSoftware, "_burn_settling", lambda self: False)
    _, r0 = campaign_run(tmp_path / "on", "orel-burn-faults", 14)
    first = r0.summary["detections"][0]
    assert (first["thruster"], first["type"]) == ("23", "fail_to_fire"), r0.summary["detections"]
    assert first["t_s"] < spec.fault["t_s"]


@pytest.mark.parametrize("seed", range(3))
def test_the_degraded_tier_names_a_thruster_at_half_thrust_with_its_fraction(seed) -> None:
    """``weak_degraded_below``: thruster 20 at 0.45 of nominal, every other at the envelope's
    worst (0.72): 20 alone is named by the second tier, and the mean of the burns it read is
    within 0.1 of 0.45; at 0.72 everywhere, nothing in 600 ticks."""
    v = load_vehicle("orel")
    dc = v.flight.detector
    assert dc.weak_degraded_below is not None
    mu = VehicleArrays.from_vehicle(v).mu_B_rad_s2
    n = len(mu)
    i = [t.name for t in v.thrusters].index("20")
    for theta_i, want in ((0.45, {i}), (0.72, set())):
        theta = np.full(n, 0.72)
        theta[i] = theta_i
        rng = np.random.default_rng(seed)
        eff = Effectiveness(mu, bound=dc.effectiveness_bound, r_var=dc.dead_zone_rad_s**2,
                            tick_s=H, common_share=dc.effectiveness_common_share)
        eff.kept = max(eff.kept, dc.weak_degraded_burns)
        use = np.ones(n, bool)
        named, fractions = set(), []
        for _ in range(600):
            e = np.where(rng.random(n) < 0.15, rng.uniform(0.03, H, n), 0.0)
            r = mu.T @ ((theta - eff.k) * e) + 3e-5 * rng.standard_normal(3)
            eff.update(r, e, use, raw_B_rad_s=r)
            assert eff.weak(dc.weak_below, dc.weak_sigma, dc.weak_burns, use, raw=True) is None
            j = eff.weak(dc.weak_degraded_below, dc.weak_sigma, dc.weak_degraded_burns, use,
                         raw=True)
            if j is not None:
                named.add(int(j))
                fractions.append(eff.burn_mean(int(j), dc.weak_degraded_burns))
        assert named == want
        if want:
            assert abs(fractions[0] - 0.45) < 0.1, fractions[0]


def test_closed_loop_orel_degraded_named_by_the_second_tier(tmp_path) -> None:
    """orel-fails run 143: 12 degraded to 0.58 at 14.1 s, pulsed beside full burns. Named
    degraded by the second tier within 10 s, its fraction within 0.1 of the fault's; with the
    tier off nothing is named in the run (the oracle: the tier can fail)."""
    spec, first = named_first_and_not_without(tmp_path, "orel-fails", 143, "12", "degraded",
                                              10.0, off={"weak_degraded_below": "null"},
                                              on=NO_PULSES)
    assert abs(first["fraction"] - spec.fault["fraction"]) < 0.1, first


def test_closed_loop_the_degraded_tier_reads_nothing_of_the_initial_slew(tmp_path) -> None:
    """orel-stuck run 116 (27 stuck on at 12.5 s): nothing is named before the fault. With
    the tier reading the initial slew's burns too (``weak_degraded_after_s: 0``), a healthy
    14 is named degraded at 8.8 s (the oracle: the guard can fail)."""
    spec, r = campaign_run(tmp_path, "orel-stuck", 116, NO_PULSES)
    t_fault = spec.fault["t_s"]
    assert not [d for d in r.summary["detections"] if d["t_s"] < t_fault], r.summary
    _, r0 = campaign_run(tmp_path / "all", "orel-stuck", 116,
                         detector={**NO_PULSES, "weak_degraded_after_s": 0.0})
    first = r0.summary["detections"][0]
    assert (first["thruster"], first["type"]) == ("14", "degraded"), r0.summary["detections"]
    assert first["t_s"] < t_fault
