"""Scenario models: faults, initial state, target, truth deviations, expectations, safety
(the design, sections 5.6 and 8).

A scenario lives in ``configs/scenarios/<id>.yaml`` (read by the shell,
``hil.config.load_scenario``, which also checks it against its vehicle and the bus catalog).
"""

from __future__ import annotations

import bisect
import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from common.schema import (
    MAX_DURATION_S,
    RUN_NAME_PATTERN,
    Fraction,
    NonNegFloat,
    PosFloat,
    Vec3,
    _FieldError,
    _Model,
)

# --------------------------------------------------------------------------- scenario

THRUSTER_FAULTS = ("stuck_on", "fail_to_fire", "degraded")
GYRO_FAULTS = ("gyro_spike", "gyro_bias_step", "gyro_frozen", "gyro_noise")
BUS_FAULTS = ("bus_drop", "bus_delay", "bus_corrupt", "node_silent", "bus_babble")
FaultKind = Literal[
    "stuck_on", "fail_to_fire", "degraded",
    "gyro_spike", "gyro_bias_step", "gyro_frozen", "gyro_noise",
    "bus_drop", "bus_delay", "bus_corrupt", "node_silent", "bus_babble",
]


class FaultSpec(_Model):
    """One injected fault (docs/design.md 5.6).

    ``fraction``: for ``stuck_on`` the residual thrust when commanded off (1.0 = full); for
    ``degraded`` the thrust that remains. Gyro faults use ``axis`` (0..2, or None for all) and
    ``magnitude_rad_s`` (spike, bias step, noise std). Bus faults (``bus.faults``, the send
    path of ``node``) use ``probability`` (per frame), ``message`` (a catalog message or frame
    name such as ``GYRO`` or ``THR_CMD_0``: only its frames; None: every frame the node
    sends), ``pattern`` (``bus_drop``: 1 = drop, 0 = pass, cycled over the matching frames,
    instead of ``probability``), ``delay_ms`` / ``delay_max_ms`` (``bus_delay``: fixed, or
    uniform in [delay_ms, delay_max_ms]) and ``reorder`` (delayed frames may overtake one
    another; default they keep their order), ``corrupt`` (``bus_corrupt``: flip ``bits``
    bits of the ``data``, one bit of the ``id``, or change the ``length``), ``rate_hz``
    (``bus_babble``: frames per second of garbage the node floods, on ``message``'s first
    identifier with a random payload, or identifier 0x000 without one).
    """

    kind: FaultKind
    t_s: NonNegFloat
    clear_t_s: NonNegFloat | None = None
    thruster: str | None = None
    fraction: Fraction | None = None
    axis: int | None = Field(default=None, ge=0, le=2)
    magnitude_rad_s: float | None = None
    node: Literal["flight", "plant"] | None = None
    probability: Fraction = 1.0
    delay_ms: NonNegFloat = 0.0
    delay_max_ms: NonNegFloat | None = None
    reorder: bool = False
    message: str | None = None
    pattern: list[Literal[0, 1]] | None = Field(default=None, min_length=1, max_length=1000)
    corrupt: Literal["data", "id", "length"] = "data"
    bits: int = Field(default=1, ge=1, le=64)
    rate_hz: Annotated[float, Field(gt=0, le=20000)] = 1000.0

    @model_validator(mode="after")
    def _consistent(self) -> FaultSpec:
        if self.clear_t_s is not None and self.clear_t_s <= self.t_s:
            raise _FieldError("clear_t_s", f"a time after t_s={self.t_s}", self.clear_t_s)
        if self.kind in THRUSTER_FAULTS and not self.thruster:
            raise _FieldError("thruster", f"a thruster name for a {self.kind} fault", None)
        if self.kind == "degraded" and self.fraction is None:
            raise _FieldError("fraction", "a thrust fraction in [0, 1] for a degraded fault", None)
        needs_magnitude = ("gyro_spike", "gyro_bias_step", "gyro_noise")
        if self.kind in needs_magnitude and self.magnitude_rad_s is None:
            raise _FieldError("magnitude_rad_s", f"a magnitude for a {self.kind} fault", None)
        if self.kind in BUS_FAULTS and self.node is None:
            raise _FieldError("node", "'flight' or 'plant' for a bus fault", None)
        if self.delay_max_ms is not None and self.delay_max_ms < self.delay_ms:
            raise _FieldError("delay_max_ms", f">= delay_ms={self.delay_ms}", self.delay_max_ms)
        if self.pattern is not None and self.kind != "bus_drop":
            raise _FieldError("pattern", "no pattern (only bus_drop takes one)", self.pattern)
        return self

    @property
    def effective_fraction(self) -> float:
        """Residual (stuck_on) or remaining (degraded) thrust fraction; 0 for fail_to_fire."""
        if self.kind == "fail_to_fire":
            return 0.0
        if self.fraction is None:
            return 1.0
        return float(self.fraction)


