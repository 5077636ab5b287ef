"""Rigid-body rotation and kinematics (docs/design.md 5.1; seed 003 eq. 1; seed 004 orbit frame).

Euler's equation in body axes B with CMG momentum ``H`` (seed 003 eq. 1, docs/design.md 5.1)::

    J dw/dt + w x (J w + H) = M_ext + M_gg - dH/dt

Kinematics ``dq/dt = 1/2 q (x) [0, w]`` with scalar-first quaternions. ``q_XY`` is the attitude
of frame X relative to frame Y: it maps X components into Y components,
``v_Y = q_XY (x) v_X (x) q_XY*``. The state is ``q_BI`` (body relative to inertial) and the
absolute body rate ``w_B``; the attitude relative to the orbit frame follows exactly as
``q_BO = q_OI* (x) q_BI`` with ``q_OI`` analytic (below), so no orbit-frame drift accumulates.

Orbit frame O (seed 004): y' along the radius vector, z' against the orbital angular velocity,
x' = y' x z' (along the velocity of a circular orbit). The inertial frame I is the orbit frame
at t = 0; the orbit frame turns about z' = z_I with angular velocity ``-w0 z'``, so
``q_OI(t) = [cos(w0 t / 2), 0, 0, -sin(w0 t / 2)]`` and the local vertical in inertial axes is
``y'_I(t) = [sin w0 t, cos w0 t, 0]``. For ``w0 = 0`` the orbit frame is inertial.

Gravity gradient (docs/design.md 5.1): ``M_gg = 3 w0^2 (j x J j)``, ``j`` the local vertical in B.

Integration: classic fixed-step RK4 with the external torque held constant over the step (the
thrust torque is the exact mean over the step, from the exact impulse), the gravity-gradient
torque evaluated at every stage. Plain float arithmetic: for 3-vectors it is several times
faster than numpy calls, and the loop is the plant's only sequential part.
"""

from __future__ import annotations

import math

import numpy as np

from common.quaternion import q_conj as quat_conj
from common.quaternion import q_mul as quat_mul

# --------------------------------------------------------------------------- quaternions


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Matrix (3, 3) of ``q_XY``: ``v_Y = C v_X``."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def q_OI(t_s: float, w0_rad_s: float) -> np.ndarray:
    """Orbit frame relative to inertial at ``t_s`` (module doc), scalar-first (4,)."""
    h = 0.5 * w0_rad_s * t_s
    return np.array([math.cos(h), 0.0, 0.0, -math.sin(h)])


def local_vertical_I(t_s: float, w0_rad_s: float) -> np.ndarray:
    """Unit radius vector y' in inertial axes (3,)."""
    th = w0_rad_s * t_s
    return np.array([math.sin(th), math.cos(th), 0.0])


def orbit_rate_O(w0_rad_s: float) -> np.ndarray:
    """Angular velocity of the orbit frame in its own axes: ``-w0 z'`` (3,)."""
    return np.array([0.0, 0.0, -w0_rad_s])


def gravity_gradient_B(j_B: np.ndarray, J_B_kg_m2: np.ndarray, w0_rad_s: float) -> np.ndarray:
    """``M_gg = 3 w0^2 (j x J j)`` (3,) N m, ``j_B`` the unit local vertical in B."""
    return 3.0 * w0_rad_s**2 * np.cross(j_B, J_B_kg_m2 @ j_B)


# --------------------------------------------------------------------------- rigid body


