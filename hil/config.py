"""Configuration loading: vehicles and scenarios read from YAML, validated once on load.

The models are the shared vocabulary and live on the ground floor (``common.vehicle``,
``common.scenario``; the design, sections 7 and 8); this shell module owns the files: paths
(``configs/vehicles/<name>.yaml``, ``configs/scenarios/<id>.yaml``), YAML reading, the merge of a
scenario's flight overrides, and the cross-checks between a scenario, its vehicle and the bus
catalog. A bad file raises ``ConfigError`` whose text is one line:
``configs/vehicles/orel.yaml: thrusters[3].thrust_n: expected > 0, got 0.0``.

The models are re-exported here: a shell module that loads a file names what it gets from
one place.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from bus.catalog import HEARTBEAT_PERIOD_S, N_MANIFOLDS_MAX, N_THRUSTERS_MAX, TICK_S
from common.errors import ConfigError, Raw
from common.scenario import (
    BUS_FAULTS,
    GYRO_FAULTS,
    THRUSTER_FAULTS,
    AttitudeCfg,
    ExpectationsCfg,
    ExpectedDetection,
    FaultKind,
    FaultSpec,
    InitialCfg,
    PlantOverridesCfg,
    SafetyCfg,
    ScenarioCfg,
)
from common.schema import MAX_DURATION_S, RUN_NAME_PATTERN, config_error
from common.units import G0_M_S2
from common.vehicle import (
    AllocatorCfg,
    CmgCfg,
    ControllerCfg,
    DetectorCfg,
    DisturbanceCfg,
    FdirCfg,
    FlexModeCfg,
    FlightCfg,
    GyroCfg,
    KalmanCfg,
    ModeShapeCfg,
    ObserverCfg,
    OnboardModelCfg,
    OrbitCfg,
    OrbitCorrectionCfg,
    ThrusterCfg,
    ThrustProfileCfg,
    TimingCfg,
    VehicleArrays,
    VehicleCfg,
)
from hil.yamlsafe import YamlLimitError, read_mapping

__all__ = [
    "BUS_FAULTS", "CONFIG_DIR", "GYRO_FAULTS", "G0_M_S2", "REPO_ROOT", "SCENARIO_DIR",
    "THRUSTER_FAULTS", "VEHICLE_DIR", "AllocatorCfg", "AttitudeCfg", "CmgCfg", "ConfigError",
    "ControllerCfg", "DetectorCfg", "DisturbanceCfg", "ExpectationsCfg", "ExpectedDetection",
    "FaultKind", "FaultSpec", "FdirCfg", "FlexModeCfg", "FlightCfg", "GyroCfg", "InitialCfg",
    "KalmanCfg", "ModeShapeCfg", "ObserverCfg", "OnboardModelCfg", "OrbitCfg",
    "OrbitCorrectionCfg", "PlantOverridesCfg", "SafetyCfg", "Scenario", "ScenarioCfg",
    "ThrustProfileCfg", "ThrusterCfg", "TimingCfg", "VehicleArrays", "VehicleCfg", "load_any",
    "load_scenario", "load_vehicle", "read_config", "resolve_vehicle_path", "MAX_DURATION_S",
    "RUN_NAME_PATTERN",
]

REPO_ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = REPO_ROOT / "configs"
VEHICLE_DIR = CONFIG_DIR / "vehicles"
SCENARIO_DIR = CONFIG_DIR / "scenarios"


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        try:
            return str(path.resolve().relative_to(REPO_ROOT))
        except ValueError:
            return str(path)


def read_config(path: Path) -> dict[str, Any]:
    """Read a config file under ``hil.yamlsafe``'s limits (size, depth, aliases, duplicate
    keys, UTF-8); every refusal is one ``ConfigError`` line."""
    try:
        return read_mapping(path)
    except YamlLimitError as exc:
        raise ConfigError(_display(path), exc.field, exc.expected, Raw(exc.found)) from None


def resolve_vehicle_path(name_or_path: str, relative_to: Path | None = None) -> Path:
    """A vehicle name (``orel``) resolves to ``configs/vehicles/orel.yaml``; a path stays."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        if not p.is_absolute() and relative_to is not None and not p.exists():
            p = relative_to / p
        return p
    return VEHICLE_DIR / f"{name_or_path}.yaml"


