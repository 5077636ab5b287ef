"""Scalar-first quaternion algebra shared by the plant and flight cores (pure, no state)."""

from __future__ import annotations

import numpy as np


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` of two 3-vectors, shape (3,) (``np.cross`` costs ~40 us of axis handling)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def q_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p (x) q`` of two scalar-first quaternions, shape (4,)."""
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = q
    return np.array([
        p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
        p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
        p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
        p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
    ])


def q_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate ``q~`` (the inverse of a unit quaternion), shape (4,)."""
    return np.array([q[0], -q[1], -q[2], -q[3]])