class RigidBody:
    """State ``q_BI`` (4,), ``w_B_rad_s`` (3,) and its RK4 step (module doc).

    ``h_cmg_B_Nms(t) = h0 + h_dot t`` and ``dH/dt = h_dot`` (``CmgCfg``); ``w0_rad_s`` and
    ``gravity_gradient`` from ``OrbitCfg``.
    """

    def __init__(self, J_B_kg_m2: np.ndarray, q_BI: np.ndarray, w_B_rad_s: np.ndarray, *,
                 w0_rad_s: float = 0.0, gravity_gradient: bool = False,
                 h_cmg_B_Nms: np.ndarray | None = None, h_dot_B_Nm: np.ndarray | None = None
                 ) -> None:
        J = np.asarray(J_B_kg_m2, dtype=float)
        self.J = J
        self.J_inv = np.linalg.inv(J)
        self._Jt = tuple(tuple(float(v) for v in row) for row in J)
        self._Jit = tuple(tuple(float(v) for v in row) for row in self.J_inv)
        self.q = [float(v) for v in np.asarray(q_BI, dtype=float) / np.linalg.norm(q_BI)]
        self.w = [float(v) for v in w_B_rad_s]
        self.w0 = float(w0_rad_s)
        self.gg = bool(gravity_gradient) and self.w0 > 0.0
        h0 = np.zeros(3) if h_cmg_B_Nms is None else np.asarray(h_cmg_B_Nms, dtype=float)
        hd = np.zeros(3) if h_dot_B_Nm is None else np.asarray(h_dot_B_Nm, dtype=float)
        self.h0 = [float(v) for v in h0]
        self.hd = [float(v) for v in hd]
        self._f = self._make_deriv()
        # ``advance(t, h, mx, my, mz, q0, q1, q2, q3, w1, w2, w3) -> (q0, .., w3)``: one RK4
        # step on plain floats. Without a CMG momentum rate it is one inlined closure.
        self.advance = self._make_advance() if not any(self.hd) else self._advance_stages

    def h_cmg(self, t_s: float) -> np.ndarray:
        return np.array(self.h0) + np.array(self.hd) * t_s

    def _deriv(self, t: float, q0: float, q1: float, q2: float, q3: float, w1: float,
               w2: float, w3: float, m: list[float]) -> tuple[float, ...]:
        """``(dw/dt (3), dq/dt (4))`` at one state (module doc)."""
        return self._f(t, q0, q1, q2, q3, w1, w2, w3, m)

    def _make_deriv(self):
        """The derivative as a closure over the constants (cell variables are the fastest
        reads in CPython; this function is called four times per step)."""
        (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = self._Jt
        (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = self._Jit
        h01, h02, h03 = self.h0
        hd1, hd2, hd3 = self.hd
        gg, w0 = self.gg, self.w0
        g = 3.0 * w0 * w0
        sin, cos = math.sin, math.cos

        def f(t, q0, q1, q2, q3, w1, w2, w3, m):
            L1 = j00 * w1 + j01 * w2 + j02 * w3 + h01 + hd1 * t
            L2 = j10 * w1 + j11 * w2 + j12 * w3 + h02 + hd2 * t
            L3 = j20 * w1 + j21 * w2 + j22 * w3 + h03 + hd3 * t
            m1 = m[0] - (w2 * L3 - w3 * L2) - hd1
            m2 = m[1] - (w3 * L1 - w1 * L3) - hd2
            m3 = m[2] - (w1 * L2 - w2 * L1) - hd3
            if gg:
                th = w0 * t
                vx, vy = sin(th), cos(th)
                # j_B = C_IB^T y'_I (y'_I has no z component).
                a1 = (1 - 2 * (q2 * q2 + q3 * q3)) * vx + 2 * (q1 * q2 + q0 * q3) * vy
                a2 = 2 * (q1 * q2 - q0 * q3) * vx + (1 - 2 * (q1 * q1 + q3 * q3)) * vy
                a3 = 2 * (q1 * q3 + q0 * q2) * vx + 2 * (q2 * q3 - q0 * q1) * vy
                b1 = j00 * a1 + j01 * a2 + j02 * a3
                b2 = j10 * a1 + j11 * a2 + j12 * a3
                b3 = j20 * a1 + j21 * a2 + j22 * a3
                m1 += g * (a2 * b3 - a3 * b2)
                m2 += g * (a3 * b1 - a1 * b3)
                m3 += g * (a1 * b2 - a2 * b1)
            return (
                i00 * m1 + i01 * m2 + i02 * m3,
                i10 * m1 + i11 * m2 + i12 * m3,
                i20 * m1 + i21 * m2 + i22 * m3,
                0.5 * (-q1 * w1 - q2 * w2 - q3 * w3),
                0.5 * (q0 * w1 + q2 * w3 - q3 * w2),
                0.5 * (q0 * w2 - q1 * w3 + q3 * w1),
                0.5 * (q0 * w3 + q1 * w2 - q2 * w1),
            )

        return f

    def _make_advance(self):
        """One RK4 step as a single closure over the constants, state in and out as floats:
        ``advance(t, h, m1, m2, m3, q0, q1, q2, q3, w1, w2, w3) -> (q0, q1, q2, q3, w1, w2, w3)``.

        ``_make_deriv``'s derivative as one ``stage`` closure on floats with the same
        floating-point operations (so the results are the same floats, bit for bit): the
        constant CMG momentum ``h0`` (``dH/dt = 0``: the ``hd`` terms are exact zeros and are
        left out), the orbit angle's sine and cosine computed once for the two mid-step stages,
        repeated products computed once, and ``2 (x) v`` taken as ``x (2 v)`` (doubling is
        exact).
        """
        (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = self._Jt
        (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = self._Jit
        h01, h02, h03 = self.h0
        gg, w0 = self.gg, self.w0
        g = 3.0 * w0 * w0
        sin, cos, sqrt = math.sin, math.cos, math.sqrt

        def stage(gx, gy, mx, my, mz, p0, p1, p2, p3, v1, v2, v3):
            """Derivative at attitude ``p``, rate ``v``; ``(gx, gy)`` the orbit angle's sine and
            cosine (unused without gravity gradient): ``(dw1, dw2, dw3, dq0, dq1, dq2, dq3)``."""
            L1 = j00 * v1 + j01 * v2 + j02 * v3 + h01
            L2 = j10 * v1 + j11 * v2 + j12 * v3 + h02
            L3 = j20 * v1 + j21 * v2 + j22 * v3 + h03
            m1 = mx - (v2 * L3 - v3 * L2)
            m2 = my - (v3 * L1 - v1 * L3)
            m3 = mz - (v1 * L2 - v2 * L1)
            if gg:
                gx2, gy2 = 2.0 * gx, 2.0 * gy
                s33, s12, s03 = p3 * p3, p1 * p2, p0 * p3
                a1 = (1.0 - 2.0 * (p2 * p2 + s33)) * gx + (s12 + s03) * gy2
                a2 = (s12 - s03) * gx2 + (1.0 - 2.0 * (p1 * p1 + s33)) * gy
                a3 = (p1 * p3 + p0 * p2) * gx2 + (p2 * p3 - p0 * p1) * gy2
                b1 = j00 * a1 + j01 * a2 + j02 * a3
                b2 = j10 * a1 + j11 * a2 + j12 * a3
                b3 = j20 * a1 + j21 * a2 + j22 * a3
                m1 += g * (a2 * b3 - a3 * b2)
                m2 += g * (a3 * b1 - a1 * b3)
                m3 += g * (a1 * b2 - a2 * b1)
            return (i00 * m1 + i01 * m2 + i02 * m3,
                    i10 * m1 + i11 * m2 + i12 * m3,
                    i20 * m1 + i21 * m2 + i22 * m3,
                    0.5 * (-p1 * v1 - p2 * v2 - p3 * v3),
                    0.5 * (p0 * v1 + p2 * v3 - p3 * v2),
                    0.5 * (p0 * v2 - p1 * v3 + p3 * v1),
                    0.5 * (p0 * v3 + p1 * v2 - p2 * v1))

        def advance(t, h, mx, my, mz, q0, q1, q2, q3, w1, w2, w3):
            hh = 0.5 * h
            if gg:  # the orbit angle at the start, the middle (two stages) and the end
                sa, ca = sin(w0 * t), cos(w0 * t)
                sb, cb = sin(w0 * (t + hh)), cos(w0 * (t + hh))
                se, ce = sin(w0 * (t + h)), cos(w0 * (t + h))
            else:
                sa = ca = sb = cb = se = ce = 0.0
            aw1, aw2, aw3, aq0, aq1, aq2, aq3 = stage(sa, ca, mx, my, mz,
                                                      q0, q1, q2, q3, w1, w2, w3)
            bw1, bw2, bw3, bq0, bq1, bq2, bq3 = stage(
                sb, cb, mx, my, mz, q0 + hh * aq0, q1 + hh * aq1, q2 + hh * aq2, q3 + hh * aq3,
                w1 + hh * aw1, w2 + hh * aw2, w3 + hh * aw3)
            cw1, cw2, cw3, cq0, cq1, cq2, cq3 = stage(
                sb, cb, mx, my, mz, q0 + hh * bq0, q1 + hh * bq1, q2 + hh * bq2, q3 + hh * bq3,
                w1 + hh * bw1, w2 + hh * bw2, w3 + hh * bw3)
            ew1, ew2, ew3, eq0, eq1, eq2, eq3 = stage(
                se, ce, mx, my, mz, q0 + h * cq0, q1 + h * cq1, q2 + h * cq2, q3 + h * cq3,
                w1 + h * cw1, w2 + h * cw2, w3 + h * cw3)
            s = h / 6.0
            w1 += s * (aw1 + 2.0 * (bw1 + cw1) + ew1)
            w2 += s * (aw2 + 2.0 * (bw2 + cw2) + ew2)
            w3 += s * (aw3 + 2.0 * (bw3 + cw3) + ew3)
            q0 += s * (aq0 + 2.0 * (bq0 + cq0) + eq0)
            q1 += s * (aq1 + 2.0 * (bq1 + cq1) + eq1)
            q2 += s * (aq2 + 2.0 * (bq2 + cq2) + eq2)
            q3 += s * (aq3 + 2.0 * (bq3 + cq3) + eq3)
            inv = 1.0 / sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            return q0 * inv, q1 * inv, q2 * inv, q3 * inv, w1, w2, w3

        return advance

    def step(self, t_s: float, h_s: float, torque_B_Nm: list[float]) -> None:
        """One RK4 step of length ``h_s`` from ``t_s`` with a constant external torque."""
        q0, q1, q2, q3, w1, w2, w3 = self.advance(t_s, h_s, *torque_B_Nm, *self.q, *self.w)
        self.q = [q0, q1, q2, q3]
        self.w = [w1, w2, w3]

    def _advance_stages(self, t_s: float, h_s: float, mx: float, my: float, mz: float,
                        q0: float, q1: float, q2: float, q3: float, w1: float, w2: float,
                        w3: float) -> tuple[float, ...]:
        """``advance`` through ``_deriv``'s four stages (any CMG momentum rate)."""
        d, m = self._f, (mx, my, mz)
        hh = 0.5 * h_s
        th = t_s + hh
        a = d(t_s, q0, q1, q2, q3, w1, w2, w3, m)
        b = d(th, q0 + hh * a[3], q1 + hh * a[4], q2 + hh * a[5], q3 + hh * a[6],
              w1 + hh * a[0], w2 + hh * a[1], w3 + hh * a[2], m)
        c = d(th, q0 + hh * b[3], q1 + hh * b[4], q2 + hh * b[5], q3 + hh * b[6],
              w1 + hh * b[0], w2 + hh * b[1], w3 + hh * b[2], m)
        e = d(t_s + h_s, q0 + h_s * c[3], q1 + h_s * c[4], q2 + h_s * c[5], q3 + h_s * c[6],
              w1 + h_s * c[0], w2 + h_s * c[1], w3 + h_s * c[2], m)
        s = h_s / 6.0
        w1 += s * (a[0] + 2.0 * (b[0] + c[0]) + e[0])
        w2 += s * (a[1] + 2.0 * (b[1] + c[1]) + e[1])
        w3 += s * (a[2] + 2.0 * (b[2] + c[2]) + e[2])
        q0 += s * (a[3] + 2.0 * (b[3] + c[3]) + e[3])
        q1 += s * (a[4] + 2.0 * (b[4] + c[4]) + e[4])
        q2 += s * (a[5] + 2.0 * (b[5] + c[5]) + e[5])
        q3 += s * (a[6] + 2.0 * (b[6] + c[6]) + e[6])
        inv = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        return q0 * inv, q1 * inv, q2 * inv, q3 * inv, w1, w2, w3

    # -- derived quantities (numpy) ---------------------------------------------------------

    @property
    def q_BI(self) -> np.ndarray:
        return np.array(self.q)

    @property
    def w_B_rad_s(self) -> np.ndarray:
        return np.array(self.w)

    def q_BO(self, t_s: float) -> np.ndarray:
        """Body relative to the orbit frame: ``q_OI* (x) q_BI`` (4,), scalar made >= 0."""
        q = quat_mul(quat_conj(q_OI(t_s, self.w0)), self.q_BI)
        return q if q[0] >= 0 else -q

    def w_BO_B_rad_s(self, t_s: float) -> np.ndarray:
        """Body rate relative to the orbit frame, in B: ``w_B - C_BO w_OI^O`` (3,)."""
        C_OB = quat_to_dcm(self.q_BO(t_s))
        return self.w_B_rad_s - C_OB.T @ orbit_rate_O(self.w0)

    def local_vertical_B(self, t_s: float) -> np.ndarray:
        return quat_to_dcm(self.q_BI).T @ local_vertical_I(t_s, self.w0)

    def angular_momentum_I(self, t_s: float) -> np.ndarray:
        """``C_IB (J w + H)`` (3,) N m s, conserved without external torque."""
        return quat_to_dcm(self.q_BI) @ (self.J @ self.w_B_rad_s + self.h_cmg(t_s))

    def kinetic_energy_J(self) -> float:
        w = self.w_B_rad_s
        return 0.5 * float(w @ self.J @ w)