class AttitudeCfg(_Model):
    """An attitude as a rotation about ``axis`` by ``angle_deg`` (relative to the orbit frame)."""

    axis: Vec3 = (1.0, 0.0, 0.0)
    angle_deg: float = 0.0

    @field_validator("axis")
    @classmethod
    def _nonzero(cls, v: Vec3) -> Vec3:
        if math.sqrt(sum(c * c for c in v)) < 1e-12:
            raise ValueError("a non-zero axis")
        return v

    def quaternion(self) -> np.ndarray:
        """Scalar-first unit quaternion [q0, q1, q2, q3]."""
        a = np.asarray(self.axis, dtype=float)
        a = a / np.linalg.norm(a)
        h = math.radians(self.angle_deg) / 2.0
        return np.concatenate(([math.cos(h)], math.sin(h) * a))


class TurnCfg(_Model):
    """One programmed turn: from ``at_s`` on, the target is ``attitude`` (relative to the
    orbit frame). The flight takes it on the first tick at or after ``at_s``."""

    at_s: NonNegFloat
    attitude: AttitudeCfg


# A programme long enough for a turn every tick of a long run would be a file nobody writes;
# this bounds what a scenario can make the flight and the plant hold.
MAX_TURNS = 10_000


def turn_tick(at_s: float, tick_s: float) -> int:
    """The first tick at or after ``at_s`` (the tick a turn takes effect on)."""
    return int(math.ceil(at_s / tick_s - 1e-9))


def target_at(target: np.ndarray, turns: list[tuple[int, np.ndarray]], tick: int) -> np.ndarray:
    """The target quaternion in force at ``tick``: the last turn whose tick has come (turns
    sorted by tick, as ``ScenarioCfg.programme_ticks`` gives them; of two turns that fall on
    one tick the later is flown), else ``target``."""
    i = bisect.bisect_right(turns, tick, key=lambda turn: turn[0])
    return turns[i - 1][1] if i else target


class InitialCfg(_Model):
    attitude: AttitudeCfg = AttitudeCfg()
    rate_B_deg_s: Vec3 = (0.0, 0.0, 0.0)


class PlantOverridesCfg(_Model):
    """Truth deviations from the nominal vehicle for one run (the flight keeps the nominal)."""

    thrust_scale: PosFloat = 1.0
    thrust_scale_per_thruster: dict[str, PosFloat] = {}
    direction_error_deg: NonNegFloat = 0.0
    command_latency_ms: NonNegFloat = 0.0
    # Replaces the vehicle's constant disturbance torque for this run (None: the vehicle's).
    disturbance_torque_B_Nm: tuple[float, float, float] | None = None
    # Each step gets the exact thrust impulse (plant.core), so 10 ms loses nothing of the
    # profile's ms features; RK4 error at w*h ~ 1e-3 is negligible.
    step_s: Annotated[float, Field(ge=1e-4, le=0.1)] = 0.01


