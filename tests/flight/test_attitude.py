"""Quaternion helpers and the strapdown estimate against closed-form rotations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flight.attitude import (
    AttitudeEstimate,
    error_quaternion,
    orbit_rate_B_rad_s,
    q_conj,
    q_from_axis_angle,
    q_mul,
    q_normalise,
    q_rotate,
    rotation_angle,
    small_angle_vector,
)


def test_product_conjugate_and_rotation():
    qx = q_from_axis_angle(np.array([1.0, 0, 0]), math.pi / 2)
    assert q_rotate(qx, np.array([0.0, 1.0, 0.0])) == pytest.approx([0.0, 0.0, 1.0], abs=1e-15)
    assert q_mul(qx, q_conj(qx)) == pytest.approx([1.0, 0, 0, 0], abs=1e-15)
    qz = q_from_axis_angle(np.array([0, 0, 1.0]), 0.3)
    # Composition: rotate by qz then (in the outer frame) by qx.
    v = np.array([0.2, -0.5, 0.7])
    assert q_rotate(q_mul(qx, qz), v) == pytest.approx(q_rotate(qx, q_rotate(qz, v)))
    assert q_normalise(-qx)[0] > 0


def test_small_angle_vector_and_angle():
    q = q_from_axis_angle(np.array([0.0, 0.6, 0.8]), math.radians(2.0))
    expect = np.array([0, 0.6, 0.8]) * math.radians(2)
    assert small_angle_vector(q) == pytest.approx(expect, rel=1e-4)
    assert rotation_angle(q) == pytest.approx(math.radians(2.0), rel=1e-12)
    assert rotation_angle(-q) == pytest.approx(math.radians(2.0), rel=1e-12)


def test_error_quaternion_is_body_relative_to_target():
    R = q_from_axis_angle(np.array([0, 0, 1.0]), 0.4)
    L = q_mul(R, q_from_axis_angle(np.array([1.0, 0, 0]), 0.1))
    N = error_quaternion(R, L)
    assert small_angle_vector(N) == pytest.approx([2 * math.sin(0.05), 0, 0], rel=1e-12)


def test_inertially_fixed_body_drifts_against_orbit_frame():
    """A body at rest in inertial space turns at +w0 about z' relative to O (O turns at -w0 z')."""
    w0 = 0.001162
    est = AttitudeEstimate(w0)
    for _ in range(500):
        est.update(np.zeros(3), 0.2)
    expect = q_from_axis_angle(np.array([0, 0, 1.0]), w0 * 100.0)
    assert est.Lambda_BO == pytest.approx(expect, abs=1e-12)


def test_orbit_rate_in_body_and_relative_rate():
    w0 = 0.001
    est = AttitudeEstimate(w0)
    assert orbit_rate_B_rad_s(est.Lambda_BO, w0) == pytest.approx([0, 0, -w0])
    # A body turning with the orbit frame has zero rate relative to it and stays put.
    for _ in range(100):
        est.update(np.array([0.0, 0.0, -w0]), 0.2)
    assert est.Lambda_BO == pytest.approx([1.0, 0, 0, 0], abs=1e-13)
    assert est.rate_relative_B_rad_s(np.array([0, 0, -w0])) == pytest.approx(np.zeros(3), abs=1e-15)


def test_constant_rate_integration_matches_closed_form():
    w = np.array([0.01, -0.02, 0.005])
    est = AttitudeEstimate(0.0)
    for _ in range(50):
        est.update(w, 0.2)
    ang = np.linalg.norm(w) * 10.0
    assert est.Lambda_BO == pytest.approx(q_from_axis_angle(w / np.linalg.norm(w), ang), abs=1e-12)
    est2 = AttitudeEstimate(0.0)
    for _ in range(50):
        est2.update_increment(w * 0.2, 0.2)
    assert est2.Lambda_BO == pytest.approx(est.Lambda_BO, abs=1e-12)