def load_vehicle(
    name_or_path: str | Path, flight_overrides: dict[str, Any] | None = None
) -> VehicleCfg:
    """Load and validate a vehicle. ``flight_overrides`` (from a scenario) merge into ``flight``."""
    path = resolve_vehicle_path(str(name_or_path))
    data = read_config(path)
    if flight_overrides:
        data = dict(data)
        data["flight"] = _deep_merge(dict(data.get("flight") or {}), flight_overrides)
    try:
        vehicle = VehicleCfg.model_validate(data)
    except ValidationError as exc:
        raise config_error(_display(path), exc) from None
    _check_bus_limits(vehicle, _display(path))
    return vehicle


def _check_bus_limits(v: VehicleCfg, where: str) -> None:
    """What the message catalog can carry (the ICD between flight and plant): thruster and
    manifold counts that fit THR_CMD and FDIR_STATUS, and the tick and PWM grid its on-time
    codes are defined on. Checked at load, so a vehicle the bus cannot fly never starts."""
    if len(v.thrusters) > N_THRUSTERS_MAX:
        raise ConfigError(where, "thrusters", f"at most {N_THRUSTERS_MAX} thrusters (THR_CMD "
                          "carries no more)", Raw(f"{len(v.thrusters)} thrusters"))
    if len(v.manifolds) > N_MANIFOLDS_MAX:
        raise ConfigError(where, "manifolds", f"at most {N_MANIFOLDS_MAX} manifolds (the "
                          "manifold masks are 4 bits)", Raw(f"{len(v.manifolds)} manifolds"))
    if abs(v.timing.tick_s - TICK_S) > 1e-12:
        raise ConfigError(where, "timing.tick_s", f"{TICK_S} (the tick the bus catalog's "
                          "cycle times and on-time codes are defined for)", v.timing.tick_s)
    for key, want in (("pwm_quantum_ms", 10.0), ("min_on_ms", 30.0), ("min_off_ms", 30.0)):
        got = getattr(v.timing, key)
        if abs(got - want) > 1e-12:
            raise ConfigError(where, f"timing.{key}", f"{want:g} (THR_CMD's on-time codes "
                              "{0, 30..170, 200} ms)", got)


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = v
    return out


@dataclass(frozen=True)
class Scenario:
    """A validated scenario with its vehicle (flight overrides applied) and source path."""

    cfg: ScenarioCfg
    vehicle: VehicleCfg
    path: Path


def load_scenario(path: str | Path) -> Scenario:
    """Load a scenario and its vehicle; cross-check thruster names in faults and expectations."""
    path = Path(path)
    where = _display(path)
    data = read_config(path)
    try:
        cfg = ScenarioCfg.model_validate(data)
    except ValidationError as exc:
        raise config_error(where, exc) from None
    if cfg.safety.heartbeat_lost_s <= HEARTBEAT_PERIOD_S:
        raise ConfigError(where, "safety.heartbeat_lost_s",
                          f"> the heartbeat period {HEARTBEAT_PERIOD_S:g} s",
                          cfg.safety.heartbeat_lost_s)
    vpath = resolve_vehicle_path(cfg.vehicle, relative_to=path.parent)
    if not vpath.exists():
        raise ConfigError(where, "vehicle", "a vehicle name or YAML path that exists", cfg.vehicle)
    try:
        vehicle = load_vehicle(vpath, cfg.flight or None)
    except ConfigError as exc:
        if exc.field.startswith("flight") and cfg.flight:
            raise ConfigError(where, exc.field, exc.expected, exc.found) from None
        raise
    names = {t.name for t in vehicle.thrusters}
    for i, f in enumerate(cfg.faults):
        if f.thruster is not None and f.thruster not in names:
            raise ConfigError(
                where, f"faults[{i}].thruster", f"a thruster of vehicle {vehicle.name}", f.thruster
            )
    for k, name in cfg.plant.thrust_scale_per_thruster.items():
        if k not in names:
            raise ConfigError(
                where, "plant.thrust_scale_per_thruster", f"a thruster of vehicle {vehicle.name}", k
            )
        del name
    if cfg.expect:
        for i, d in enumerate(cfg.expect.detections):
            for n in [d.thruster] if isinstance(d.thruster, str) else d.thruster:
                if n not in names:
                    raise ConfigError(
                        where, f"expect.detections[{i}].thruster",
                        f"a thruster of vehicle {vehicle.name}", n,
                    )
    return Scenario(cfg=cfg, vehicle=vehicle, path=path)


def load_any(path: str | Path) -> VehicleCfg | Scenario:
    """Validate a vehicle or a scenario file (a scenario has a ``vehicle`` key)."""
    path = Path(path)
    data = read_config(path)
    scenario_keys = {"vehicle", "duration_s", "faults", "expect", "initial", "target"}
    if "thrusters" not in data and scenario_keys & set(data):
        return load_scenario(path)
    return load_vehicle(path)

