"""``hil dbc``: write, check and size the DBC generated from the catalog (docs/design.md 4)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bus.catalog import BITRATE_BPS, CATALOG, FRAME_BYTES, bus_load, classic_frame_bits
from bus.dbc import DBC_PATH, dbc_text
from hil.errors import UsageError


def register(sub) -> None:
    """Add ``dbc`` to ``sub``."""
    p = sub.add_parser(
        "dbc",
        help="write, check or size the CAN database (bus/hil.dbc)",
        description="Generate the DBC from the message catalog.",
    )
    p.add_argument("--out", metavar="FILE", help="write the DBC here (default: stdout)")
    p.add_argument("--vehicle", metavar="V",
                   help="a DBC for this vehicle: value tables name the thruster indices "
                        "(FDIR_STATUS.thruster_a/b, FAULT_CMD.thruster) and 63 = none")
    p.add_argument(
        "--check",
        action="store_true",
        help="exit 1 if the committed bus/hil.dbc differs from the catalog",
    )
    p.add_argument(
        "--load",
        action="store_true",
        help="print the bus load per frame and in total at the nominal cycle times",
    )
    p.add_argument(
        "--bitrate",
        type=int,
        default=BITRATE_BPS,
        metavar="BPS",
        help=f"bit rate for --load (default {BITRATE_BPS})",
    )
    p.set_defaults(func=run)


def load_table(bitrate_bps: int) -> str:
    bits = classic_frame_bits(FRAME_BYTES)
    lines = [
        f"bus load at {bitrate_bps} bit/s, classic CAN, {bits} bits per 8-byte frame "
        "(worst-case stuffing)",
        f"{'frame':<18}{'id':>7}{'cycle ms':>10}{'bit/s':>10}{'load %':>9}",
    ]
    total = 0.0
    for name, bps, frac in bus_load(bitrate_bps):
        f = CATALOG.frame(name)
        total += bps
        lines.append(
            f"{name:<18}{f'0x{f.frame_id:03X}':>7}{f.cycle_s * 1000:>10.0f}"
            f"{bps:>10.0f}{100 * frac:>9.3f}"
        )
    on_demand = [f.name for f in CATALOG.frames if f.cycle_s is None]
    lines.append(f"{'total':<18}{'':>7}{'':>10}{total:>10.0f}{100 * total / bitrate_bps:>9.3f}")
    lines.append(f"on demand, not counted: {', '.join(on_demand)}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.bitrate <= 0:
        raise UsageError(f"hil dbc: --bitrate: expected > 0, got {args.bitrate}")
    names = None
    if getattr(args, "vehicle", None):
        from hil.config import load_vehicle

        names = [t.name for t in load_vehicle(args.vehicle).thrusters]
    text = dbc_text(thruster_names=names)
    if args.check and names is not None:
        raise UsageError("hil dbc: --check: expected no --vehicle (bus/hil.dbc is the "
                         "vehicle-free one), got --vehicle")
    if args.check:
        committed = DBC_PATH.read_bytes() if DBC_PATH.exists() else b""
        if committed != text.encode():
            print(
                f"{DBC_PATH.name}: differs from the catalog; run `hil dbc --out bus/hil.dbc`",
                file=sys.stderr,
            )
            return 1
        print(f"{DBC_PATH.name}: matches the catalog")
        return 0
    if args.load:
        print(load_table(args.bitrate))
        return 0
    if args.out:
        Path(args.out).write_bytes(text.encode())
    else:
        sys.stdout.write(text)
    return 0