class ExpectedDetection(_Model):
    thruster: str | list[str]
    type: Literal["stuck_on", "fail_to_fire", "degraded"]
    within_s: PosFloat                    # the bound the run is judged against
    seed_latency_s: PosFloat | None = None  # the seed's own figure, where it gives one


class ExpectationsCfg(_Model):
    detections: list[ExpectedDetection] = []
    no_false_alarm: bool = True
    max_attitude_error_deg: PosFloat | None = None
    max_rate_error_deg_s: PosFloat | None = None
    # Only judge the attitude/rate maxima after this time (e.g. after the initial slew).
    settle_after_s: NonNegFloat = 0.0
    # A demonstration run that must raise a false alarm (S003-flex-rigid, seed 003 fig. 2).
    false_alarm_expected: bool = False
    # Orbit correction: the delta-v (body axes, m/s) the plant must have received by the end,
    # each component within delta_v_tol_m_s.
    delta_v_B_m_s: tuple[float, float, float] | None = None
    delta_v_tol_m_s: PosFloat = 0.3
    # Rate "within the dead zone apart from brief excursions" (seed 004): after
    # settle_after_s, no stretch longer than max_excursion_s with |rate| > rate_band_deg_s.
    rate_band_deg_s: PosFloat | None = None
    max_excursion_s: PosFloat = 10.0
    # Recovery: from recover_after_s seconds after the first correct detection to the end,
    # attitude error and rate stay within these bounds (the response holds attitude again).
    recover_after_s: NonNegFloat | None = None
    recovered_attitude_deg: PosFloat | None = None
    recovered_rate_deg_s: PosFloat | None = None


class SafetyCfg(_Model):
    """When each side gives up on the other and goes to its safe state (the design, section 4).

    ``thr_cmd_lost_ticks``: the plant closes every thruster valve and manifold when no
    THR_CMD came for this many ticks (lockstep: deadline misses in a row; real time: ticks of
    the plant's clock since the last command received). ``heartbeat_lost_s``: real time only,
    the plant does the same when the flight's heartbeat (sent every
    ``bus.catalog.HEARTBEAT_PERIOD_S``) has been silent this long; it must exceed that period
    (checked by the loader, ``hil.config.load_scenario``: the period is the bus's).
    ``gyro_lost_ticks``: the flight enters its safe mode (no firing, FDIR_STATUS safe flag,
    heartbeat state SAFE) after this many ticks without a valid gyro sample (none arrived, or
    every one was rejected by the receiver), and leaves it on the next valid one. Entering and
    leaving are events in the records and on the terminal. ``recover_ticks``: fresh commands
    of consecutive ticks the plant needs before it leaves its safe state.
    ``python -m hil.nodes`` flags
    (``--lost-after``, ``--heartbeat-lost-s``, ``--gyro-lost-after``) override these.
    """

    thr_cmd_lost_ticks: int = Field(default=3, ge=1, strict=True)  # strict: `true` is no count
    heartbeat_lost_s: PosFloat = 1.5
    gyro_lost_ticks: int = Field(default=3, ge=1, strict=True)
    # The plant leaves its safe state only after this many fresh THR_CMD of consecutive
    # ticks (hil.safe_states.CommandGate), not on the first frame after a stall.
    recover_ticks: int = Field(default=3, ge=1, le=50, strict=True)
    # What the plant does for a tick whose THR_CMD is missing, late or refused, before
    # ``thr_cmd_lost_ticks`` in a row make it safe: "zero" fires nothing that tick (the valves
    # close, manifolds stay as commanded), "hold" repeats the last command it applied
    # (docs/hostile-bus.md).
    thr_cmd_missing: Literal["zero", "hold"] = "zero"


LCM_URL_PATTERN = r"^(udpm|tcpq)://[^\s]+$"


