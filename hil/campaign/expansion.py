"""Run k of a campaign as an ordinary scenario: draw its parameters, write its files.

``expand_run(campaign, k)`` draws run k's values (``hil.campaign.dispersions``: from the master
seed, k and each dispersion's name alone) and builds the scenario as a plain dict, with the
vehicle as a plain dict beside it. ``write_run`` writes ``<name>-<k>.yaml`` (and, when the run
changes the vehicle, ``<name>-<k>.vehicle.yaml`` that the scenario names), which ``hil run``
and every other scenario command accept as they are. Tasks load exactly these files, so a run
expanded by hand is the run the campaign ran.

Where each value goes: thrust, direction and latency errors into the scenario's ``plant:``
section (``PlantOverridesCfg``: truth only, the flight keeps the nominal vehicle); the initial
attitude and rate into ``initial:``; the fault into ``faults:``. Gyro noise and bias and the
flex modes' frequencies and damping are vehicle figures that a scenario cannot override (the
scenario loader merges only ``flight:`` into the vehicle), so those go into the run's own copy
of the vehicle. The flight software reads none of them (it uses the gyro's kind and latency
and its own observer's flex estimate), so they change the truth and nothing else, as a truth
override would.

The scenario's ``expect:`` is ``{no_false_alarm: true}``: ``hil run`` of an expanded run exits 1
on a false alarm; the campaign's own verdicts come from ``hil.campaign.statistics``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hil.campaign.dispersions import Dist, stream
from hil.campaign.file import Campaign


@dataclass(frozen=True)
class RunSpec:
    """One expanded run: ``scenario`` and ``vehicle`` (plain dicts), whether the vehicle differs
    from the base (``vehicle_changed``), the drawn ``params`` (flat, for the results table) and
    the injected ``fault`` (or None)."""

    run: int
    name: str
    scenario: dict[str, Any]
    vehicle: dict[str, Any]
    vehicle_changed: bool
    vehicle_ref: str
    params: dict[str, Any]
    fault: dict[str, Any] | None

    @property
    def n_ticks(self) -> int:
        return int(round(self.scenario["duration_s"] / self.vehicle["timing"]["tick_s"]))


def _unit(rng: np.random.Generator) -> list[float]:
    """A direction uniform on the sphere (normalised Gaussian vector)."""
    while True:
        v = rng.standard_normal(3)
        n = float(np.linalg.norm(v))
        if n > 1e-9:
            return [float(x) / n for x in v]


def _r(x: float) -> float:
    # Rounded so the YAML file shows what ran; the run uses the rounded value too.
    return float(f"{x:.12g}")


def run_name(c: Campaign, k: int) -> str:
    return f"{c.name}-{k:05d}"


def expand_run(c: Campaign, k: int) -> RunSpec:
    """Run ``k`` of campaign ``c`` (module doc)."""
    if not 0 <= k < c.runs:
        raise ValueError(f"run: expected 0 <= run < {c.runs}, got {k}")
    seed = c.seed

    def draw(name: str, d: Dist) -> Any:
        return d.draw(stream(seed, k, name), k)

    base = copy.deepcopy(c.base_scenario) if c.base_scenario else {}
    vehicle = copy.deepcopy(c.vehicle)
    params: dict[str, Any] = {}
    plant = dict(base.get("plant") or {})
    initial = copy.deepcopy(base.get("initial") or {})
    dd = c.dists

    if "noise_seed" in dd:
        noise_seed = int(draw("noise_seed", dd["noise_seed"]))
    else:
        noise_seed = int(stream(seed, k, "noise_seed").integers(0, 2**31 - 1))
    params["noise_seed"] = noise_seed
    duration = float(draw("duration_s", c.duration)) if c.duration else float(base["duration_s"])
    params["duration_s"] = _r(duration)

    for key in ("thrust_scale", "direction_error_deg", "command_latency_ms"):
        if key in dd:
            plant[key] = params[key] = _r(draw(key, dd[key]))
    if "thrust_scale_per_thruster" in dd:
        per = {n: _r(draw(f"thrust_scale_per_thruster.{n}", dd["thrust_scale_per_thruster"]))
               for n in c.thrusters}
        plant["thrust_scale_per_thruster"] = per
        vals = list(per.values())
        params["thrust_scale_per_thruster_min"] = min(vals)
        params["thrust_scale_per_thruster_max"] = max(vals)

    if "initial_angle_deg" in dd or "initial_axis" in dd:
        att = dict(initial.get("attitude") or {})
        if "initial_axis" in dd:
            axis = list(draw("initial_axis", dd["initial_axis"]))
        else:
            axis = _unit(stream(seed, k, "initial_axis"))
        att["axis"] = [_r(a) for a in axis]
        if "initial_angle_deg" in dd:
            att["angle_deg"] = _r(draw("initial_angle_deg", dd["initial_angle_deg"]))
        params["initial_axis"] = att["axis"]
        params["initial_angle_deg"] = att.get("angle_deg", 0.0)
        initial["attitude"] = att
    if "initial_rate_deg_s" in dd:
        mag = float(draw("initial_rate_deg_s", dd["initial_rate_deg_s"]))
        u = _unit(stream(seed, k, "initial_rate_deg_s.direction"))
        initial["rate_B_deg_s"] = [_r(mag * x) for x in u]
        params["initial_rate_deg_s"] = _r(mag)

    changed = False
    gyro = vehicle["gyro"]
    if "gyro_noise_std_rad_s" in dd:
        gyro["noise_std_rad_s"] = params["gyro_noise_std_rad_s"] = _r(
            draw("gyro_noise_std_rad_s", dd["gyro_noise_std_rad_s"]))
        changed = True
    if "gyro_bias_rad_s" in dd:
        gyro["bias_rad_s"] = [_r(draw(f"gyro_bias_rad_s.{i}", dd["gyro_bias_rad_s"]))
                              for i in range(3)]
        params["gyro_bias_rad_s"] = gyro["bias_rad_s"]
        changed = True
    for key, fld in (("flex_freq_scale", "freq_hz"), ("flex_log_decrement_scale",
                                                      "log_decrement")):
        if key in dd:
            scales = []
            for i, m in enumerate(vehicle["flex_modes"]):
                s = float(draw(f"{key}.{i}", dd[key]))
                m[fld] = _r(m[fld] * s)
                scales.append(_r(s))
            params[key] = scales
            changed = True

    faults = list(base.get("faults") or [])
    fault = None
    if c.fault_dists is not None:
        fd = c.fault_dists
        kind = str(draw("fault.kind", fd["kind"]))
        fault = {"kind": kind, "t_s": _r(draw("fault.t_s", fd["t_s"]))}
        thr = draw("fault.thruster", fd["thruster"])
        if thr is not None:
            fault["thruster"] = thr
        frac = fd.get("fraction")
        if isinstance(frac, dict):
            frac = frac.get(kind)
        if frac is not None:
            fault["fraction"] = _r(draw("fault.fraction", frac))
        clear = fd.get("clear_after_s")
        if isinstance(clear, dict):
            clear = clear.get(kind)
        if clear is not None:
            fault["clear_t_s"] = _r(fault["t_s"] + draw("fault.clear_after_s", clear))
        if "axis" in fd:
            fault["axis"] = int(draw("fault.axis", fd["axis"]))
        mag = fd.get("magnitude_rad_s")
        if isinstance(mag, dict):
            mag = mag.get(kind)
        if mag is not None:
            fault["magnitude_rad_s"] = _r(draw("fault.magnitude_rad_s", mag))
        faults.append(fault)
        params.update({f"fault_{key}": v for key, v in fault.items()})

    name = run_name(c, k)
    scen: dict[str, Any] = {
        "name": name,
        "description": f"run {k} of campaign {c.name} (master seed {seed}); written by "
                       f"`hil campaign expand`",
        "vehicle": c.vehicle_ref,
        "duration_s": params["duration_s"],
        "seed": noise_seed,
    }
    for key in ("initial", "target"):
        val = initial if key == "initial" else base.get("target")
        if val:
            scen[key] = val
    if plant:
        scen["plant"] = plant
    flight = _merge(dict(base.get("flight") or {}), dict(c.model.flight))
    if flight:
        scen["flight"] = flight
    if faults:
        scen["faults"] = faults
    scen["expect"] = {"no_false_alarm": True}
    if base.get("safety"):
        scen["safety"] = base["safety"]
    if base.get("bus"):  # the bus `hil campaign --bus` runs it over (docs/lcm.md)
        scen["bus"] = base["bus"]
    return RunSpec(run=k, name=name, scenario=scen, vehicle=vehicle, vehicle_changed=changed,
                   vehicle_ref=c.vehicle_ref, params=params, fault=fault)


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


class _Dumper(yaml.SafeDumper):
    pass


def _flow_lists(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    # Short lists of scalars on one line ([x, y, z]) as the shipped files write them.
    flow = len(data) <= 4 and all(not isinstance(x, (dict, list)) for x in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _flow_lists)
_Dumper.add_representer(tuple, _flow_lists)


def dump_yaml(d: dict[str, Any]) -> str:
    return yaml.dump(d, Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=100)


def write_run(spec: RunSpec, out: Path, *, inline_vehicle: bool = False,
              absolute: bool = False) -> Path:
    """Write the run's scenario (and its vehicle when it differs from the base, or always with
    ``inline_vehicle``) into ``out``; return the scenario's path. The scenario names its
    vehicle file by name (beside it), or by absolute path with ``absolute`` (tasks: a file of
    the same name in the worker's working folder must not be taken instead)."""
    out.mkdir(parents=True, exist_ok=True)
    scen = dict(spec.scenario)
    if spec.vehicle_changed or inline_vehicle or spec.vehicle_ref == "inline":
        vpath = out / f"{spec.name}.vehicle.yaml"
        vpath.write_text(f"# vehicle of run {spec.run} ({spec.name}): the base vehicle with "
                         f"this run's gyro and flex draws\n" + dump_yaml(spec.vehicle))
        scen["vehicle"] = str(vpath.resolve()) if absolute or inline_vehicle else vpath.name
    path = out / f"{spec.name}.yaml"
    path.write_text(dump_yaml(scen))
    return path


def needs_command(fault: dict[str, Any] | None) -> bool:
    """Whether observing this fault needs its thruster to be commanded after ``t_s``: a thruster
    that fails to fire (or gives less thrust) shows nothing while it is not commanded. A stuck-on
    thruster shows itself while commanded off, a gyro fault without any command."""
    return bool(fault and fault.get("thruster") is not None
                and fault["kind"] in ("fail_to_fire", "degraded"))
