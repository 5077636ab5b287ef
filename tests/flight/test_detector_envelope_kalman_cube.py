"""The detector on kalman_cube (seed 002's cube) across the envelope: learnt command latency
and the ellipsoidal dead zone (issue 12).

Oracles: the plant's own command latency, thrust errors and faults (closed loop: flight core +
plant core, as tests/flight/test_fdir_envelope.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_fdir_envelope import _run  # same folder (on sys.path under pytest)

from flight.detector import STUCK_ON, leak_or_deficit
from hil.config import AttitudeCfg, FaultSpec, InitialCfg, PlantOverridesCfg

# A slew from 20 deg with a tumble: every channel fires for seconds, then a hold.
SLEW = InitialCfg(attitude=AttitudeCfg(axis=(1, 1, 0), angle_deg=20.0),
                  rate_B_deg_s=(1.5, -1.0, 0.5))
# Thrust errors at the edge of the envelope (global 0.88 x per thruster 0.85-1.15) and 14 ms
# of command latency against the onboard model's nominal 0.
EDGE = dict(thrust_scale=0.88, command_latency_ms=14.0, direction_error_deg=1.5,
            thrust_scale_per_thruster={"X+": 0.85, "X-": 1.15, "Y+": 0.87, "Y-": 1.13,
                                       "Z+": 1.1, "Z-": 0.9})


@pytest.mark.parametrize("latency_ms", [0.0, 6.0, 14.0])
def test_command_latency_is_learnt(latency_ms: float) -> None:
    keep: list = []
    _run("kalman_cube", [], 40.0, init=SLEW,
         plant=PlantOverridesCfg(command_latency_ms=latency_ms), keep=keep)
    fs = keep[0]
    assert fs.effectiveness.latency_s * 1e3 == pytest.approx(latency_ms, abs=2.0)
    assert fs.model.latency_s * 1e3 == pytest.approx(latency_ms, abs=2.0)


def test_edge_of_the_envelope_raises_no_alarm_and_does_without_the_learning() -> None:
    """The same run alarms when the latency and the thrust scale are not learnt (the oracle
    that the test can fail)."""
    dets, _, _ = _run("kalman_cube", [], 60.0, init=SLEW, plant=PlantOverridesCfg(**EDGE))
    assert dets == [], [(t, d.describe()) for t, d in dets]
    off = {"detector": {"learn_latency_ms": 0.0, "effectiveness_bound": 0.0}}
    dets_off, _, _ = _run("kalman_cube", [], 60.0, init=SLEW, plant=PlantOverridesCfg(**EDGE),
                          flight=off)
    assert dets_off


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.15])
def test_a_leak_during_firings_on_other_channels_is_seen(fraction: float) -> None:
    """Y+ stuck on while the craft slews: the other channels' firings do not hide it (the
    ellipsoid); a spherical relative dead zone wide enough for the envelope misses the 15 %
    leak (checked below for that fraction)."""
    fault = FaultSpec(kind="stuck_on", t_s=3.0, thruster="Y+", fraction=fraction)
    dets, _, _ = _run("kalman_cube", [fault], 20.0, init=SLEW, plant=PlantOverridesCfg(**EDGE))
    assert dets, "missed"
    t, d = dets[0]
    assert (d.names, d.kind) == (("Y+",), STUCK_ON)
    assert t - 3.0 <= 7.1  # seed 002: 15 % within 7.1 s
    if fraction == 0.15:
        sphere = {"detector": {"relative_dead_zone": 0.3, "relative_dead_zone_across": None}}
        dets_s, _, _ = _run("kalman_cube", [fault], 20.0, init=SLEW,
                            plant=PlantOverridesCfg(**EDGE), flight=sphere)
        assert not dets_s or dets_s[0][0] - 3.0 > 7.1


def _ticks(seed: int):
    """10 ticks of a pair of opposite thrusters i, j: i fires on some ticks (full or partial),
    j on others, some ticks neither."""
    rng = np.random.default_rng(seed)
    h, mu = 0.2, 6.7e-3 / 0.2
    eff_i = np.where(rng.random(10) < 0.5, rng.uniform(0.05, h, 10), 0.0)
    eff_j = np.where((eff_i == 0.0) & (rng.random(10) < 0.4), rng.uniform(0.05, h, 10), 0.0)
    return mu * eff_i, mu * (h - eff_j), rng


@pytest.mark.parametrize("seed", range(5))
def test_leak_or_deficit_names_the_hypothesis_the_data_came_from(seed: int) -> None:
    burn_i, closed_j, rng = _ticks(seed)
    noise = 1e-4 * rng.standard_normal(10)
    leak = -0.5 * closed_j + noise       # j stuck on at 50 %
    deficit = -0.5 * burn_i + noise      # i degraded to 50 %
    assert leak_or_deficit(leak, burn_i, closed_j) < 0.5
    assert leak_or_deficit(deficit, burn_i, closed_j) > 2.0


def test_leak_or_deficit_abstains_when_the_ticks_cannot_tell() -> None:
    """i commanded for the whole tick on every tick and j never: both regressors are the
    same, so neither hypothesis is preferred."""
    full = np.full(10, 6.7e-3)
    assert leak_or_deficit(-0.5 * full, full, full) == 1.0


# Seed 002's start (3 deg/s about x): the s-law then holds in a limit cycle that fires X+ or X-
# on nearly every tick, so a failing X- and a leaking X+ move the residuals alike.
LIMIT_CYCLE = InitialCfg(rate_B_deg_s=(3.0, 0.0, 0.0))


@pytest.mark.parametrize("fault,named", [
    (FaultSpec(kind="stuck_on", t_s=20.0, thruster="X+", fraction=1.0), ("X+", "stuck_on")),
    (FaultSpec(kind="fail_to_fire", t_s=20.0, thruster="X-"), ("X-", "fail_to_fire")),
    (FaultSpec(kind="degraded", t_s=20.0, thruster="X+", fraction=0.5), ("X+", "degraded")),
    (FaultSpec(kind="degraded", t_s=20.0, thruster="Y-", fraction=0.4), ("Y-", "degraded")),
], ids=["stuck", "fail", "degraded", "degraded_y"])
def test_opposite_hypotheses_are_told_apart(fault: FaultSpec, named: tuple[str, str]) -> None:
    """The first detection names the injected thruster and kind (the pair's fit, and a probe
    when the ticks cannot tell), within 3 s."""
    dets, _, _ = _run("kalman_cube", [fault], 30.0, init=LIMIT_CYCLE,
                      plant=PlantOverridesCfg(**EDGE))
    assert dets, "missed"
    t, d = dets[0]
    assert (d.names[0], d.kind) == named, d.describe()
    assert t - fault.t_s <= 3.0


def test_latency_learning_without_the_effectiveness_is_refused() -> None:
    """The latency is a state of the effectiveness filter: asking for it with the learning
    off is a one-line configuration error, not an option silently ignored."""
    from common.errors import ConfigError
    from hil.config import load_vehicle

    with pytest.raises(ConfigError, match=r"learn_latency_ms: expected 0 when "
                                          r"effectiveness_bound is 0.*got 20\.0"):
        load_vehicle("kalman_cube", {"detector": {"effectiveness_bound": 0.0}})
