"""Controller mode boundaries (seed 004 section 2) and the seed 002 s-law dead zone.

Oracles, all written here from the seeds and the controller's documented formulas, with the
vehicle's angular accelerations computed from the YAML (``mu = J^-1 (r x F)``):

* ``eps_i = 0.5 * min(sum of positive, sum of negative mu_n,i)`` (module constant
  ``CURVE_ACCEL_FRACTION``, the documented "half the weaker-sign authority");
* Euler-axis turn above 15 deg of total angle:
  ``e_ref = -min(w_max, sqrt(2 eps_n theta), s (theta - nu_dz)) * n`` with
  ``eps_n = min_i eps_i / |n_i|`` (the acceleration about the axis no channel exceeds);
* |nu_i| above and below 6.1 deg (total < 15 deg): the switching curve (seed 004 eq. 2.2) capped
  by the ramp, ``e_ref = -sign(nu) min(s (|nu| - nu_dz)+, sqrt(2 eps_i |nu|), w_max)``,
  ``s = dw_dz / nu_dz``: continuous across 6.1 deg, and across 15 deg about a body axis;
* band: outside ``|e - e_ref| > dw_dz`` the bounds aim at the inner band ``dw_dz - hysteresis``;
* seed 002: ``s = phi + k w``; ``|s| <= s_dz`` -> no firing; beyond, a full tick
  (``h - (on_lag - off_lag)``) of the channel's authority of the opposite sign to ``s``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flight.allocator import Allocator
from flight.controller import ABOVE, BELOW, INSIDE, Controller
from hil.config import load_vehicle

D = math.radians
TINY = 1e-9  # rad or rad/s: "just below / just above" a boundary


def geometry_mu(v) -> np.ndarray:
    """(N, 3) angular accelerations from the YAML fields, rad/s^2."""
    J = np.array(v.inertia_B_kg_m2, dtype=float)
    com = np.array(v.com_m, dtype=float)
    out = []
    for t in v.thrusters:
        d = np.array(t.direction, dtype=float)
        d /= np.linalg.norm(d)
        out.append(np.linalg.solve(J, np.cross(np.array(t.position_m) - com, d * t.thrust_n)))
    return np.array(out)


def quat(axis: np.ndarray, angle: float) -> np.ndarray:
    """Scalar-first rotation quaternion (body relative to the orbit frame)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate(([math.cos(angle / 2)], math.sin(angle / 2) * a))


class Law:
    """The documented phase-plane law, written independently of the controller."""

    def __init__(self, v) -> None:
        c = v.flight.controller
        mu = geometry_mu(v)
        pos = np.clip(mu, 0, None).sum(axis=0)
        neg = np.clip(-mu, 0, None).sum(axis=0)
        self.pos, self.neg = pos, neg
        self.eps = 0.5 * np.minimum(pos, neg)
        self.dw_dz = D(c.rate_deadband_deg_s)
        self.dw_in = D(c.rate_deadband_deg_s - c.hysteresis_deg_s)
        self.nu_dz = D(c.angle_deadband_deg)
        self.large = D(c.large_angle_deg)
        self.curve = D(c.curve_angle_deg)
        self.w_max = D(c.max_rate_deg_s)

    def w_turn(self, theta: float, axis: np.ndarray) -> float:
        n = np.abs(axis) / np.linalg.norm(axis)
        eps_n = min(self.eps[i] / n[i] for i in range(3) if n[i] > 0)
        ramp = self.dw_dz / self.nu_dz * max(theta - self.nu_dz, 0.0)
        return min(self.w_max, math.sqrt(2 * eps_n * theta), ramp)

    def e_ref_channel(self, nu: float, i: int) -> float:
        a = abs(nu)
        curve = math.sqrt(2 * self.eps[i] * a)
        ramp = self.dw_dz / self.nu_dz * max(a - self.nu_dz, 0.0)
        return -math.copysign(min(ramp, curve, self.w_max), nu)


@pytest.fixture(scope="module")
def generic():
    return load_vehicle("generic")


@pytest.fixture(scope="module")
def ctl(generic):
    return Controller(generic)


