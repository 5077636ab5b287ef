"""The shipped vehicles have the layout docs/design.md section 7 and their seeds ask for.

orel (seed 004): 30 thrusters in three belts and two manifolds of 14 and 16, each manifold alone
able to turn the craft both ways about every axis; roll pairs that make a nearly pure couple.
iss_rs (seed 003): SM thrusters in manifolds I and II, a Progress whose "+roll" thruster has
about the SM "+yaw" thruster's yaw effect but a clearly different direction; gravity gradient at
w0 = 0.001162 rad/s; flex modes. Feasibility of a sense is an LP (scipy linprog): is there
tau >= 0 with sum_n mu_n tau_n = +/- e_k over the thrusters allowed to fire?
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from hil.config import VehicleArrays, VehicleCfg, load_vehicle

SHIPPED = ("generic", "kalman_cube", "orel", "iss_rs")
SENSES = [(k, s) for k in range(3) for s in (1.0, -1.0)]
AXIS = "xyz"


def _arrays(name: str) -> tuple[VehicleCfg, VehicleArrays]:
    v = load_vehicle(name)
    return v, VehicleArrays.from_vehicle(v)


def _index(a: VehicleArrays, names: list[str] | tuple[str, ...]) -> list[int]:
    return [a.names.index(n) for n in names]


def _feasible(vectors: np.ndarray, target: np.ndarray) -> bool:
    """Is target = sum_n vectors[n] tau_n for some tau >= 0? (vectors (N, 3))"""
    n = vectors.shape[0]
    res = linprog(
        np.ones(n), A_eq=vectors.T, b_eq=target, bounds=[(0.0, None)] * n, method="highs"
    )
    return res.status == 0


def _missing_senses(vectors: np.ndarray) -> list[str]:
    # Scale to order one so the LP tolerances do not depend on the vehicle's size.
    v = vectors / np.abs(vectors).max()
    out = []
    for k, s in SENSES:
        target = np.zeros(3)
        target[k] = s
        if not _feasible(v, target):
            out.append(f"{'+' if s > 0 else '-'}{AXIS[k]}")
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _angle_deg(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(_unit(u) @ _unit(v), -1.0, 1.0))))


def _manifold_members(a: VehicleArrays, manifold: str) -> list[int]:
    m = a.manifolds.index(manifold)
    return [i for i in range(len(a.names)) if a.manifold_of[i] == m]


# --------------------------------------------------------------------------- every vehicle


@pytest.mark.parametrize("name", SHIPPED)
def test_vehicle_loads(name: str) -> None:
    v = load_vehicle(name)
    assert v.name == name


@pytest.mark.parametrize("name", SHIPPED)
def test_all_thrusters_turn_both_ways_about_every_axis(name: str) -> None:
    _, a = _arrays(name)
    assert _missing_senses(a.mu_B_rad_s2) == []


@pytest.mark.parametrize("name", ["orel", "iss_rs"])
def test_no_two_thrusters_share_a_direction(name: str) -> None:
    # Seed 003's limit: thrusters with the same unit acceleration cannot be told apart. The
    # shipped layouts keep every pair clearly above the detector's grouping angle.
    v, a = _arrays(name)
    e = a.mu_B_rad_s2 / np.linalg.norm(a.mu_B_rad_s2, axis=1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(e @ e.T, -1.0, 1.0)))
    np.fill_diagonal(ang, 180.0)
    i, j = np.unravel_index(np.argmin(ang), ang.shape)
    assert ang[i, j] > 2.0 * v.flight.detector.same_direction_deg, (a.names[i], a.names[j])


@pytest.mark.parametrize("name", ["orel", "iss_rs"])
def test_one_tick_of_any_thruster_clears_the_detector_dead_zone(name: str) -> None:
    # A thruster stuck on for a whole tick must move the rate by more than the dead zone,
    # otherwise the residual detector can never see it (docs/design.md 6.4 step 2).
    v, a = _arrays(name)
    one_tick = np.linalg.norm(a.mu_B_rad_s2, axis=1) * v.timing.tick_s
    assert one_tick.min() > 1.5 * v.flight.detector.dead_zone_rad_s, a.names[int(one_tick.argmin())]


# --------------------------------------------------------------------------- orel (seed 004)

OREL_AFT = [str(n) for n in range(1, 9)]
OREL_MINUS_X = [str(n) for n in range(9, 15)]
OREL_ROLL = [str(n) for n in range(15, 23)]
OREL_MIDDLE = [str(n) for n in range(23, 31)]
OREL_PAIRS = [("15", "19"), ("17", "21"), ("16", "20"), ("18", "22")]


def test_orel_thrusters_and_manifolds() -> None:
    v, a = _arrays("orel")
    assert a.names == tuple(str(n) for n in range(1, 31))
    assert np.allclose(a.thrust_n, 248.0)  # seed 004: DPO of ~248 N
    sizes = sorted(len(_manifold_members(a, m)) for m in a.manifolds)
    assert sizes == [14, 16]  # seed 004: manifolds of 14 and 16
    # seed 004 section 5: DPO1, 3, 5, 7 on the first manifold; DPO9, 10, 12, 13 on the second
    assert {v.thrusters[i].manifold for i in _index(a, ["1", "3", "5", "7"])} == {"I"}
    assert {v.thrusters[i].manifold for i in _index(a, ["9", "10", "12", "13"])} == {"II"}


def test_orel_roll_pairs_are_nearly_pure_roll() -> None:
    v, a = _arrays("orel")
    assert [tuple(p) for p in v.flight.allocator.roll_pairs] == OREL_PAIRS
    signs = []
    for p, q in OREL_PAIRS:
        i, j = _index(a, [p, q])
        mu = a.mu_B_rad_s2[i] + a.mu_B_rad_s2[j]
        assert abs(mu[0]) > 20.0 * max(abs(mu[1]), abs(mu[2])), (p, q, mu)
        # the two forces cancel: no translation (seed 004 section 3)
        assert np.linalg.norm(a.d_B[i] + a.d_B[j]) < 1e-3
        signs.append(np.sign(mu[0]))
        # both members of a pair on the same manifold, so closing one manifold keeps the other's
        assert v.thrusters[i].manifold == v.thrusters[j].manifold
    assert sorted(signs) == [-1.0, -1.0, 1.0, 1.0]
    # each manifold holds one +roll and one -roll pair
    for m in a.manifolds:
        pair_signs = {
            np.sign(a.mu_B_rad_s2[a.names.index(p)][0] + a.mu_B_rad_s2[a.names.index(q)][0])
            for p, q in OREL_PAIRS
            if v.thrusters[a.names.index(p)].manifold == m
        }
        assert pair_signs == {-1.0, 1.0}, m


def test_orel_belt_roles() -> None:
    _, a = _arrays("orel")
    torque_nm = np.linalg.norm(a.torque_per_n_B * a.thrust_n[:, None], axis=1)
    aft, minus_x = _index(a, OREL_AFT), _index(a, OREL_MINUS_X)
    roll, middle = _index(a, OREL_ROLL), _index(a, OREL_MIDDLE)
    assert np.all(a.d_B[aft, 0] > 0.9)  # aft belt: +X thrust
    assert np.all(a.d_B[minus_x, 0] < -0.9)  # front 9-14: -X thrust
    # aft and -X thrusters torque pitch and yaw (y, z) much more than roll
    mu = a.mu_B_rad_s2
    assert np.all(np.abs(mu[aft + minus_x, 0]) < 0.1 * np.linalg.norm(mu[aft + minus_x], axis=1))
    # roll thrusters: roll dominates each single one (the belt is near the centre of mass)
    assert np.all(np.abs(mu[roll, 0]) > 0.9 * np.linalg.norm(mu[roll], axis=1))
    # middle belt: force mostly in Y/Z, torque small next to every other thruster's
    assert np.all(np.linalg.norm(a.d_B[middle, 1:], axis=1) > 0.99)
    others = [i for i in range(30) if i not in middle]
    assert torque_nm[middle].max() < 0.3 * torque_nm[others].min()


def test_orel_middle_belt_pairs_as_in_seed() -> None:
    # seed 004 section 5: DPO23 with DPO24 pushes -Y and -Z; DPO23 with DPO30 pushes -Y only
    _, a = _arrays("orel")
    i23, i24, i30 = _index(a, ["23", "24", "30"])
    f = a.d_B[i23] + a.d_B[i24]
    assert f[1] < -0.5 and f[2] < -0.5
    f = a.d_B[i23] + a.d_B[i30]
    assert f[1] < -1.5 and abs(f[0]) < 0.05 and abs(f[2]) < 0.05


@pytest.mark.parametrize("manifold", ["I", "II"])
def test_orel_each_manifold_alone_controls_every_sense(manifold: str) -> None:
    _, a = _arrays("orel")
    idx = _manifold_members(a, manifold)
    assert _missing_senses(a.mu_B_rad_s2[idx]) == []
    # and translation along +/-X, +/-Y, +/-Z (seed 004: either manifold solves the spatial task)
    assert _missing_senses(a.d_B[idx]) == []


def test_orel_centre_of_mass_slightly_off_axis_toward_plus_y_and_z() -> None:
    v = load_vehicle("orel")
    _, y, z = v.com_m
    assert y > 0 and z > 0
    assert np.hypot(y, z) < 0.2


# --------------------------------------------------------------------------- iss_rs (seed 003)

PROGRESS_ROLL = "P2+roll_I"
SM_YAW = "SM+yaw_I"


def test_iss_environment() -> None:
    v = load_vehicle("iss_rs")
    assert v.orbit.gravity_gradient
    assert v.orbit.rate_rad_s == pytest.approx(0.001162)  # seed 003 eq. 9
    assert len(v.flex_modes) >= 1
    for m in v.flex_modes:
        assert 0.05 < m.freq_hz < 1.0
        assert np.linalg.norm(m.gyro_phi) > 0
    assert min(np.linalg.eigvalsh(np.array(v.inertia_B_kg_m2))) > 1e7  # station scale
    assert v.flight.detector.threshold_on == 0.5  # seed 003
    assert v.flight.detector.threshold_off == 0.5
    assert v.cmg is not None


def test_iss_progress_roll_and_sm_yaw_alike_in_yaw_apart_in_direction() -> None:
    # seed 003 fig. 5-6: almost equal yaw effects, so the detector must use the directions
    _, a = _arrays("iss_rs")
    p, s = (a.mu_B_rad_s2[i] for i in _index(a, [PROGRESS_ROLL, SM_YAW]))
    assert p[0] > 0 and s[1] > 0 and p[1] > 0
    assert abs(p[1] - s[1]) < 0.3 * max(abs(p[1]), abs(s[1]))
    assert _angle_deg(p, s) > 10.0
    # the SM +yaw thruster acts mostly on yaw; the Progress one mostly off its roll channel
    assert abs(_unit(s)[1]) > 0.9
    assert abs(p[0]) <= max(abs(p[1]), abs(p[2]))


def test_iss_progress_thrusters_act_off_axis() -> None:
    # seed 003: Progress thrusters' accelerations are mostly not along the control axes
    _, a = _arrays("iss_rs")
    prog = [i for i, n in enumerate(a.names) if n.startswith("P2")]
    assert len(prog) >= 4
    for i in prog:
        assert np.abs(_unit(a.mu_B_rad_s2[i])).max() < np.cos(np.radians(30.0)), a.names[i]


@pytest.mark.parametrize("manifold", ["I", "II"])
def test_iss_each_sm_manifold_alone_controls_pitch_yaw_and_roll(manifold: str) -> None:
    _, a = _arrays("iss_rs")
    idx = _manifold_members(a, manifold)
    assert all(a.names[i].startswith("SM") for i in idx)
    assert _missing_senses(a.mu_B_rad_s2[idx]) == []


def test_iss_sm_roll_pairs_are_couples() -> None:
    # seed 003 fig. 1: +K1/+K2 and -K1/-K2 are pairs for +roll and -roll in each manifold
    _, a = _arrays("iss_rs")
    for m in ("I", "II"):
        for sense, sign in (("+", 1.0), ("-", -1.0)):
            i, j = _index(a, [f"SM{sense}roll1_{m}", f"SM{sense}roll2_{m}"])
            mu = a.mu_B_rad_s2[i] + a.mu_B_rad_s2[j]
            assert np.sign(mu[0]) == sign
            assert abs(mu[0]) > 20.0 * max(abs(mu[1]), abs(mu[2]))
