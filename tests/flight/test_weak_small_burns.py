"""Small burns counted together (issue 12, ``flight.detector.DetectorCfg.weak_small_below``):
a thruster whose every burn moves the rate by less than twice the dead zone (iss_rs's SM roll
thrusters: 1.2-2.5e-6 rad/s a tick against 4e-6) is read by the burn-fraction test once
consecutive burns weigh as much as one measurable burn.

Oracles: the thrust the synthetic burns are built from; the size-weighted mean of the burns'
fractions computed here by hand.
"""

from __future__ import annotations

import numpy as np
import pytest

from common.vehicle import VehicleArrays
from flight.detector import Effectiveness
from hil.config import load_vehicle

H = 0.2


def _eff(chunk: bool) -> tuple[Effectiveness, np.ndarray, object]:
    v = load_vehicle("iss_rs")
    dc = v.flight.detector
    mu = VehicleArrays.from_vehicle(v).mu_B_rad_s2
    eff = Effectiveness(mu, bound=dc.effectiveness_bound, r_var=dc.dead_zone_rad_s**2, tick_s=H)
    eff.kept = max(eff.kept, dc.weak_burns)
    eff.chunk_small = chunk
    return eff, mu, v


@pytest.mark.parametrize("seed", range(3))
def test_a_small_thruster_that_fails_is_read_only_with_small_burns_counted(seed) -> None:
    """SM+roll2_I gives nothing, burning 40-70 ms on every tick (each burn a third of a
    measurable one), with the residual noise of a quiet gyro (3e-7 rad/s): named by the
    small-burn tier with the small burns counted, never without; at the envelope's worst
    (0.72) not named."""
    for chunk, theta_i, named_want in ((True, 0.0, True), (False, 0.0, False),
                                       (True, 0.72, False)):
        eff, mu, v = _eff(chunk)
        dc = v.flight.detector
        n = len(mu)
        i = [t.name for t in v.thrusters].index("SM+roll2_I")
        theta = np.full(n, 0.72)
        theta[i] = theta_i
        rng = np.random.default_rng(seed)
        use = np.ones(n, bool)
        named = set()
        for _ in range(300):
            e = np.zeros(n)
            e[i] = rng.uniform(0.04, 0.07)
            assert np.linalg.norm(mu[i] * e[i]) < 2.0 * dc.dead_zone_rad_s
            r = mu.T @ ((theta - eff.k) * e) + 3e-7 * rng.standard_normal(3)
            eff.update(r, e, use, raw_B_rad_s=r)
            j = eff.weak(dc.weak_small_below, dc.weak_sigma, dc.weak_burns, use, raw=True,
                         small=True)
            if j is not None:
                named.add(int(j))
        assert named == ({i} if named_want else set()), (chunk, theta_i, named)


def test_a_chunk_is_the_size_weighted_mean_of_its_burns() -> None:
    """Three small burns of known fractions, then enough to pass one measurable weight: the
    one burn kept is their size-weighted mean, on the innovation and on the raw residual."""
    eff, mu, v = _eff(True)
    n = len(mu)
    i = [t.name for t in v.thrusters].index("SM+roll2_I")
    use = np.ones(n, bool)
    one = 4.0 * eff.r_var
    w_sum = wf = wr = 0.0
    sizes = [0.05, 0.04, 0.07, 0.06, 0.05, 0.07, 0.04, 0.06, 0.05, 0.07]
    for k, s in enumerate(sizes):
        fi, fr = 0.1 * k, 0.2 - 0.05 * k
        e = np.zeros(n)
        e[i] = s
        phi = mu[i] * s
        w = float(phi @ phi)
        k = eff.k[i]  # the fraction is read against the scale the model used this tick
        eff.update(phi * (fi - k), e, use, raw_B_rad_s=phi * (fr - k))
        w_sum, wf, wr = w_sum + w, wf + w * fi, wr + w * fr
        if w_sum >= one:
            break
    else:
        pytest.fail("the burns never weighed one measurable burn")
    assert eff._recent[i] == [] and len(eff._chunks[i]) == 1 and len(eff._chunks_raw[i]) == 1
    assert eff._chunks[i][0][1] == pytest.approx(wf / w_sum, rel=1e-9)
    assert eff._chunks_raw[i][0][1] == pytest.approx(wr / w_sum, rel=1e-9)


def test_closed_loop_iss_rs_small_thruster_failing_is_named(tmp_path) -> None:
    """iss_rs-fails run 58: SM+roll2_I fails to fire at 5.5 s and is commanded 40-80 ms on
    nearly every tick after it, each burn under the 4e-6 rad/s that makes one measurable.
    Named fails to fire by the small-burn tier within 20 s; without the tier nothing is named
    in the run (the oracle: the tier can fail)."""
    from tests.flight.campaign_run import named_first_and_not_without

    named_first_and_not_without(tmp_path, "iss_rs-fails", 58, "SM+roll2_I", "fail_to_fire", 20.0,
                                off={"weak_small_below": "null"})


def test_closed_loop_iss_rs_small_thruster_degraded_is_named_with_its_fraction(tmp_path) -> None:
    """iss_rs-fails run 27 (test pulses off): SM+roll2_II degraded to 0.36 at 33.4 s, its burns
    all small. Named degraded by the degraded tier over the measurable and summed burns within
    20 s, its fraction within 0.1 of the fault's; without that tier nothing is named in the
    run."""
    from tests.flight.campaign_run import named_first_and_not_without

    spec, first = named_first_and_not_without(tmp_path, "iss_rs-fails", 27, "SM+roll2_II",
                                              "degraded", 20.0,
                                              off={"weak_degraded_below": "null"},
                                              on={"pulse_test_below": "null"})
    assert abs(first["fraction"] - spec.fault["fraction"]) < 0.1, first