@pytest.fixture(scope="module")
def law(generic):
    return Law(generic)


def test_curve_accelerations_are_half_the_weaker_sign_authority(ctl, law) -> None:
    np.testing.assert_allclose(ctl.eps_B_rad_s2, law.eps, rtol=1e-12)
    # generic: X- (0.8 m arm) and Z- (0.7 m) are the weak signs (seed 000 fig. 4).
    np.testing.assert_allclose(law.eps, 0.5 * np.array([8 / 1000, 10 / 1200, 7 / 1400]),
                               rtol=1e-12)


# --------------------------------------------------------------------------- 15 deg boundary


@pytest.mark.parametrize("seed", range(6))
def test_15_deg_boundary_switches_from_curve_to_euler_turn(ctl, law, seed) -> None:
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    for theta, mode in ((law.large - TINY, "curve"), (law.large + TINY, "euler_turn")):
        d = ctl.demand_phase_plane(quat(axis, theta), np.zeros(3))
        assert d.mode == mode
        assert d.total_angle_rad == pytest.approx(theta, abs=1e-12)
        nu = 2 * math.sin(theta / 2) * axis  # seed 004: nu ~ 2 N_vec
        np.testing.assert_allclose(d.nu_B_rad, nu, atol=1e-15)
        if mode == "euler_turn":
            expect = -law.w_turn(theta, axis) * axis
        else:  # some channel is beyond 6.1 deg (15 / sqrt(3) > 6.1): on its curve
            expect = np.array([law.e_ref_channel(nu[i], i) for i in range(3)])
        np.testing.assert_allclose(d.e_ref_B_rad_s, expect, rtol=1e-12, atol=1e-15)


def test_euler_turn_rate_is_min_of_cap_and_braking_curve(ctl, law) -> None:
    """|e_ref| = min(w_max, sqrt(2 eps_n theta)) on both sides of the kink, along -axis."""
    kink = law.w_max**2 / (2 * law.eps.min())  # 42.8 deg on generic (weakest-channel axis)
    assert law.large < kink < math.pi
    rng = np.random.default_rng(3)
    thetas = [law.large + TINY, D(20.0), kink - 1e-6, kink + 1e-6, D(90.0), D(179.0)]
    for theta in thetas + list(rng.uniform(law.large, math.pi - 1e-3, 20)):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        d = ctl.demand_phase_plane(quat(axis, theta), np.zeros(3))
        assert d.mode == "euler_turn"
        w = law.w_turn(theta, axis)
        assert np.linalg.norm(d.e_ref_B_rad_s) == pytest.approx(w, rel=1e-12)
        np.testing.assert_allclose(d.e_ref_B_rad_s, -w * axis, rtol=1e-12, atol=1e-16)
        if theta > kink:  # eps_n >= eps_min: beyond the weakest channel's kink, always capped
            assert w == law.w_max == D(3.5)
        else:
            assert w <= law.w_max


def test_euler_turn_bounds_track_the_commanded_rate(ctl, law) -> None:
    """At the commanded turn rate: inside; off it by more than the band: aim at the inner band."""
    axis = np.array([0.6, -0.48, 0.64])
    theta = D(30.0)
    e_ref = -law.w_turn(theta, axis) * axis
    d = ctl.demand_phase_plane(quat(axis, theta), e_ref)
    assert d.region == (INSIDE,) * 3 and not d.fire
    np.testing.assert_allclose(d.dw_down_B_rad_s, -law.dw_dz, atol=1e-15)
    np.testing.assert_allclose(d.dw_up_B_rad_s, law.dw_dz, atol=1e-15)
    e = e_ref + np.array([law.dw_dz + TINY, -(law.dw_dz + TINY), law.dw_dz - TINY])
    d = ctl.demand_phase_plane(quat(axis, theta), e)
    assert d.region == (ABOVE, BELOW, INSIDE) and d.fire
    assert d.dw_up_B_rad_s[0] == pytest.approx(law.dw_in - (law.dw_dz + TINY), abs=1e-15)
    assert d.dw_down_B_rad_s[1] == pytest.approx(-law.dw_in + law.dw_dz + TINY, abs=1e-15)


