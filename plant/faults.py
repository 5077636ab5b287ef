"""Fault state of the plant (docs/design.md 5.6): what is injected, when it is active, its effect.

A fault is a validated ``FaultSpec`` with an activity window ``[t_on_s, t_off_s)``
(``t_off_s = clear_t_s`` or infinity until cleared). Effects, queried by time:

* ``stuck_on`` (fraction f, default 1): the valve does not close fully; commanded off, the
  thruster gives ``f`` of its thrust; commanded on, full thrust. Closing its manifold stops it.
* ``fail_to_fire``: the valve does not open: no thrust when commanded.
* ``degraded`` (fraction d): commanded on, the thruster gives ``d`` of its thrust.
* gyro faults (``axis`` 0..2 or all axes): ``gyro_spike`` adds ``magnitude_rad_s`` to the
  first sample measured at or after ``t_s`` (one bad sample); ``gyro_bias_step`` adds it to the
  bias while active; ``gyro_frozen`` repeats the last output; ``gyro_noise`` adds white noise of
  standard deviation ``magnitude_rad_s``.
* bus faults (``bus_drop``, ``bus_delay``, ``bus_corrupt``, ``node_silent``) are kept and
  reported (``active_bus_faults``) for the process shell; the physics ignores them.

Validation against the vehicle raises ``FaultCommandError`` with one line of the form
``fault: thruster: expected one of ['X+', 'X-'], got 'X9'``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from common.errors import ConfigError
from common.scenario import BUS_FAULTS, GYRO_FAULTS, THRUSTER_FAULTS, FaultSpec
from common.schema import config_error
from common.vehicle import VehicleCfg
from plant.errors import FaultCommandError


def _fault_error(field: str, expected: str, found: object) -> FaultCommandError:
    return FaultCommandError(f"fault: {field}: expected {expected}, got {found!r}")


def validate_fault(vehicle: VehicleCfg, fault: FaultSpec | Mapping[str, Any]) -> FaultSpec:
    """A ``FaultSpec`` checked against ``vehicle``; raise ``FaultCommandError`` if invalid.

    ``fault`` may be a raw mapping (from the fault panel): the ``FaultSpec`` model checks the
    field types and ranges (fraction in [0, 1], times >= 0), then the vehicle check follows.
    """
    if not isinstance(fault, FaultSpec):
        raw = dict(fault)
        # Check the vehicle-independent ranges first so the user sees the most direct error.
        t = raw.get("t_s")
        if isinstance(t, int | float) and t < 0:
            raise _fault_error("t_s", ">= 0", t)
        fr = raw.get("fraction")
        if isinstance(fr, int | float) and not 0.0 <= fr <= 1.0:
            raise _fault_error("fraction", "a fraction in [0, 1]", fr)
        try:
            fault = FaultSpec.model_validate(raw)
        except ValidationError as exc:
            err: ConfigError = config_error("fault", exc)
            raise FaultCommandError(str(err)) from None
    names = [t.name for t in vehicle.thrusters]
    if fault.thruster is not None and fault.thruster not in names:
        raise _fault_error("thruster", f"one of {names}", fault.thruster)
    if fault.kind in THRUSTER_FAULTS and fault.thruster is None:
        raise _fault_error("thruster", f"one of {names}", None)
    if fault.kind in GYRO_FAULTS and fault.magnitude_rad_s is not None:
        if not math.isfinite(fault.magnitude_rad_s):
            raise _fault_error("magnitude_rad_s", "a finite number", fault.magnitude_rad_s)
        if fault.kind == "gyro_noise" and fault.magnitude_rad_s < 0:
            raise _fault_error("magnitude_rad_s", ">= 0 (a standard deviation)",
                               fault.magnitude_rad_s)
    return fault


@dataclass
class FaultEntry:
    """One injected fault and its activity window ``[t_on_s, t_off_s)``."""

    id: int
    spec: FaultSpec
    t_on_s: float
    t_off_s: float
    spike_used: bool = False

    def active(self, t_s: float) -> bool:
        return self.t_on_s <= t_s < self.t_off_s


class FaultState:
    """Every fault injected into one plant, with time-indexed queries (pure, no clock)."""

    def __init__(self, vehicle: VehicleCfg) -> None:
        self.vehicle = vehicle
        self.names = [t.name for t in vehicle.thrusters]
        self.entries: list[FaultEntry] = []
        self._next_id = 0
        # False until a gyro fault is injected: the sensor then skips the fault queries.
        self.has_gyro_faults = False

    def inject(self, fault: FaultSpec | Mapping[str, Any], t_now_s: float = 0.0) -> FaultEntry:
        """Validate and add ``fault``; a start time in the past becomes ``t_now_s``."""
        spec = validate_fault(self.vehicle, fault)
        t_on = max(float(spec.t_s), t_now_s)
        t_off = math.inf if spec.clear_t_s is None else max(float(spec.clear_t_s), t_on)
        entry = FaultEntry(self._next_id, spec, t_on, t_off)
        self._next_id += 1
        self.entries.append(entry)
        if spec.kind in GYRO_FAULTS:
            self.has_gyro_faults = True
        return entry

    def clear(self, t_s: float, thruster: str | None = None) -> list[FaultEntry]:
        """End at ``t_s`` every fault (or every fault of ``thruster``); return those changed.

        Faults scheduled to start after ``t_s`` are removed as well (they never happen).
        """
        if thruster is not None and thruster not in self.names:
            raise _fault_error("thruster", f"one of {self.names}", thruster)
        changed = []
        for e in self.entries:
            if thruster is not None and e.spec.thruster != thruster:
                continue
            if e.t_off_s > t_s:
                e.t_off_s = max(t_s, e.t_on_s)
                changed.append(e)
        return changed

    # -- queries ----------------------------------------------------------------------------

    def active(self, t_s: float) -> list[FaultSpec]:
        return [e.spec for e in self.entries if e.active(t_s)]

    def thruster_state(self, j: int, t_s: float) -> tuple[float, float]:
        """``(on_gain, stuck_fraction)`` of thruster ``j`` at ``t_s``.

        ``on_gain``: normalised thrust when commanded on (1 nominal, d degraded, 0 fail to
        fire; the smallest wins). ``stuck_fraction``: thrust when commanded off (0 nominal).
        """
        gain, stuck = 1.0, 0.0
        if not self.entries:
            return gain, stuck
        name = self.names[j]
        for e in self.entries:
            if e.spec.thruster != name or not e.active(t_s):
                continue
            k = e.spec.kind
            if k == "stuck_on":
                stuck = max(stuck, e.spec.effective_fraction)
            elif k in ("fail_to_fire", "degraded"):
                gain = min(gain, e.spec.effective_fraction)
        return gain, stuck

    def thruster_event_times(self, entry: FaultEntry) -> list[float]:
        """Times at which ``entry`` changes a thruster's target (start and end)."""
        if entry.spec.kind not in THRUSTER_FAULTS:
            return []
        return [t for t in (entry.t_on_s, entry.t_off_s) if math.isfinite(t)]

    def _axes(self, spec: FaultSpec) -> np.ndarray:
        m = np.zeros(3)
        if spec.axis is None:
            m[:] = 1.0
        else:
            m[spec.axis] = 1.0
        return m

    def gyro_bias_step(self, t_s: float) -> np.ndarray:
        """Added bias (3,) rad/s from active ``gyro_bias_step`` faults."""
        out = np.zeros(3)
        for e in self.entries:
            if e.spec.kind == "gyro_bias_step" and e.active(t_s):
                out += self._axes(e.spec) * float(e.spec.magnitude_rad_s or 0.0)
        return out

    def gyro_extra_noise(self, t_s: float) -> np.ndarray:
        """Extra white-noise standard deviation (3,) rad/s from ``gyro_noise`` faults."""
        var = np.zeros(3)
        for e in self.entries:
            if e.spec.kind == "gyro_noise" and e.active(t_s):
                var += self._axes(e.spec) * float(e.spec.magnitude_rad_s or 0.0) ** 2
        return np.sqrt(var)

    def gyro_frozen(self, t_s: float) -> bool:
        return any(e.spec.kind == "gyro_frozen" and e.active(t_s) for e in self.entries)

    def take_gyro_spike(self, t_s: float) -> np.ndarray:
        """Spike (3,) for the sample measured at ``t_s``; each spike fault fires once."""
        out = np.zeros(3)
        for e in self.entries:
            if (e.spec.kind == "gyro_spike" and not e.spike_used
                    and e.t_on_s <= t_s < e.t_off_s):
                e.spike_used = True
                out += self._axes(e.spec) * float(e.spec.magnitude_rad_s or 0.0)
        return out

    def active_bus_faults(self, t_s: float) -> list[FaultSpec]:
        """Bus faults in force at ``t_s`` (for the process shell; no physical effect)."""
        return [e.spec for e in self.entries if e.spec.kind in BUS_FAULTS and e.active(t_s)]
