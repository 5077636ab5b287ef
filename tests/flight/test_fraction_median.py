"""The thrust fraction a fails-to-fire or degraded detection names is the median of the
thruster's last burns, not their mean (``Effectiveness.fraction``, ``fraction_since``).

Oracles: the burns' own fractions given here (one burn that straddles the fault, with most of
its thrust delivered, among burns after it); the closed loop against what the plant was given
(a thruster that fails to fire, named so, where the mean named it degraded).
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.detector import _FRACTION_TICKS, Effectiveness
from tests.flight.campaign_run import campaign_run

MU = np.array([[0.005, 0, 0], [-0.005, 0, 0], [0, 0.0075, 0], [0, -0.0075, 0],
               [0, 0, 0.01], [0, 0, -0.01]])
FAIL_FRACTION = 0.15  # DetectorCfg.fail_fraction's default


def _eff(burns: list[float]) -> Effectiveness:
    eff = Effectiveness(MU, bound=0.3, r_var=1e-4**2, tick_s=0.2)
    eff._recent[4] = [(k, f) for k, f in enumerate(burns)]
    return eff


@pytest.mark.parametrize("burns, want, mean_named_degraded", [
    ([1.03, 0.97, 1.04, 0.81, 0.11, -0.15], 0.11, True),  # kalman_cube-faults run 31
    ([1.0, 1.1, 1.02, 0.0, 0.07, 0.22], 0.07, False),      # generic-faults run 37
    ([1.0, 0.98, 0.95, 0.5, 0.47, 0.55], 0.5, False),      # degraded to about half
    ([1.0, 0.5, 0.52], 0.52, False),                       # the straddling burn at its mean
])
def test_the_fraction_is_the_median_of_the_last_burns(burns, want, mean_named_degraded) -> None:
    eff = _eff(burns)
    last = burns[-_FRACTION_TICKS:]
    assert eff.fraction[4] == pytest.approx(float(np.median(last))) == pytest.approx(want)
    assert eff.fraction_since(4, len(burns) - 3) == pytest.approx(want)
    # the kind it gives: a failed thruster stays under fail_fraction with one straddling burn
    assert (want < FAIL_FRACTION) == (np.median(last) < FAIL_FRACTION)
    assert (float(np.mean(last)) >= FAIL_FRACTION > want) == mean_named_degraded


def test_no_burn_reads_theta() -> None:
    eff = _eff([])
    assert eff.fraction[4] == pytest.approx(eff.theta[4])
    assert eff.fraction_since(4, 0) == pytest.approx(eff.theta[4])


@pytest.mark.parametrize("run", [31, 61])
def test_a_thruster_that_fails_to_fire_is_named_so(tmp_path, run: int) -> None:
    """kalman_cube-faults runs 31 (Z+) and 61 (Y+) fail to fire: named fail_to_fire, the right
    thruster, fraction under 0.15 (the mean of the same burns named them degraded at 0.25 and
    0.19)."""
    spec, r = campaign_run(tmp_path, "kalman_cube-faults", run)
    assert spec.fault["kind"] == "fail_to_fire"
    d = r.summary["detections"][0]
    assert d["correct"] and d["type"] == "fail_to_fire" and d["fraction"] < FAIL_FRACTION, d


@pytest.mark.parametrize("burns, want", [
    ([1.0, 1.0, 0.2], 1.0),     # one low burn: the median passes it
    ([0.2, 1.0, 1.1], 1.0),
    ([1.0, 0.1, -0.1], 1.0 / 3),  # one high burn: the mean is the larger, still a fault
    ([0.79, 0.8, 0.81], 0.8),
])
def test_the_not_a_fault_check_reads_the_larger_of_mean_and_median(burns, want) -> None:
    """``fraction_healthiest``: one burn, low or high, never turns a thruster the mean would
    pass into a fault (generic-envelope run 136: X+ at 0.79 of nominal by the envelope's own
    thrust dispersions, named degraded on the median of burns whose mean read over 0.8)."""
    eff = _eff([1.0, 1.0] + burns)
    assert eff.fraction_healthiest[4] == pytest.approx(want)
    assert eff.fraction_healthiest[4] == pytest.approx(max(np.mean(burns), np.median(burns)))
    assert eff.fraction_since(4, 2, healthiest=True) == pytest.approx(want)
    assert eff.fraction_healthiest[4] >= eff.fraction[4]