# --------------------------------------------------------------------------- 6.1 deg boundary


@pytest.mark.parametrize("sign", [1.0, -1.0])
@pytest.mark.parametrize("ch", [0, 1, 2])
def test_6_1_deg_boundary_switches_channel_to_the_curve(ctl, law, ch, sign) -> None:
    """Just above 6.1 deg: the curve ``sqrt(2 eps |nu|)``; just below: the phase-plane line."""
    other = np.array([D(0.3), -D(2.0), D(4.0)])
    for a, mode in ((law.curve + TINY, "curve"), (law.curve - TINY, "phase_plane")):
        nu = other.copy()
        nu[ch] = sign * a
        assert np.linalg.norm(nu) < law.large
        d = ctl.demand_from_errors(nu, np.zeros(3))
        assert d.mode == mode
        expect = [law.e_ref_channel(nu[i], i) for i in range(3)]
        np.testing.assert_allclose(d.e_ref_B_rad_s, expect, rtol=1e-12, atol=1e-16)
    # Continuous across the boundary (generic: the ramp is below the curve at 6.1 deg on roll
    # and yaw, where the old law jumped from ~1.3 to ~1.7 deg/s).
    lo = ctl.demand_from_errors(np.where(np.arange(3) == ch, sign * (law.curve - TINY), other),
                                np.zeros(3)).e_ref_B_rad_s[ch]
    hi = ctl.demand_from_errors(np.where(np.arange(3) == ch, sign * (law.curve + TINY), other),
                                np.zeros(3)).e_ref_B_rad_s[ch]
    assert abs(hi - lo) < 1e-6


@pytest.mark.parametrize("vehicle", ["generic", "iss_rs", "orel"])
@pytest.mark.parametrize("ch", [0, 1, 2])
def test_commanded_rate_is_continuous_across_15_deg_about_a_body_axis(vehicle, ch) -> None:
    """An error about one body axis: the Euler turn just above 15 deg commands the rate the
    channel's own law commands just below (the turn's acceleration about a body axis is that
    channel's ``eps``)."""
    c = Controller(load_vehicle(vehicle))
    axis = np.eye(3)[ch]
    big = D(c.cfg.large_angle_deg)
    below = c.demand_phase_plane(quat(axis, big - TINY), np.zeros(3))
    above = c.demand_phase_plane(quat(axis, big + TINY), np.zeros(3))
    assert (below.mode, above.mode) == ("curve", "euler_turn")
    # Below, the channel's angle is nu = 2 sin(theta / 2); above, the turn uses theta itself:
    # sqrt(theta / (2 sin(theta / 2))) - 1 = 0.14 % at 15 deg on the curve, 0.3 % on iss_rs's
    # ramp (the old law jumped by 27 % on generic about x).
    assert above.e_ref_B_rad_s[ch] == pytest.approx(below.e_ref_B_rad_s[ch], rel=5e-3)


def test_curve_mode_band_and_hysteresis(ctl, law) -> None:
    """On the curve: the band around it, the inner target band when outside (hysteresis)."""
    nu = np.array([D(10.0), D(1.0), 0.0])
    c = law.e_ref_channel(nu[0], 0)
    inside = ctl.demand_from_errors(nu, np.array([c + law.dw_dz - TINY, 0.0, 0.0]))
    assert inside.mode == "curve" and inside.region[0] == INSIDE
    outside = ctl.demand_from_errors(nu, np.array([c + law.dw_dz + TINY, 0.0, 0.0]))
    assert outside.region[0] == ABOVE and outside.fire
    assert outside.dw_up_B_rad_s[0] == pytest.approx(law.dw_in - law.dw_dz - TINY, abs=1e-15)
    assert outside.dw_down_B_rad_s[0] == pytest.approx(-law.dw_in - law.dw_dz - TINY, abs=1e-15)


