"""The campaign file (YAML): what to run, how many times, and what to disperse.

A campaign names a base (a vehicle, or a scenario whose settings every run starts from), the
number of runs, a master seed and dispersions; ``fault:`` (optional) draws one injected fault
per run. A fault-free campaign is the same file without ``fault:``. Every value that varies is
a *distribution* (``hil.campaign.dispersions``)::

    name: orel-envelope
    base: {vehicle: orel}           # or {scenario: configs/scenarios/S003-flex.yaml}
    runs: 500
    seed: 20261201
    duration_s: 60                  # a number or a distribution (default: the base's)
    dispersions:
      thrust_scale: {uniform: [0.85, 1.15]}
      thrust_scale_per_thruster: {uniform: [0.85, 1.15]}
      direction_error_deg: {uniform: [0, 2]}
      command_latency_ms: {uniform: [0, 15]}
      initial_angle_deg: {uniform: [0, 30]}     # about a random axis unless initial_axis
      initial_rate_deg_s: {uniform: [0, 3.5]}   # magnitude, random direction
    fault:                          # omit for a fault-free campaign
      kind: {cycle: [stuck_on, fail_to_fire, degraded]}
      thruster: {cycle: all, stride: 3}         # any | all | {manifold: I} | {choice: [...]}
      t_s: {uniform: [10, 40]}
      fraction: {stuck_on: {choice: [1.0, 0.5, 0.15]}, degraded: {uniform: [0.2, 0.6]}}
    flight: {}                      # partial override of the vehicle's flight: section

Validation is strict (unknown keys, wrong types, bad distributions) and every error is one
line: ``configs/campaigns/x.yaml: dispersions.thrust_scale.uniform: expected [low, high] with
low <= high, got [1.2, 0.8]``. Names of thrusters and manifolds are checked against the
vehicle. Whatever the scenario loader itself rejects (for example a fault kind it does not
know) is reported for the first 16 runs before anything starts, and for any later run as that
run's error.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from hil.campaign.dispersions import (
    DISPERSIONS,
    Dist,
    DistError,
    parse_dist,
    parse_thruster_dist,
)
from hil.yamlsafe import YamlLimitError, read_mapping


class CampaignError(Exception):
    """A campaign file, a results folder or a campaign command line is invalid (exit 2).

    ``str(err)`` is one line: ``where: field: expected ..., got ...``.
    """

    def __init__(self, where: str, field: str, expected: str, found: object) -> None:
        self.where, self.field, self.expected, self.found = where, field, expected, found
        loc = f"{where}: {field}" if field else where
        shown = found if isinstance(found, Bare) else repr(found)
        super().__init__(f"{loc}: expected {expected}, got {shown}")


class Bare(str):
    """A found value printed as is (``nothing``, ``no such file``)."""


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class BaseSpec(_M):
    """Exactly one of ``vehicle`` (a name in configs/vehicles or a YAML path) or ``scenario``."""

    vehicle: str | None = None
    scenario: str | None = None

    @model_validator(mode="after")
    def _one(self) -> BaseSpec:
        if (self.vehicle is None) == (self.scenario is None):
            raise ValueError("exactly one of vehicle or scenario")
        return self


class FaultSpecDist(_M):
    """One fault per run; each field a distribution. ``fraction``, ``magnitude_rad_s`` and
    ``clear_after_s`` may each be one distribution or a mapping fault kind -> distribution
    (drawn only for that kind); ``thruster: none`` for faults without a thruster;
    ``clear_after_s`` clears the fault that long after ``t_s``."""

    kind: Any
    thruster: Any = "any"
    t_s: Any
    fraction: Any = None
    clear_after_s: Any = None
    axis: Any = None
    magnitude_rad_s: Any = None


class CampaignModel(_M):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.+-]+$")
    description: str = ""
    base: BaseSpec
    runs: int = Field(ge=1, strict=True)
    seed: int = Field(ge=0, strict=True)
    duration_s: Any = None
    dispersions: dict[str, Any] = {}
    fault: FaultSpecDist | None = None
    flight: dict[str, Any] = {}
    # How many runs `--bus` sends over the real bus (the first ones of a seeded sample).
    bus_sample: int = Field(default=3, ge=1, strict=True)


@dataclass(frozen=True)
class Campaign:
    """A validated campaign: the model, its parsed distributions and where it came from.

    ``path`` the file; ``base_scenario`` the base scenario as a plain dict (``model_dump``) or
    None; ``vehicle`` the base vehicle as a plain dict (flight overrides of a base scenario
    applied); ``thrusters`` and ``manifolds`` of that vehicle.
    """

    model: CampaignModel
    path: Path
    vehicle: dict[str, Any]
    base_scenario: dict[str, Any] | None
    vehicle_ref: str
    dists: dict[str, Dist]
    fault_dists: dict[str, Any] | None
    duration: Dist | None
    thrusters: tuple[str, ...] = field(default=())
    manifolds: dict[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def runs(self) -> int:
        return self.model.runs

    @property
    def seed(self) -> int:
        return self.model.seed

    @property
    def vehicle_name(self) -> str:
        return str(self.vehicle["name"])

    def fingerprint(self) -> str:
        """Hash of everything that decides a run's parameters except ``runs``: results with the
        same fingerprint are the same runs, so a folder can be resumed or extended."""
        d = self.model.model_dump(mode="json")
        d.pop("runs", None)
        d.pop("bus_sample", None)
        d.pop("description", None)
        blob = json.dumps({"campaign": d, "vehicle": self.vehicle,
                           "base": self.base_scenario}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for p in loc:
        out += f"[{p}]" if isinstance(p, int) else ("." if out else "") + str(p)
    return out


_EXPECTED = {
    "missing": "this field (it is required)",
    "extra_forbidden": "no such field (unknown key)",
    "int_type": "an integer",
    "int_parsing": "an integer",
    "int_from_float": "an integer",
    "string_type": "a string",
    "dict_type": "a mapping",
    "model_type": "a mapping",
    "string_pattern_mismatch": "letters, digits and _ . + - only",
    "string_too_short": "a non-empty string",
}


def _pydantic_error(where: str, exc: ValidationError) -> CampaignError:
    err = exc.errors(include_url=False)[0]
    field_ = _loc(tuple(p for p in err["loc"] if p not in ("function-after",)))
    ctx = err.get("ctx") or {}
    t = err["type"]
    if t in _EXPECTED:
        expected = _EXPECTED[t]
    elif t == "greater_than_equal":
        expected = f">= {ctx['ge']}"
    elif t == "value_error":
        expected = str(ctx.get("error", err["msg"]))
    else:
        expected = err["msg"][0].lower() + err["msg"][1:]
    found: object = err.get("input")
    if t == "missing":
        found = Bare("nothing")
    elif isinstance(found, dict):
        found = Bare("a mapping")
    return CampaignError(where, field_, expected, found)


def _read_yaml(path: Path, where: str) -> dict[str, Any]:
    """The campaign file under ``hil.yamlsafe``'s limits (size, depth, aliases, duplicate
    keys, UTF-8), as for vehicles and scenarios."""
    try:
        return read_mapping(path)
    except YamlLimitError as exc:
        raise CampaignError(where, exc.field, exc.expected, Bare(exc.found)) from None


def _base(model: CampaignModel, path: Path, where: str
          ) -> tuple[dict[str, Any], dict[str, Any] | None, str]:
    """(vehicle dict, base scenario dict or None, how a run file names the vehicle)."""
    from hil.config import load_scenario, load_vehicle

    if model.base.scenario is not None:
        p = Path(model.base.scenario)
        if not p.is_absolute() and not p.exists():
            p = path.parent / p
        if not p.exists():
            raise CampaignError(where, "base.scenario", "an existing scenario file",
                                model.base.scenario)
        sc = load_scenario(p)
        scen = sc.cfg.model_dump(mode="json")
        veh = sc.vehicle.model_dump(mode="json")
        # The vehicle dict already holds the scenario's flight overrides.
        scen["flight"] = {}
        return veh, scen, "inline"
    ref = model.base.vehicle
    p = Path(ref)
    if p.suffix in (".yaml", ".yml"):
        if not p.is_absolute() and not p.exists():
            p = path.parent / p
        if not p.exists():
            raise CampaignError(where, "base.vehicle", "a vehicle name or YAML path that exists",
                                ref)
        return load_vehicle(p).model_dump(mode="json"), None, "inline"
    try:
        veh = load_vehicle(ref).model_dump(mode="json")
    except Exception as exc:  # noqa: BLE001 - the vehicle loader's own one-line error
        if "no such file" in str(exc):
            raise CampaignError(where, "base.vehicle", "a vehicle name in configs/vehicles",
                                ref) from None
        raise
    return veh, None, ref


def parse_campaign(path: str | Path) -> Campaign:
    """Load and validate a campaign file; raise ``CampaignError`` (one line) when it is bad."""
    path = Path(path)
    where = display(path)
    data = _read_yaml(path, where)
    try:
        model = CampaignModel.model_validate(data)
    except ValidationError as exc:
        raise _pydantic_error(where, exc) from None
    vehicle, base_scenario, ref = _base(model, path, where)
    thrusters = tuple(t["name"] for t in vehicle["thrusters"])
    manifolds: dict[str, tuple[str, ...]] = {
        m: tuple(t["name"] for t in vehicle["thrusters"] if t["manifold"] == m)
        for m in vehicle["manifolds"]}
    n_modes = len(vehicle.get("flex_modes") or [])
    dists: dict[str, Dist] = {}
    try:
        for name, raw in model.dispersions.items():
            if name not in DISPERSIONS:
                raise DistError(f"dispersions.{name}",
                                f"one of {sorted(DISPERSIONS)}", Bare("an unknown name"))
            spec = DISPERSIONS[name]
            if spec.per == "flex_mode" and n_modes == 0:
                raise DistError(f"dispersions.{name}", "a vehicle with flex_modes",
                                f"vehicle {vehicle['name']} without flex modes")
            dists[name] = parse_dist(raw, f"dispersions.{name}", spec.kind)
        duration = None
        if model.duration_s is not None:
            duration = parse_dist(model.duration_s, "duration_s", "positive")
        fault = None
        if model.fault is not None:
            f = model.fault
            fault = {
                "kind": parse_dist(f.kind, "fault.kind", "string"),
                "thruster": parse_thruster_dist(f.thruster, "fault.thruster", thrusters,
                                                manifolds),
                "t_s": parse_dist(f.t_s, "fault.t_s", "nonneg"),
            }
            if f.fraction is not None:
                fault["fraction"] = _per_kind(f.fraction, "fault.fraction", "fraction",
                                              fault["kind"])
            for key, kind in (("clear_after_s", "positive"), ("axis", "axis"),
                              ("magnitude_rad_s", "number")):
                raw = getattr(f, key)
                if raw is not None:
                    # one distribution, or fault kind -> distribution (gyro faults: a spike,
                    # a bias step and a noise level have magnitudes of their own)
                    fault[key] = (parse_dist(raw, f"fault.{key}", kind) if key == "axis"
                                  else _per_kind(raw, f"fault.{key}", kind, fault["kind"]))
    except DistError as exc:
        raise CampaignError(where, exc.field, exc.expected, exc.found) from None
    if base_scenario is None and duration is None:
        raise CampaignError(where, "duration_s", "a duration (the base is a bare vehicle)",
                            Bare("nothing"))
    if fault is not None:
        t_hi = (fault["t_s"].bounds() or (0.0, 0.0))[1]
        d_lo = (duration.bounds() if duration else None) or (
            (base_scenario or {}).get("duration_s", 0.0),) * 2
        if t_hi >= d_lo[0]:
            raise CampaignError(where, "fault.t_s", f"times before the shortest duration "
                                f"({d_lo[0]:g} s)", Bare(f"up to {t_hi:g} s"))
    c = Campaign(model=model, path=path, vehicle=vehicle, base_scenario=base_scenario,
                 vehicle_ref=ref, dists=dists, fault_dists=fault, duration=duration,
                 thrusters=thrusters, manifolds=manifolds)
    return c


def _per_kind(raw: Any, where: str, kind: str, kinds: Dist) -> Any:
    """A fault field as one distribution, or a mapping fault kind -> distribution."""
    from hil.campaign.dispersions import DIST_KEYS

    if isinstance(raw, dict) and raw and not (set(raw) & set(DIST_KEYS)):
        known = set(kinds.values()) if kinds.values() is not None else None
        out = {}
        for k, v in raw.items():
            if known is not None and k not in known:
                raise DistError(f"{where}.{k}", f"a fault kind of fault.kind {sorted(known)}", k)
            out[k] = parse_dist(v, f"{where}.{k}", kind)
        return out
    return parse_dist(raw, where, kind)
