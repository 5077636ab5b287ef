"""Distributions of the campaign file and the seeded draws of one run.

A distribution is a mapping with one key, or a bare value (``fixed``)::

    {uniform: [low, high]}       # continuous, low <= high
    {normal: [mean, std]}        # std >= 0
    {choice: [a, b, c]}          # each equally likely
    {cycle: [a, b, c]}           # run k takes item (k // stride) % len; {cycle: [...], stride: 3}
    {fixed: value}               # or just: value

``cycle`` covers every combination in a few runs (fault kinds with stride 1 and thrusters with
stride 3 go through all kind x thruster pairs in 3 N runs); the others are random.

Every draw of run k comes from its own stream, ``SeedSequence(master_seed, spawn_key=(k,
crc32(name)))``: run k's parameters depend on the master seed, k and the dispersion's name
alone, so a run is the same on any worker, in any order, and adding one dispersion to a file
does not change the draws of the others.

``DISPERSIONS`` lists what may be dispersed and where it goes (the scenario's ``plant:`` and
``initial:`` sections, or the run's copy of the vehicle for gyro and flex figures, which the
scenario cannot override: see ``hil.campaign.expansion``).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

DIST_KEYS = ("uniform", "normal", "choice", "cycle", "fixed")


class DistError(ValueError):
    """A bad distribution: ``field``, what was ``expected``, what was ``found``."""

    def __init__(self, field: str, expected: str, found: object) -> None:
        super().__init__(f"{field}: expected {expected}, got {found!r}")
        self.field, self.expected, self.found = field, expected, found


@dataclass(frozen=True)
class DispSpec:
    """``kind``: what one value must be; ``per``: one draw per run, per thruster, per axis or
    per flex mode; ``doc``: where the value goes."""

    kind: str
    per: str
    doc: str


DISPERSIONS: dict[str, DispSpec] = {
    "thrust_scale": DispSpec("positive", "run", "plant.thrust_scale (every thruster)"),
    "thrust_scale_per_thruster": DispSpec("positive", "thruster",
                                          "plant.thrust_scale_per_thruster (one draw each)"),
    "direction_error_deg": DispSpec("nonneg", "run", "plant.direction_error_deg"),
    "command_latency_ms": DispSpec("nonneg", "run", "plant.command_latency_ms"),
    "initial_angle_deg": DispSpec("number", "run", "initial.attitude.angle_deg"),
    "initial_axis": DispSpec("vector3", "run",
                             "initial.attitude.axis (default: uniform on the sphere)"),
    "initial_rate_deg_s": DispSpec("nonneg", "run",
                                   "|initial.rate_B_deg_s|, in a direction uniform on the sphere"),
    "gyro_noise_std_rad_s": DispSpec("nonneg", "run", "vehicle gyro.noise_std_rad_s"),
    "gyro_bias_rad_s": DispSpec("number", "axis3", "vehicle gyro.bias_rad_s (one draw per axis)"),
    "flex_freq_scale": DispSpec("positive", "flex_mode",
                                "vehicle flex_modes[i].freq_hz times the draw (one per mode)"),
    "flex_log_decrement_scale": DispSpec(
        "positive", "flex_mode", "vehicle flex_modes[i].log_decrement times the draw (per mode)"),
    "noise_seed": DispSpec("seed", "run", "scenario seed (default: drawn per run)"),
}


def stream(master_seed: int, run: int, name: str) -> np.random.Generator:
    """The random stream of one dispersion of one run (module doc)."""
    ss = np.random.SeedSequence(master_seed, spawn_key=(run, zlib.crc32(name.encode())))
    return np.random.Generator(np.random.PCG64(ss))


@dataclass(frozen=True)
class Dist:
    """One parsed distribution; ``draw(rng, run)`` gives one value."""

    form: str
    args: tuple[Any, ...]
    stride: int = 1

    def draw(self, rng: np.random.Generator, run: int) -> Any:
        if self.form == "fixed":
            return self.args[0]
        if self.form == "uniform":
            lo, hi = self.args
            return float(rng.uniform(lo, hi)) if hi > lo else float(lo)
        if self.form == "normal":
            mean, std = self.args
            return float(rng.normal(mean, std)) if std > 0 else float(mean)
        if self.form == "choice":
            return self.args[int(rng.integers(len(self.args)))]
        if self.form == "cycle":
            return self.args[(run // self.stride) % len(self.args)]
        raise AssertionError(self.form)

    def values(self) -> tuple[Any, ...] | None:
        """The finite set of values it can take, or None for a continuous one."""
        if self.form == "fixed":
            return (self.args[0],)
        if self.form in ("choice", "cycle"):
            return tuple(self.args)
        return None

    def bounds(self) -> tuple[float, float] | None:
        if self.form == "uniform":
            return self.args
        if self.form == "normal":
            return (-math.inf, math.inf) if self.args[1] > 0 else (self.args[0],) * 2
        vals = self.values()
        if vals and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
            return (min(vals), max(vals))
        return None


_KIND_TEXT = {
    "positive": "a number > 0",
    "nonneg": "a number >= 0",
    "number": "a number",
    "fraction": "a number in [0, 1]",
    "string": "a string",
    "axis": "an axis 0, 1 or 2",
    "vector3": "a non-zero vector [x, y, z]",
    "seed": "an integer >= 0",
}


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_value(v: Any, where: str, kind: str) -> Any:
    ok = {
        "positive": lambda x: _is_num(x) and x > 0,
        "nonneg": lambda x: _is_num(x) and x >= 0,
        "number": _is_num,
        "fraction": lambda x: _is_num(x) and 0 <= x <= 1,
        "string": lambda x: isinstance(x, str) and x != "",
        "axis": lambda x: isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 2,
        "vector3": lambda x: isinstance(x, list) and len(x) == 3 and all(map(_is_num, x))
        and any(c != 0 for c in x),
        "seed": lambda x: isinstance(x, int) and not isinstance(x, bool) and x >= 0,
    }[kind]
    if not ok(v):
        raise DistError(where, _KIND_TEXT[kind], v)
    if kind == "vector3":
        return tuple(float(c) for c in v)
    return float(v) if kind in ("positive", "nonneg", "number", "fraction") else v


def _continuous_ok(kind: str, lo: float, hi: float, where: str, form: str) -> None:
    """The whole range of a continuous distribution must be valid for the kind."""
    if kind in ("string", "axis", "vector3", "seed"):
        raise DistError(where, f"choice, cycle or fixed for {_KIND_TEXT[kind]}",
                        f"{form} (a continuous distribution)")
    if kind == "positive" and lo <= 0:
        raise DistError(where, "a range above 0", [lo, hi])
    if kind == "nonneg" and lo < 0:
        raise DistError(where, "a range at or above 0", [lo, hi])
    if kind == "fraction" and (lo < 0 or hi > 1):
        raise DistError(where, "a range within [0, 1]", [lo, hi])


def parse_dist(raw: Any, where: str, kind: str) -> Dist:
    """Parse one distribution of values of ``kind`` (``_KIND_TEXT``); ``where`` names it."""
    if not isinstance(raw, dict):
        return Dist("fixed", (_check_value(raw, where, kind),))
    keys = set(raw)
    forms = keys & set(DIST_KEYS)
    if len(forms) != 1 or keys - forms - ({"stride"} if forms == {"cycle"} else set()):
        raise DistError(where, "one of uniform, normal, choice, cycle or fixed (one key; "
                        "cycle may add stride)", sorted(keys))
    form = forms.pop()
    arg = raw[form]
    w = f"{where}.{form}"
    if form == "fixed":
        return Dist("fixed", (_check_value(arg, w, kind),))
    if form in ("uniform", "normal"):
        if not (isinstance(arg, list) and len(arg) == 2 and all(map(_is_num, arg))):
            shape = "[low, high]" if form == "uniform" else "[mean, std]"
            raise DistError(w, f"{shape} (two numbers)", arg)
        a, b = float(arg[0]), float(arg[1])
        if form == "uniform":
            if a > b:
                raise DistError(w, "[low, high] with low <= high", arg)
            _continuous_ok(kind, a, b, w, form)
        else:
            if b < 0:
                raise DistError(w, "[mean, std] with std >= 0", arg)
            if kind in ("string", "axis", "vector3", "seed"):
                _continuous_ok(kind, a, a, w, form)
            if b == 0:
                _check_value(a, w, kind)
            # A normal draw outside a field's range (a negative latency) is that run's error,
            # reported by the scenario loader; use uniform for hard bounds.
        return Dist(form, (a, b))
    if not (isinstance(arg, list) and arg):
        raise DistError(w, "a non-empty list", arg)
    vals = tuple(_check_value(v, f"{w}[{i}]", kind) for i, v in enumerate(arg))
    stride = raw.get("stride", 1)
    if not (isinstance(stride, int) and not isinstance(stride, bool) and stride >= 1):
        raise DistError(f"{where}.stride", "an integer >= 1", stride)
    return Dist(form, vals, stride)


def parse_thruster_dist(raw: Any, where: str, thrusters: tuple[str, ...],
                        manifolds: dict[str, tuple[str, ...]]) -> Dist:
    """Thruster of a fault: ``any`` (a random one), ``all`` in a cycle, ``{manifold: M}`` (a
    random one of that manifold), ``{choice|cycle: [names]}`` (a belt is a list of names), a
    name, or ``{fixed: name}``. Names are checked against the vehicle."""
    if raw == "any":
        return Dist("choice", thrusters)
    if raw == "none":
        return Dist("fixed", (None,))
    if isinstance(raw, dict) and set(raw) == {"manifold"}:
        m = raw["manifold"]
        if m not in manifolds:
            raise DistError(f"{where}.manifold", f"one of {sorted(manifolds)}", m)
        return Dist("choice", manifolds[m])
    if isinstance(raw, dict) and raw.get("cycle") == "all":
        raw = dict(raw, cycle=list(thrusters))
    if isinstance(raw, dict) and raw.get("choice") == "all":
        raw = dict(raw, choice=list(thrusters))
    d = parse_dist(raw, where, "string")
    for v in d.values() or ():
        if v not in thrusters:
            raise DistError(where, "thruster names of the vehicle (or any, all, {manifold: M})",
                            v)
    return d