def test_phase_plane_centre_line_is_continuous_below_6_1_deg(ctl, law) -> None:
    """Inside one mode the centre line has no jump: dead band edge and ramp/curve crossover."""
    grid = np.linspace(0.0, law.curve - TINY, 4001)
    for i in range(3):
        e = np.array([ctl.centre_line(a, ctl.eps_B_rad_s2[i]) for a in grid])
        np.testing.assert_allclose(e, [law.e_ref_channel(a, i) for a in grid], atol=1e-16)
        slope_bound = law.dw_dz / law.nu_dz  # the ramp is the steepest piece beyond tiny |nu|
        assert np.abs(np.diff(e)).max() <= slope_bound * (grid[1] - grid[0]) * (1 + 1e-9) + 1e-15
        assert np.all(e[grid <= law.nu_dz] == 0.0)  # nothing asked inside the angle dead band


# --------------------------------------------------------------------------- seed 002 s-law


@pytest.fixture(scope="module")
def cube():
    return load_vehicle("kalman_cube")


@pytest.mark.parametrize("ch", [0, 1, 2])
def test_s_law_dead_zone_and_sign(cube, ch) -> None:
    c = cube.flight.controller
    ctl = Controller(cube)
    law = Law(cube)
    k, s_dz = float(c.s_gain_s), D(c.s_deadband_deg)
    full = cube.timing.tick_s - (cube.thrust_profile.on_lag_ms
                                 - cube.thrust_profile.off_lag_ms) / 1000.0
    alloc = Allocator(cube)
    mu = geometry_mu(cube)
    rng = np.random.default_rng(ch)
    for _ in range(10):
        nu_c = rng.uniform(-1.5, 1.5) * s_dz  # angle part; the rate makes up s
        for s_target, region in ((s_dz - TINY, INSIDE), (-(s_dz - TINY), INSIDE),
                                 (s_dz + TINY, ABOVE), (-(s_dz + TINY), BELOW)):
            nu = np.zeros(3)
            e = np.zeros(3)
            nu[ch] = nu_c
            e[ch] = (s_target - nu_c) / k  # s = phi + k w
            d = ctl.s_law_from_errors(nu, e)
            assert d.mode == "s_law" and d.region[ch] == region
            assert all(r == INSIDE for j, r in enumerate(d.region) if j != ch)
            alloc.reset()
            a = alloc.allocate(d.dw_down_B_rad_s, d.dw_up_B_rad_s)
            if region == INSIDE:
                assert not d.fire and not a.on_ms.any()
                assert d.dw_down_B_rad_s[ch] == -law.dw_dz and d.dw_up_B_rad_s[ch] == law.dw_dz
            elif region == ABOVE:  # s > s_dz: full tick of negative acceleration
                assert d.dw_down_B_rad_s[ch] == -np.inf
                assert d.dw_up_B_rad_s[ch] == pytest.approx(-law.neg[ch] * full, rel=1e-12)
                assert a.on_ms[mu[:, ch] < 0].tolist() == [200] and a.on_ms.sum() == 200
            else:  # s < -s_dz: full tick of positive acceleration
                assert d.dw_up_B_rad_s[ch] == np.inf
                assert d.dw_down_B_rad_s[ch] == pytest.approx(law.pos[ch] * full, rel=1e-12)
                assert a.on_ms[mu[:, ch] > 0].tolist() == [200] and a.on_ms.sum() == 200


def test_s_law_through_the_attitude_path(cube) -> None:
    """``demand`` (law ``s_law``) from a quaternion and a rate: s = 2 N_x + k w_x."""
    ctl = Controller(cube)
    k, s_dz = float(cube.flight.controller.s_gain_s), D(cube.flight.controller.s_deadband_deg)
    phi = D(0.2)
    L = quat(np.array([1.0, 0.0, 0.0]), phi)
    nu_x = 2 * math.sin(phi / 2)
    for s_target, region in ((s_dz - 1e-7, INSIDE), (s_dz + 1e-7, ABOVE),
                             (-s_dz - 1e-7, BELOW)):
        w = np.array([(s_target - nu_x) / k, 0.0, 0.0])
        d = ctl.demand(L, w)
        assert d.mode == "s_law" and d.region == (region, INSIDE, INSIDE)
