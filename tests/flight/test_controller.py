"""Seed 004 phase-plane controller (and seed 002 s-law): regions, hysteresis, large angles, loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flight.allocator import Allocator
from flight.attitude import propagate, q_from_axis_angle
from flight.controller import ABOVE, BELOW, INSIDE, Controller
from hil.config import load_vehicle

D = math.radians


@pytest.fixture(scope="module")
def generic():
    return load_vehicle("generic")


@pytest.fixture(scope="module")
def ctl(generic):
    return Controller(generic)


def test_inside_dead_zone_no_command(ctl):
    d = ctl.demand_from_errors(np.zeros(3), np.array([D(0.05), -D(0.1), 0.0]))
    assert d.region == (INSIDE, INSIDE, INSIDE) and not d.fire
    assert np.all(d.dw_down_B_rad_s < 0) and np.all(d.dw_up_B_rad_s > 0)
    # The bounds are the vertical distances to the outer band (0.12 deg/s half-width).
    assert d.dw_up_B_rad_s[0] == pytest.approx(D(0.12) - D(0.05))
    assert d.dw_down_B_rad_s[1] == pytest.approx(-D(0.12) + D(0.1))


def test_above_and_below_give_signed_bounds(ctl):
    hyst_in = D(0.12 - 0.02)
    d = ctl.demand_from_errors(np.zeros(3), np.array([D(0.3), -D(0.3), 0.0]))
    assert d.region == (ABOVE, BELOW, INSIDE) and d.fire
    # Above: negative change, at least to the near inner boundary.
    assert d.dw_up_B_rad_s[0] == pytest.approx(hyst_in - D(0.3))
    assert d.dw_down_B_rad_s[0] == pytest.approx(-hyst_in - D(0.3))
    assert d.dw_down_B_rad_s[1] == pytest.approx(D(0.3) - hyst_in)
    assert d.dw_up_B_rad_s[1] > 0


def test_switching_line_slopes_down_with_angle(ctl):
    """At an angle error beyond the dead band, zero rate is already above the band."""
    d = ctl.demand_from_errors(np.array([D(1.5), -D(1.5), 0.0]), np.zeros(3))
    assert d.region[0] == ABOVE and d.region[1] == BELOW
    assert d.e_ref_B_rad_s[0] < 0 < d.e_ref_B_rad_s[1]


def test_hysteresis_point_just_inside_after_firing_does_not_refire(ctl):
    d = ctl.demand_from_errors(np.zeros(3), np.array([D(0.3), 0.0, 0.0]))
    assert d.fire
    # Apply a change that only reaches just inside the outer boundary (quantisation shortfall).
    e_after = np.array([D(0.12) - 1e-6, 0.0, 0.0])
    d2 = ctl.demand_from_errors(np.zeros(3), e_after)
    assert d2.region[0] == INSIDE and not d2.fire
    # While a point just outside fires towards the inner boundary, past the outer one.
    d3 = ctl.demand_from_errors(np.zeros(3), np.array([D(0.12) + 1e-6, 0, 0]))
    assert d3.fire and d3.dw_up_B_rad_s[0] == pytest.approx(-D(0.02) - 1e-6)


def test_euler_axis_turn_direction_and_rate(ctl):
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    L = q_from_axis_angle(axis, D(40.0))
    d = ctl.demand_phase_plane(L, np.zeros(3))
    assert d.mode == "euler_turn" and d.total_angle_rad == pytest.approx(D(40.0))
    # Commanded rate along -axis (reducing the error), at most 3.5 deg/s.
    assert np.dot(d.e_ref_B_rad_s, axis) < 0
    assert np.cross(d.e_ref_B_rad_s, axis) == pytest.approx(np.zeros(3), abs=1e-15)
    assert np.linalg.norm(d.e_ref_B_rad_s) <= D(3.5) + 1e-15
    mid = 0.5 * (d.dw_down_B_rad_s + d.dw_up_B_rad_s)
    assert mid == pytest.approx(d.e_ref_B_rad_s)


def test_switching_curve_between_6_1_and_15_deg(ctl):
    d = ctl.demand_from_errors(np.array([D(10.0), D(1.0), 0.0]), np.zeros(3))
    assert d.mode == "curve"
    eps = ctl.eps_B_rad_s2[0]
    assert d.e_ref_B_rad_s[0] == pytest.approx(-math.sqrt(2 * eps * D(10.0)))
    assert d.region[0] == BELOW or d.region[0] == ABOVE


def test_s_law_maps_to_full_tick_bounds(generic):
    cube = load_vehicle("kalman_cube")
    ctl = Controller(cube)
    d = ctl.demand_s_law(np.array([1.0, 0, 0, 0]), np.array([D(3.0), 0.0, 0.0]))
    assert d.mode == "s_law" and d.region == (ABOVE, INSIDE, INSIDE)
    assert d.dw_down_B_rad_s[0] == -np.inf
    alloc = Allocator(cube, solver="simplex")
    a = alloc.allocate(d.dw_down_B_rad_s, d.dw_up_B_rad_s)
    minus_x = int(np.argmin(alloc.mu[:, 0]))
    assert a.on_ms[minus_x] == 200 and a.on_ms.sum() == 200


def _closed_loop(vehicle, start_deg: float, ticks: int):
    ctl = Controller(vehicle)
    alloc = Allocator(vehicle, solver="simplex")
    h = vehicle.timing.tick_s
    L = q_from_axis_angle(np.array([1.0, 0.0, 0.0]), D(start_deg))
    w = np.zeros(3)
    hist = []
    for _ in range(ticks):
        d = ctl.demand_phase_plane(L, w)
        a = alloc.allocate(d.dw_down_B_rad_s, d.dw_up_B_rad_s)
        # Double integrator per axis: the rate change of the effective firing times, applied
        # over the tick (mean rate for the attitude step).
        w_next = w + a.dw_pred_B_rad_s
        L = propagate(L, 0.5 * (w + w_next), h, 0.0)
        w = w_next
        hist.append((d.nu_B_rad.copy(), d.rate_err_B_rad_s.copy(), d.region, d.mode))
    return ctl, hist


def test_closed_loop_converges_from_22_5_deg(generic):
    """Seed 000's case: 22.5 deg about X converges into the dead zone and stays."""
    ctl, hist = _closed_loop(generic, 22.5, 900)
    modes = [m for *_, m in hist]
    assert modes[0] == "euler_turn" and "curve" in modes
    tail = hist[-200:]
    nu_max = max(np.abs(nu).max() for nu, *_ in tail)
    rate_max = max(np.abs(e).max() for _, e, *_ in tail)
    assert nu_max < D(1.2)
    assert rate_max < D(0.12) + 1e-4
    peak_rate = max(np.abs(e).max() for _, e, *_ in hist)
    assert peak_rate <= D(3.5) + D(0.2)
