"""The plant: rigid body, flex modes, thrusters, manifolds, gyro and faults in one pure object.

Deterministic given ``(vehicle, overrides, initial, seed)`` and the sequence of calls; no clock,
no I/O: every time is an argument in seconds. Typical lockstep use by the process shell::

    plant = Plant(vehicle, seed=1, overrides=scenario.plant, initial=scenario.initial)
    for n in range(ticks):
        t_n = n * vehicle.timing.tick_s
        plant.advance_to(t_n)
        sample = plant.gyro_samples_until(t_n)[-1]        # -> SYNC / GYRO
        plant.apply_command(n, plant.apply_time(t_n), on_ms, manifold_open)   # THR_CMD(n)
    truth = plant.truth

Time line of one thruster (``plant.thruster``): a command for tick n opens the valve over
``[t_apply, t_apply + on_ms)``; every change of the valve's target (command, manifold isolation
valve) reaches the thrust ``T_R`` later and then follows the seed 004 eq. 4.1 profile; a fault
changes the target at its own time. A thruster commanded 200 ms in one tick and > 0 in the next
(starting where the previous ends, within 1 us) stays lit with no new rise.

Integration (``advance_to``): fixed steps on the global grid ``k * step_s``, split at gyro
sample times and tick boundaries. Each step gets the *exact* thrust impulse of every thruster
(closed form of the profile), so the step may be much longer than the ms features of the
profile without losing impulse: the force, torque and modal forcing are the exact means over
the step. The rigid body uses RK4 (``plant.dynamics``), the flex modes their exact transition
(``plant.flex``). Mass is constant (fuel is accounted, not fed back).

Initial state (``InitialCfg``): attitude relative to the orbit frame; ``rate_B_deg_s`` is the
body rate relative to the orbit frame (so 0 means holding the orbital attitude; for an orbit
rate of 0 it is the inertial rate).
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from common.scenario import FaultSpec, InitialCfg, PlantOverridesCfg
from common.units import G0_M_S2
from common.vehicle import VehicleArrays, VehicleCfg
from plant.dynamics import RigidBody, orbit_rate_O, quat_to_dcm
from plant.faults import FaultEntry, FaultState
from plant.flex import FlexModes, influence_matrix
from plant.gyro import Gyro, GyroSample
from plant.thruster import (
    CONTINUITY_TOL_S,
    ThrusterBank,
    ThrustProfile,
    allowed_on_ms,
    clamp_on_ms,
)

# Times closer than this are the same instant (float tick arithmetic).
_EPS_S = 1e-9
TICK_RECORDS_KEPT = 600  # two minutes of ticks: enough for any reader between pops

_ZERO3 = (0.0, 0.0, 0.0)

# Event kinds, in processing order at equal times.
_EV_MAN, _EV_CMD, _EV_FAULT, _EV_MARK = 0, 1, 2, 3


@dataclass(frozen=True)
class Truth:
    """The plant's true state at ``t_s`` (for the recording; never on the flight's side).

    Shapes: N thrusters, M manifolds, n flex modes. ``q_BO``/``q_BI`` (4,) scalar-first;
    ``omega_B_rad_s`` (3,) absolute body rate; ``omega_BO_B_rad_s`` (3,) rate relative to the
    orbit frame; ``flex_q``/``flex_qdot`` (n,); ``flex_rate_gyro_B_rad_s`` (3,) the flex part
    of the gyro reading; ``v_O_m_s`` (3,) thrust delta-v resolved in the orbit frame when
    applied; ``dv_B_m_s`` (3,) thrust delta-v integrated in body axes; ``thrust_n`` (N,) actual
    thrust now; ``valve_cmd`` (N,) commanded valve state now; ``manifold_open`` (M,) isolation
    valves as commanded now; ``impulse_Ns`` (N,) and ``fuel_kg`` (N,) cumulative per thruster;
    ``faults`` the faults active now.
    """

    t_s: float
    q_BO: np.ndarray
    q_BI: np.ndarray
    omega_B_rad_s: np.ndarray
    omega_BO_B_rad_s: np.ndarray
    flex_q: np.ndarray
    flex_qdot: np.ndarray
    flex_rate_gyro_B_rad_s: np.ndarray
    v_O_m_s: np.ndarray
    dv_B_m_s: np.ndarray
    thrust_n: np.ndarray
    valve_cmd: np.ndarray
    manifold_open: np.ndarray
    impulse_Ns: np.ndarray
    fuel_kg: np.ndarray
    fuel_total_kg: float
    h_cmg_B_Nms: np.ndarray
    faults: tuple[FaultSpec, ...]


@dataclass(frozen=True)
class TickRecord:
    """One applied tick command and the actual impulse over ``[t_apply_s, t_end_s)``.

    ``on_ms_requested`` (N,) as received, ``on_ms_applied`` (N,) after clamping to the allowed
    set, ``clamped`` (N,) which ones changed; ``impulse_Ns`` (N,) and ``fuel_kg`` (N,) actual,
    measured from this tick's apply time to the next one's (so the tails of a pulse count in
    the tick that follows, as a gyro would see them).
    """

    tick: int
    t_apply_s: float
    t_end_s: float
    on_ms_requested: np.ndarray
    on_ms_applied: np.ndarray
    clamped: np.ndarray
    manifold_open: np.ndarray
    impulse_Ns: np.ndarray
    fuel_kg: np.ndarray


def perturbed_directions(d_B: np.ndarray, angle_deg: float, rng: np.random.Generator
                         ) -> np.ndarray:
    """Each unit direction (N, 3) tilted by exactly ``angle_deg`` toward a random azimuth."""
    out = np.array(d_B, dtype=float)
    a = math.radians(angle_deg)
    for j in range(out.shape[0]):
        v = rng.standard_normal(3)  # drawn even for a zero angle: same stream for any angle
        d = out[j]
        e = v - np.dot(v, d) * d
        ne = np.linalg.norm(e)
        if a == 0.0 or ne < 1e-12:
            continue
        out[j] = math.cos(a) * d + math.sin(a) * e / ne
    return out


class Plant:
    """Pure deterministic plant emulator (module doc).

    ``Plant(vehicle, *, seed=0, overrides=None, initial=None, step_s=None)``; ``step_s``
    defaults to ``overrides.step_s``.
    """

    def __init__(self, vehicle: VehicleCfg, *, seed: int = 0,
                 overrides: PlantOverridesCfg | None = None, initial: InitialCfg | None = None,
                 step_s: float | None = None) -> None:
        self.vehicle = vehicle
        self.overrides = overrides or PlantOverridesCfg()
        self.initial = initial or InitialCfg()
        self.seed = seed
        self.step_s = float(step_s if step_s is not None else self.overrides.step_s)
        if not self.step_s > 0:
            raise ValueError(f"step_s must be > 0, got {self.step_s}")
        self.arrays = VehicleArrays.from_vehicle(vehicle)
        a = self.arrays
        self.n_thr = len(a.names)
        self.n_man = len(a.manifolds)
        ss = np.random.SeedSequence(seed)
        rng_dir, rng_gn, rng_gw, rng_gf, rng_dist = (np.random.Generator(np.random.PCG64(s))
                                                     for s in ss.spawn(5))
        self._rng_dist = rng_dist

        # Actual (truth) thrusters: scale and direction errors (PlantOverridesCfg).
        ov = self.overrides
        scale = np.array([ov.thrust_scale * ov.thrust_scale_per_thruster.get(n, 1.0)
                          for n in a.names])
        self.thrust_actual_n = a.thrust_n * scale
        self.d_actual_B = perturbed_directions(a.d_B, ov.direction_error_deg, rng_dir)
        self.isp_s = np.array([t.isp_s for t in vehicle.thrusters])
        self._isp_g0 = self.isp_s * G0_M_S2  # fuel per newton second: 1 / (Isp g0)
        flex_b = influence_matrix(vehicle.flex_modes, a.names, a.r_B_m, self.d_actual_B)
        P = self.thrust_actual_n[:, None]
        # Per-thruster weights of the exact impulse: force (3), torque (3), modal forcing (n).
        self._weights = np.hstack([self.d_actual_B * P, np.cross(a.r_B_m, self.d_actual_B) * P,
                                   flex_b * P])

        self.profile = ThrustProfile.calibrate(vehicle.thrust_profile,
                                               f"vehicles/{vehicle.name}: thrust_profile")
        self.allowed_on_ms = allowed_on_ms(vehicle.timing)
        self.bank = ThrusterBank(self.n_thr, self.profile)
        self.faults = FaultState(vehicle)
        self.flex = FlexModes(vehicle.flex_modes, flex_b)
        self.gyro = Gyro(vehicle.gyro, (rng_gn, rng_gw, rng_gf))
        self._gyro_integrating = vehicle.gyro.kind == "integrating"

        # Initial attitude and rate relative to the orbit frame (module doc).
        w0 = vehicle.orbit.rate_rad_s
        q_BO0 = self.initial.attitude.quaternion()
        w_BO = np.radians(np.array(self.initial.rate_B_deg_s, dtype=float))
        w_OI_B = quat_to_dcm(q_BO0).T @ orbit_rate_O(w0)
        cmg = vehicle.cmg
        self.body = RigidBody(
            a.J_B_kg_m2, q_BO0, w_BO + w_OI_B, w0_rad_s=w0,
            gravity_gradient=vehicle.orbit.gravity_gradient,
            h_cmg_B_Nms=None if cmg is None else np.array(cmg.h_B_Nms),
            h_dot_B_Nm=None if cmg is None else np.array(cmg.h_dot_B_Nm),
        )
        dist = vehicle.disturbance
        const = self.overrides.disturbance_torque_B_Nm
        self._dist_const = np.array(dist.constant_torque_B_Nm if const is None else const,
                                    dtype=float)
        self._dist_const_l = self._dist_const.tolist()
        self._zero_modes = [0.0] * len(vehicle.flex_modes)
        self._dist_std = float(dist.random_torque_std_Nm)
        # Random torque: piecewise constant over the global grid k * hold (DisturbanceCfg), a
        # fresh N(0, std^2) per axis per interval, drawn in time order; a step's torque is the
        # exact mean over the intervals it overlaps, so the statistics do not depend on step_s.
        self._dist_hold_s = float(dist.random_torque_hold_s)
        self._dist_k = -1
        self._dist_val = [0.0, 0.0, 0.0]

        self.t = 0.0
        self._events: list[tuple[float, int, int, int, int, list[bool]]] = []
        self._ev_seq = 0
        # Command domain (before T_R): the latest command interval of each thruster.
        self._cmd_from = [-math.inf] * self.n_thr
        self._cmd_until = [-math.inf] * self.n_thr
        self._cmd_on_before_from = [False] * self.n_thr
        self._cmd_tokens: list[list[list[bool]]] = [[] for _ in range(self.n_thr)]
        self._man_cmd = np.ones(self.n_man, dtype=bool)
        self._last_apply_s = -math.inf
        # Effective (after T_R) discrete state that sets each thruster's target.
        self._cmd_eff = [False] * self.n_thr
        self._man_eff = [True] * self.n_man
        self._manifold_of = [int(m) for m in a.manifold_of]

        self.impulse_Ns = np.zeros(self.n_thr)
        self.fuel_kg = np.zeros(self.n_thr)
        self.dv_B = [0.0, 0.0, 0.0]
        self.dv_O = [0.0, 0.0, 0.0]
        self._theta_rigid = [0.0, 0.0, 0.0]  # int w_B dt since the last gyro sample
        self._next_sample_k = 0
        self._samples: list[GyroSample] = []
        self._pending_ticks: dict[int, tuple] = {}
        self._open_tick: tuple | None = None
        # Completed tick records until someone pops them; bounded, because the process shells
        # never do (unbounded, this list was the plant's memory growth: ~27 MB per hour).
        self._records: deque[TickRecord] = deque(maxlen=TICK_RECORDS_KEPT)
        self.counters = {"clamped_commands": 0, "late_commands": 0, "steps": 0}

    # ------------------------------------------------------------------ commands

    def apply_time(self, t_tick_s: float) -> float:
        """Apply time of a command for the tick starting at ``t_tick_s``: plus the latency."""
        return t_tick_s + self.overrides.command_latency_ms / 1000.0

    def apply_command(self, tick: int, t_apply_s: float, on_ms: np.ndarray,
                      manifold_open: np.ndarray | None = None) -> np.ndarray:
        """Schedule one tick's valve commands from ``t_apply_s``; return the applied on_ms (N,).

        ``on_ms`` (N,) on-durations in ms (clamped to the allowed set and counted);
        ``manifold_open`` (M,) isolation valve states (None: unchanged). A time already past
        (or before the previous command) is applied now and counted as late.
        """
        req = np.asarray(on_ms, dtype=float).reshape(-1)
        if req.shape[0] != self.n_thr:
            raise ValueError(f"on_ms: expected {self.n_thr} values, got {req.shape[0]}")
        t_apply = float(t_apply_s)
        if t_apply < max(self.t, self._last_apply_s) - _EPS_S:
            self.counters["late_commands"] += 1
            t_apply = max(self.t, self._last_apply_s)
        self._last_apply_s = t_apply
        applied, clamped = clamp_on_ms(req, self.allowed_on_ms)
        self.counters["clamped_commands"] += int(np.count_nonzero(clamped))
        if manifold_open is not None:
            self._command_manifolds(t_apply, np.asarray(manifold_open, dtype=bool).reshape(-1))
        self._command_valves(t_apply, applied / 1000.0)
        self._push(t_apply, _EV_MARK, tick, 0)
        self._pending_ticks[tick] = (tick, t_apply, req.copy(), applied, clamped,
                                     self._man_cmd.copy())
        return applied

    def close_all_valves(self, t_s: float, *, manifolds: bool = False) -> None:
        """Safe action from ``t_s``: every thruster valve commanded closed (and, with
        ``manifolds``, every isolation valve, which also stops a stuck-on thruster)."""
        t = max(float(t_s), self.t)
        if manifolds:
            self._command_manifolds(t, np.zeros(self.n_man, dtype=bool))
        self._command_valves(t, np.zeros(self.n_thr))

    def _command_manifolds(self, t: float, mask: np.ndarray) -> None:
        if mask.shape[0] != self.n_man:
            raise ValueError(f"manifold_open: expected {self.n_man} values, got {mask.shape[0]}")
        for m in range(self.n_man):
            if bool(mask[m]) != bool(self._man_cmd[m]):
                self._man_cmd[m] = bool(mask[m])
                self._push(t + self.profile.t_r_s, _EV_MAN, m, int(mask[m]))

    def _command_valves(self, t: float, tau_s: np.ndarray) -> None:
        t_r = self.profile.t_r_s
        tol = CONTINUITY_TOL_S
        c_from, c_until, tokens = self._cmd_from, self._cmd_until, self._cmd_tokens
        t_lo = t - tol
        for j, tau in enumerate(tau_s.tolist()):
            if tau <= 0 and c_until[j] < t_lo and (c_from[j] < t_lo or abs(c_from[j] - t) > tol):
                continue  # off before and off now: nothing to change (the common case)
            same_time = abs(c_from[j] - t) <= tol
            # Commanded state just before t (a repeated command at the same time replaces the
            # previous one and sees the state before it).
            if same_time:
                was_on = self._cmd_on_before_from[j]
            else:
                was_on = c_from[j] < t and c_until[j] >= t - tol
            # This command supersedes every scheduled change from t on.
            if tokens[j]:
                keep = []
                for tok in tokens[j]:
                    if tok[1] >= t + t_r - tol:
                        tok[0] = False
                    elif tok[0]:
                        keep.append(tok)
                tokens[j] = keep
            if tau > 0:
                if not was_on:
                    self._push_cmd(j, t + t_r, True)
                    c_from[j] = t
                    self._cmd_on_before_from[j] = False
                self._push_cmd(j, t + tau + t_r, False)
                c_until[j] = t + tau
            elif was_on:
                self._push_cmd(j, t + t_r, False)
                c_until[j] = t
            elif same_time:
                c_until[j] = t  # a replaced command at t: nothing left of it

    def _push_cmd(self, j: int, t_eff: float, on: bool) -> None:
        tok = [True, t_eff]
        self._cmd_tokens[j].append(tok)
        heapq.heappush(self._events, (t_eff, _EV_CMD, self._ev_seq, j, int(on), tok))
        self._ev_seq += 1

    def _push(self, t: float, kind: int, idx: int, val: int, tok: list | None = None) -> None:
        heapq.heappush(self._events, (t, kind, self._ev_seq, idx, val, tok or [True, t]))
        self._ev_seq += 1

    # ------------------------------------------------------------------ faults

    def inject(self, fault: FaultSpec | dict) -> FaultEntry:
        """Validate (``FaultCommandError`` if invalid) and schedule a fault (``plant.faults``)."""
        entry = self.faults.inject(fault, self.t)
        self._schedule_fault_events(entry)
        return entry

    def clear_faults(self, thruster: str | None = None, t_s: float | None = None
                     ) -> list[FaultEntry]:
        """End every fault (or those of ``thruster``) at ``t_s`` (default: now)."""
        t = self.t if t_s is None else max(float(t_s), self.t)
        changed = self.faults.clear(t, thruster)
        for e in changed:
            self._schedule_fault_events(e)
        return changed

    def _schedule_fault_events(self, entry: FaultEntry) -> None:
        if entry.spec.thruster is None:
            return
        j = self.vehicle.thruster_index(entry.spec.thruster)
        for t in self.faults.thruster_event_times(entry):
            self._push(max(t, self.t), _EV_FAULT, j, 0)

    # ------------------------------------------------------------------ events

    def _target(self, j: int, t: float) -> float:
        if not self._man_eff[self._manifold_of[j]]:
            return 0.0
        if not self.faults.entries:  # no faults: gain 1, nothing stuck
            return 1.0 if self._cmd_eff[j] else 0.0
        gain, stuck = self.faults.thruster_state(j, t)
        return max(gain if self._cmd_eff[j] else 0.0, stuck)

    def _process_events(self, t_upto: float, marks: bool) -> None:
        ev = self._events
        while ev and ev[0][0] <= t_upto + _EPS_S:
            if not marks and ev[0][1] == _EV_MARK:
                return
            t, kind, _, idx, val, tok = heapq.heappop(ev)
            if not tok[0]:
                continue
            tok[0] = False  # done: a later command has nothing to cancel here (and drops it)
            if kind == _EV_CMD:
                self._cmd_eff[idx] = val == 1
                self.bank.set_target(idx, t, self._target(idx, t))
            elif kind == _EV_MAN:
                self._man_eff[idx] = bool(val)
                for j in np.flatnonzero(self.arrays.manifold_of == idx).tolist():
                    self.bank.set_target(j, t, self._target(j, t))
            elif kind == _EV_FAULT:
                self.bank.set_target(idx, t, self._target(idx, t))
            else:
                self._tick_mark(idx, t)

    def _tick_mark(self, tick: int, t: float) -> None:
        if self._open_tick is not None:
            (n, t0, req, app, clp, man, imp0, fuel0) = self._open_tick
            self._records.append(TickRecord(n, t0, t, req, app, clp, man,
                                            self.impulse_Ns - imp0, self.fuel_kg - fuel0))
        info = self._pending_ticks.pop(tick, None)
        if info is not None:
            self._open_tick = (*info, self.impulse_Ns.copy(), self.fuel_kg.copy())

    def _next_break(self, t_end: float) -> float:
        t1 = min(t_end, self.gyro.sample_time(self._next_sample_k))
        for e in self._events:  # marks are few: a linear scan is cheaper than a second heap
            if e[1] == _EV_MARK and e[5][0] and e[0] > self.t + _EPS_S:
                t1 = min(t1, e[0])
        return t1

    # ------------------------------------------------------------------ integration

    def advance_to(self, t_s: float) -> list[GyroSample]:
        """Integrate to ``t_s``; return the gyro samples measured on the way (also queued for
        ``gyro_samples_until``)."""
        t_end = float(t_s)
        if t_end < self.t - _EPS_S:
            raise ValueError(f"advance_to: time goes forward only ({t_end} < {self.t})")
        new: list[GyroSample] = []
        while True:
            self._process_events(self.t, marks=True)
            while self.gyro.sample_time(self._next_sample_k) <= self.t + _EPS_S:
                new.append(self._take_sample())
            if self.t >= t_end - _EPS_S:
                break
            t1 = self._next_break(t_end)
            self._integrate_chunk(self.t, t1)
            self.t = t1
        self._samples.extend(new)
        return new

    def _grid(self, t0: float, t1: float) -> list[float]:
        """Step boundaries of ``[t0, t1]``: the ends and the global grid points between."""
        h = self.step_s
        k0 = math.floor(t0 / h + 1e-6) + 1
        k1 = math.ceil(t1 / h - 1e-6) - 1
        return [t0, *[k * h for k in range(k0, k1 + 1)], t1]

    def _random_torque_mean(self, a: float, b: float) -> list[float]:
        """Mean of the held random torque over ``[a, b]`` (3 floats); draws the intervals up to
        ``b`` in order (the grid ``k * hold`` is global: same torque history for any step)."""
        T = self._dist_hold_s
        acc = [0.0, 0.0, 0.0]
        t = a
        while b - t > _EPS_S:
            k = int(math.floor(t / T + 1e-9))
            while self._dist_k < k:
                self._dist_k += 1
                self._dist_val = (self._rng_dist.standard_normal(3) * self._dist_std).tolist()
            end = min(b, (k + 1) * T)
            w = end - t
            v = self._dist_val
            acc = [acc[0] + v[0] * w, acc[1] + v[1] * w, acc[2] + v[2] * w]
            t = end
        d = b - a
        return [x / d for x in acc] if d > 0 else acc

    def _integrate_chunk(self, t0: float, t1: float) -> None:
        """Integrate ``[t0, t1]`` (no event inside) on the step grid: the exact mean thrust of
        every step from one vectorised call, then the sequential part with the state in local
        floats (RK4 ``body.advance``, flex transition, delta-v, gyro angle)."""
        self.bank.start_chunk(t0)
        self._process_events(t1, marks=False)
        grid_l = self._grid(t0, t1)
        n_steps = len(grid_l) - 1
        dts_l = [grid_l[k + 1] - grid_l[k] for k in range(n_steps)]
        impulse = self.bank.impulse_on_grid(grid_l, self._weights)
        if impulse is None:  # no thrust at all in the chunk: every mean is an exact zero
            torque_l = [self._dist_const_l] * n_steps
            force_l = [_ZERO3] * n_steps
            flex_l = [self._zero_modes] * n_steps
        else:
            per_step, per_thr = impulse
            mean = per_step / np.array(dts_l)[:, None]  # exact mean force, torque, modal forcing
            imp = per_thr * self.thrust_actual_n
            self.impulse_Ns += imp
            self.fuel_kg += imp / self._isp_g0
            torque_l = (mean[:, 3:6] + self._dist_const).tolist()
            force_l = mean[:, 0:3].tolist()
            flex_l = mean[:, 6:].tolist()
        if self._dist_std > 0:
            noise = [self._random_torque_mean(grid_l[k], grid_l[k + 1]) for k in range(n_steps)]
            torque_l = (np.array(torque_l) + np.array(noise)).tolist()
        body, flex = self.body, self.flex
        fq, fqd = flex.q, flex.qd
        if flex.n:
            h_common = self.step_s
            mats_common = flex.flat_mats(h_common)
            mats_l = [mats_common if abs(h - h_common) < 1e-12 else flex.flat_mats(h)
                      for h in dts_l]
        else:
            mats_l = [()] * n_steps
        w0 = body.w0
        inv_m = 1.0 / self.arrays.mass_kg
        advance = body.advance
        cos, sin = math.cos, math.sin
        q0, q1, q2, q3 = body.q
        w1, w2, w3 = body.w
        dvb0, dvb1, dvb2 = self.dv_B
        dvo0, dvo1, dvo2 = self.dv_O
        tw0 = tw1 = tw2 = 0.0
        # Step k starts at grid_l[k] (the grid has one more point: the end of the chunk).
        for t, h, (mx, my, mz), (fx, fy, fz), u, mats in zip(
                grid_l, dts_l, torque_l, force_l, flex_l, mats_l, strict=False):
            n0, n1, n2, n3, v1, v2, v3 = advance(t, h, mx, my, mz, q0, q1, q2, q3, w1, w2, w3)
            hh = 0.5 * h
            tw0 += hh * (w1 + v1)
            tw1 += hh * (w2 + v2)
            tw2 += hh * (w3 + v3)
            i = 0
            for p11, p12, p21, p22, g1, g2 in mats:  # flex modes: exact transition
                a, b, ui = fq[i], fqd[i], u[i]
                fq[i] = p11 * a + p12 * b + g1 * ui
                fqd[i] = p21 * a + p22 * b + g2 * ui
                i += 1
            if fx != 0.0 or fy != 0.0 or fz != 0.0:
                # Delta-v: body axes, and the orbit frame with the mid-step attitude (the
                # normalised mean of the end quaternions; steps are small).
                sm = inv_m * h
                a1, a2, a3 = fx * sm, fy * sm, fz * sm
                dvb0 += a1
                dvb1 += a2
                dvb2 += a3
                w, x, y, z = q0 + n0, q1 + n1, q2 + n2, q3 + n3
                kq = 2.0 / (w * w + x * x + y * y + z * z)
                u1 = ((1.0 - kq * (y * y + z * z)) * a1 + kq * (x * y - w * z) * a2
                      + kq * (x * z + w * y) * a3)
                u2 = (kq * (x * y + w * z) * a1 + (1.0 - kq * (x * x + z * z)) * a2
                      + kq * (y * z - w * x) * a3)
                u3 = (kq * (x * z - w * y) * a1 + kq * (y * z + w * x) * a2
                      + (1.0 - kq * (x * x + y * y)) * a3)
                th = w0 * (t + hh)
                c, sn = cos(th), sin(th)
                # Rows of C_OI are x', y', z' in inertial axes (plant.dynamics module doc).
                dvo0 += c * u1 - sn * u2
                dvo1 += sn * u1 + c * u2
                dvo2 += u3
            q0, q1, q2, q3, w1, w2, w3 = n0, n1, n2, n3, v1, v2, v3
        body.q = [q0, q1, q2, q3]
        body.w = [w1, w2, w3]
        self.dv_B = [dvb0, dvb1, dvb2]
        self.dv_O = [dvo0, dvo1, dvo2]
        th = self._theta_rigid
        th[0] += tw0
        th[1] += tw1
        th[2] += tw2
        self.counters["steps"] += n_steps

    def _take_sample(self) -> GyroSample:
        t = self.gyro.sample_time(self._next_sample_k)
        self._next_sample_k += 1
        flex = self.flex
        angle = flex.gyro_angle_B().tolist() if self._gyro_integrating else _ZERO3
        s = self.gyro.measure(t, self.body.w, flex.gyro_rate_B().tolist(), self._theta_rigid,
                              angle, self.faults)
        self._theta_rigid = [0.0, 0.0, 0.0]
        return s

    # ------------------------------------------------------------------ outputs

    def gyro_samples_until(self, t_s: float) -> list[GyroSample]:
        """Pop the queued samples available (``t_avail_s``) by ``t_s``, oldest first."""
        out = [s for s in self._samples if s.t_avail_s <= t_s + _EPS_S]
        self._samples = [s for s in self._samples if s.t_avail_s > t_s + _EPS_S]
        return out

    def pop_tick_records(self) -> list[TickRecord]:
        """Completed tick records (a tick completes when the next command's apply time is
        reached), oldest first; at most the last ``TICK_RECORDS_KEPT``."""
        out = list(self._records)
        self._records.clear()
        return out

    def thrust_now_n(self) -> np.ndarray:
        """Actual thrust (N,) newtons at the current time."""
        return np.array([self.bank.level(j, self.t) for j in range(self.n_thr)]
                        ) * self.thrust_actual_n

    @property
    def truth(self) -> Truth:
        t = self.t
        b = self.body
        valve = np.array([self._cmd_from[j] <= t + _EPS_S < self._cmd_until[j]
                          for j in range(self.n_thr)])
        return Truth(
            t_s=t,
            q_BO=b.q_BO(t),
            q_BI=b.q_BI,
            omega_B_rad_s=b.w_B_rad_s,
            omega_BO_B_rad_s=b.w_BO_B_rad_s(t),
            flex_q=np.array(self.flex.q),
            flex_qdot=np.array(self.flex.qd),
            flex_rate_gyro_B_rad_s=self.flex.gyro_rate_B(),
            v_O_m_s=np.array(self.dv_O),
            dv_B_m_s=np.array(self.dv_B),
            thrust_n=self.thrust_now_n(),
            valve_cmd=valve,
            manifold_open=self._man_cmd.copy(),
            impulse_Ns=self.impulse_Ns.copy(),
            fuel_kg=self.fuel_kg.copy(),
            fuel_total_kg=float(self.fuel_kg.sum()),
            h_cmg_B_Nms=b.h_cmg(t),
            faults=tuple(self.faults.active(t)),
        )
