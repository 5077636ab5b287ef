"""FDIR response to a detection (docs/design.md 6.4 step 7): a small state machine written as data.

States: ``nominal`` (no fault), ``reconfigured`` (a thruster or manifold taken out, detection
re-armed), ``reported`` (fault reported, response ``none``: the detector stays latched, single
fault assumption), ``safe`` (all valves commanded closed: lost peer, or nothing left to control
with). Events: the detector's kinds ``stuck_on``, ``fail_to_fire``, ``degraded``, the gyro
check's ``gyro_fault`` (reported, no thruster action), and
``peer_lost`` / ``peer_back`` from the process shell.

The table ``(state, event) -> (next state, action)`` is built once from the vehicle's
``flight.fdir`` section; an action that names a config key is resolved there:

* stuck on -> ``on_stuck_on`` (default ``close_manifold``: only closing its manifold's isolation
  valve stops a thruster that does not turn off, docs/design.md 5.5);
* fails to fire -> ``on_fail_to_fire`` (default ``drop_thruster``: the allocator stops using it);
* degraded -> ``on_degraded``.

A group detection ("one of {i, j}", same acceleration direction) acts on the whole group: every
thruster of the group is dropped, or every manifold holding one is closed. After
``close_manifold`` or ``drop_thruster`` the caller must re-baseline the detector
(``Response.rebaseline``): the closing valve stops a thruster that was meant to fire this tick,
which would otherwise read as a new fails-to-fire. If the response leaves no thruster available
the state becomes ``safe``.

Outputs for the allocator: ``available`` (N,) bool and ``manifold_open`` (M,) bool.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from common.vehicle import FdirCfg
from flight.detector import Detection

NOMINAL, RECONFIGURED, REPORTED, SAFE = "nominal", "reconfigured", "reported", "safe"
STATES = (NOMINAL, RECONFIGURED, REPORTED, SAFE)
FAULT_EVENTS = ("stuck_on", "fail_to_fire", "degraded", "gyro_fault")
ACTIONS = ("close_manifold", "drop_thruster", "none", "all_off", "resume")

# (state, event) -> (next state, action). "cfg:<key>" takes the action from FdirCfg.<key>;
# a configured "none" turns the next state into "reported".
TRANSITIONS: dict[tuple[str, str], tuple[str, str]] = {
    (NOMINAL, "stuck_on"): (RECONFIGURED, "cfg:on_stuck_on"),
    (NOMINAL, "fail_to_fire"): (RECONFIGURED, "cfg:on_fail_to_fire"),
    (NOMINAL, "degraded"): (RECONFIGURED, "cfg:on_degraded"),
    (RECONFIGURED, "stuck_on"): (RECONFIGURED, "cfg:on_stuck_on"),
    (RECONFIGURED, "fail_to_fire"): (RECONFIGURED, "cfg:on_fail_to_fire"),
    (RECONFIGURED, "degraded"): (RECONFIGURED, "cfg:on_degraded"),
    (NOMINAL, "peer_lost"): (SAFE, "all_off"),
    (RECONFIGURED, "peer_lost"): (SAFE, "all_off"),
    (REPORTED, "peer_lost"): (SAFE, "all_off"),
    (SAFE, "peer_back"): (NOMINAL, "resume"),
    # A sensor fault (flight.gyro_check) is reported; no thruster is taken out for it.
    (NOMINAL, "gyro_fault"): (NOMINAL, "none"),
    (RECONFIGURED, "gyro_fault"): (RECONFIGURED, "none"),
    (REPORTED, "gyro_fault"): (REPORTED, "none"),
}


@dataclass(frozen=True)
class Response:
    """What one event did: ``state`` after it, ``action`` taken, ``rebaseline`` (the detector and
    the onboard model must restart their residuals), the detection that caused it (or None)."""

    state: str
    action: str
    rebaseline: bool
    detection: Detection | None


@dataclass
class Fdir:
    """The FDIR state machine for one vehicle.

    ``manifold_of`` (N,) manifold index of each thruster; ``n_manifolds`` M.
    """

    cfg: FdirCfg
    manifold_of: np.ndarray
    n_manifolds: int
    state: str = NOMINAL
    detections: list[Detection] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.manifold_of = np.asarray(self.manifold_of, dtype=int)
        self.dropped = np.zeros(len(self.manifold_of), dtype=bool)
        self.manifold_open = np.ones(self.n_manifolds, dtype=bool)
        self._state_before_safe = NOMINAL

    @property
    def available(self) -> np.ndarray:
        """(N,) bool: usable by the allocator (not dropped, manifold open, not in safe mode)."""
        if self.state == SAFE:
            return np.zeros(len(self.manifold_of), dtype=bool)
        return ~self.dropped & self.manifold_open[self.manifold_of]

    @property
    def safe_mode(self) -> bool:
        return self.state == SAFE

    def handle(self, event: str, detection: Detection | None = None) -> Response:
        """Apply one event; events with no row in the table change nothing (action ``none``)."""
        row = TRANSITIONS.get((self.state, event))
        if row is None:
            return Response(self.state, "none", False, detection)
        nxt, action = row
        if action.startswith("cfg:"):
            action = getattr(self.cfg, action[4:])
            if action == "none":
                nxt = REPORTED
        if detection is not None:
            self.detections.append(detection)
        group = detection.group if detection is not None else ()
        rebaseline = False
        if action == "close_manifold":
            for i in group:
                self.manifold_open[self.manifold_of[i]] = False
            rebaseline = True
        elif action == "drop_thruster":
            for i in group:
                self.dropped[i] = True
            rebaseline = True
        elif action == "all_off":
            self._state_before_safe = self.state
        elif action == "resume":
            nxt = self._state_before_safe
            rebaseline = True
        self.state = nxt
        if self.state != SAFE and not self.available.any():
            self.state = SAFE
        return Response(self.state, action, rebaseline, detection)
