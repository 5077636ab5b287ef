"""``hil thresholds``: propose the detector's forgetting factor and thresholds (the design, 6.4
step 6) from the pure proposal in ``flight.thresholds``; this shell reads the statistics file and
names the command-line flags in its errors."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from flight.errors import ThresholdError
from flight.thresholds import propose
from hil.argtypes import integer, number
from hil.errors import UsageError

# propose()'s parameter names -> the flags that set them (errors name the flag the user typed).
_FLAGS = {"detection_time_s": "--detection-time", "tick_s": "--tick", "xi_fault": "--xi-fault",
          "margin": "--margin", "xi_mean": "--xi-mean", "xi_max": "--xi-max", "run": "--run"}
_PARAM = re.compile(r"(?:^|(?<=; )|(?<=, ))(" + "|".join(_FLAGS) + r")(?=[:,])")


def register(sub) -> None:
    """Add this module's sub-parsers to ``sub``."""
    p = sub.add_parser(
        "thresholds",
        help="propose detector forgetting factor and thresholds",
        description=(
            "Propose the detector's forgetting factor w and thresholds from a required "
            "detection time and fault-free residual statistics (seed 000: "
            "rho[n] = xi (1 - w^(n+1)) / (1 - w)). Give either --stats FILE (xi of a "
            "fault-free run, JSON {\"xi\": [[...]]} or NPZ with array xi, shape (ticks, "
            "thrusters)) or --xi-mean/--xi-max/--run."
        ),
    )
    p.add_argument("--detection-time", type=number(gt=0, le=86400), required=True, metavar="S",
                   help="required detection time, s")
    p.add_argument("--tick", type=number(gt=0, le=10), default=0.2, metavar="S",
                   help="flight tick, s (0.2)")
    p.add_argument("--stats", metavar="FILE", help="xi sequences of a fault-free run")
    p.add_argument("--xi-mean", type=number(ge=0, le=1), default=0.02,
                   help="mean |xi| without fault (0.02)")
    p.add_argument("--xi-max", type=number(gt=0, le=1), default=1.0,
                   help="largest |xi| without fault (1)")
    p.add_argument("--run", type=integer(ge=1, le=10000), default=1,
                   help="longest burst of consecutive outliers without fault (1)")
    p.add_argument("--xi-fault", type=number(gt=0, le=1), default=1.0,
                   help="projection of the residual under a fault (1 with normalisation)")
    p.add_argument("--margin", type=number(ge=1, le=100), default=1.5,
                   help="threshold / no-fault maximum (1.5)")
    p.set_defaults(func=_thresholds)


def _thresholds(args: argparse.Namespace) -> int:
    xi_seq = load_xi(args.stats) if args.stats else None
    try:
        prop = propose(args.detection_time, args.tick, xi_seq=xi_seq, xi_mean=args.xi_mean,
                       xi_max=args.xi_max, run=args.run, xi_fault=args.xi_fault,
                       margin=args.margin)
    except ThresholdError as exc:
        raise UsageError(_PARAM.sub(lambda m: _FLAGS[m.group(1)], str(exc))) from None
    for line in prop.reasoning:
        print(line)
    return 0


def load_xi(path: str | Path) -> np.ndarray:
    """Projections xi (T, N) of a fault-free run from a JSON file ({"xi": [[...], ...]}) or an
    NPZ archive with an array ``xi``."""
    p = Path(path)
    if not p.exists():
        raise UsageError(f"{p}: expected an existing JSON or NPZ file, got no such file")
    try:
        if p.suffix == ".npz":
            with np.load(p) as data:
                if "xi" not in data:
                    raise UsageError(f"{p}: expected an array 'xi', got {sorted(data.files)}")
                xi = np.asarray(data["xi"], dtype=float)
        else:
            obj = json.loads(p.read_text(encoding="utf-8"))
            if not isinstance(obj, dict) or "xi" not in obj:
                raise UsageError(
                    f"{p}: expected a JSON object with a key 'xi', got {type(obj).__name__}")
            xi = np.asarray(obj["xi"], dtype=float)
    except (ValueError, OSError) as exc:
        raise UsageError(f"{p}: expected numeric xi (T, N), got {exc}") from None
    if xi.ndim == 1:
        xi = xi[:, None]
    if xi.ndim != 2 or xi.size == 0 or not np.all(np.isfinite(xi)):
        raise UsageError(f"{p}: xi: expected a finite (T, N) array, got shape {xi.shape}")
    return xi
