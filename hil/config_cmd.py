"""`hil config check FILE...`: validate vehicle and scenario files."""

from __future__ import annotations

import sys

from hil.config import Scenario, load_any
from hil.errors import ConfigError


def _check(args) -> int:
    bad = 0
    for path in args.files:
        try:
            obj = load_any(path)
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            bad += 1
            continue
        if isinstance(obj, Scenario):
            print(f"ok: {path}: scenario {obj.cfg.name} on vehicle {obj.vehicle.name}, "
                  f"{len(obj.cfg.faults)} fault(s), {obj.cfg.duration_s:g} s")
        else:
            print(f"ok: {path}: vehicle {obj.name}, {len(obj.thrusters)} thrusters, "
                  f"{len(obj.manifolds)} manifold(s), {len(obj.flex_modes)} flex mode(s)")
    return 2 if bad else 0


def register(sub) -> None:
    p = sub.add_parser("config", help="validate configuration files")
    csub = p.add_subparsers(dest="config_command", metavar="ACTION", required=True)
    c = csub.add_parser(
        "check", help="validate vehicle and scenario YAML files (exit 2 if any is bad)"
    )
    c.add_argument("files", nargs="+", metavar="FILE")
    c.set_defaults(func=_check)