class BusCfg(_Model):
    """Which bus the run uses (docs/lcm.md); ``hil run --bus`` overrides it::

        bus: {kind: lcm, url: "udpm://239.255.76.67:7667?ttl=0"}

    ``kind``: ``can`` (the python-can interface of ``--interface/--channel``, vcan0 by
    default) or ``lcm``; ``url``: the LCM provider (``udpm://`` or ``tcpq://``: the processes
    are separate, so ``memq://`` cannot carry a run), only with ``kind: lcm``.
    """

    kind: Literal["can", "lcm"]
    url: str | None = Field(default=None, pattern=LCM_URL_PATTERN, max_length=200)

    @model_validator(mode="after")
    def _url_only_for_lcm(self) -> BusCfg:
        if self.kind == "can" and self.url is not None:
            raise _FieldError("url", "no url with kind can (the LCM provider is for kind lcm)",
                              self.url)
        return self


class ScenarioCfg(_Model):
    """A scenario file (``configs/scenarios/*.yaml``; the README shows one in full).

    ``name``, ``description``, ``vehicle`` (a name in ``configs/vehicles`` or a path),
    ``duration_s``, ``seed`` (every random source derives from it), ``initial`` (attitude and
    rate relative to the orbit frame), ``target`` (attitude), ``plant`` (truth deviations,
    ``PlantOverridesCfg``), ``flight`` (partial override of the vehicle's ``flight:``),
    ``faults`` (``FaultSpec`` list), ``expect`` (optional verdict, ``ExpectationsCfg``) and
    ``safety`` (optional, ``SafetyCfg``)::

        safety: {thr_cmd_lost_ticks: 3, heartbeat_lost_s: 1.5, gyro_lost_ticks: 3}

    ``programme`` (optional): programmed turns (seed 003's flight test was a programme of
    turns), ``{at_s, attitude}`` in increasing time within the run, each the target from its
    time on (``target`` before the first)::

        programme:
          - {at_s: 10.0, attitude: {axis: [0, 0, 1], angle_deg: 0.1}}
          - {at_s: 13.2, attitude: {axis: [0, 0, 1], angle_deg: -0.1}}
    """

    # The name becomes the default output folder ``runs/<name>``: a safe set of characters,
    # so a run never writes outside the folder chosen for it.
    name: str = Field(pattern=RUN_NAME_PATTERN)
    description: str = ""
    vehicle: str
    # A week of simulated time bounds what a run (and its records) can grow to.
    duration_s: Annotated[float, Field(gt=0, le=MAX_DURATION_S)]
    seed: int = Field(default=1, ge=0, lt=2**63)
    initial: InitialCfg = InitialCfg()
    target: AttitudeCfg = AttitudeCfg()
    programme: Annotated[list[TurnCfg], Field(max_length=MAX_TURNS)] = []
    plant: PlantOverridesCfg = PlantOverridesCfg()
    # Partial override of the vehicle's `flight:` section, merged key by key.
    flight: dict[str, Any] = {}
    faults: list[FaultSpec] = []
    expect: ExpectationsCfg | None = None
    safety: SafetyCfg = SafetyCfg()
    bus: BusCfg | None = None

    @model_validator(mode="after")
    def _programme_in_order(self) -> ScenarioCfg:
        last = -1.0
        for i, turn in enumerate(self.programme):
            if turn.at_s <= last:
                raise _FieldError(f"programme[{i}].at_s",
                                  f"a time after the previous turn's {last} s", turn.at_s)
            if turn.at_s >= self.duration_s:
                raise _FieldError(f"programme[{i}].at_s",
                                  f"a time within the run (< duration_s {self.duration_s})",
                                  turn.at_s)
            last = turn.at_s
        return self

    def programme_ticks(self, tick_s: float) -> list[tuple[int, np.ndarray]]:
        """The programme as (tick it takes effect on, target quaternion), in order."""
        return [(turn_tick(t.at_s, tick_s), t.attitude.quaternion()) for t in self.programme]

