"""Sub-commands of `hil` owned by the flight package: ``hil thresholds`` (DESIGN 6.4 step 6)."""

from __future__ import annotations

import argparse

from flight.thresholds import load_xi, propose
from hil.argtypes import integer, number


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
    prop = propose(args.detection_time, args.tick, xi_seq=xi_seq, xi_mean=args.xi_mean,
                   xi_max=args.xi_max, run=args.run, xi_fault=args.xi_fault, margin=args.margin)
    for line in prop.reasoning:
        print(line)
    return 0
