"""DBC generation from the catalog, through cantools' database model (docs/design.md section 4).

``build_database()`` turns ``bus.catalog.CATALOG`` into ``cantools.database.can.Database``
(one Message per frame, with the E2E header as two ordinary signals so that any DBC tool
shows them); ``dbc_text()`` dumps it. ``bus/hil.dbc`` is that text, committed; a test and
``hil dbc --check`` regenerate it and compare.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from bus.catalog import CATALOG, FRAME_BYTES, Catalog, FrameDef, SignalDef

DBC_PATH = Path(__file__).with_name("hil.dbc")
DBC_VERSION = "thruster-hil bus 1"
E2E_CRC = "E2E_CRC"
E2E_COUNTER = "E2E_COUNTER"


def _node_name(node) -> str:
    return node.name


def _num(x: float) -> float | int:
    """Integral limits as ints, so the DBC reads [0|255] rather than [0.0|255.0]."""
    return int(x) if float(x).is_integer() else x


# Signals that carry a thruster index (63: none / not applicable).
THRUSTER_INDEX_SIGNALS = {("FDIR_STATUS", "thruster_a"), ("FDIR_STATUS", "thruster_b"),
                          ("FAULT_CMD", "thruster")}
NO_THRUSTER_VALUE = 63


def _signal(s: SignalDef, receivers: list[str],
            names: dict[int, str] | None = None) -> Signal:
    choices = dict(sorted(s.choices.items())) if s.choices else None
    if names is not None:
        choices = dict(sorted({**(choices or {}), **names}.items()))
    return Signal(
        name=s.name,
        start=s.start_bit,
        length=s.length,
        byte_order="little_endian",
        is_signed=s.signed,
        conversion=BaseConversion.factory(scale=s.scale, offset=s.offset, choices=choices),
        minimum=_num(s.minimum),
        maximum=_num(s.phys_max),
        unit=s.unit or None,
        comment=s.comment or None,
        receivers=receivers,
    )


def _message(f: FrameDef, thruster_names: list[str] | None = None) -> Message:
    receivers = [_node_name(n) for n in f.receivers]
    header = [
        Signal(
            E2E_CRC,
            0,
            8,
            minimum=0,
            maximum=255,
            comment=f"CRC-8/SAE-J1850 over data ID 0x{f.data_id:04X} and bytes 1..7",
            receivers=receivers,
        ),
        Signal(
            E2E_COUNTER,
            8,
            4,
            minimum=0,
            maximum=15,
            comment="E2E alive counter 0..15",
            receivers=receivers,
        ),
    ]
    return Message(
        frame_id=f.frame_id,
        name=f.name,
        length=FRAME_BYTES,
        signals=header + [_signal(s, receivers, _index_names(f, s, thruster_names))
                          for s in f.signals],
        comment=f.comment or None,
        senders=[_node_name(f.sender)],
        cycle_time=None if f.cycle_s is None else round(f.cycle_s * 1000),
        strict=True,
    )


def _index_names(f: FrameDef, s: SignalDef,
                 thruster_names: list[str] | None) -> dict[int, str] | None:
    """A value table for a thruster-index signal: the vehicle's names and 63 = none."""
    if thruster_names is None:
        return None
    base = f.name.rstrip("0123456789").rstrip("_")
    if (base, s.name) not in THRUSTER_INDEX_SIGNALS:
        return None
    return {**dict(enumerate(thruster_names)), NO_THRUSTER_VALUE: "none"}


def build_database(catalog: Catalog = CATALOG,
                   thruster_names: list[str] | None = None) -> Database:
    """The catalog as a cantools database; with ``thruster_names`` (one vehicle's, in index
    order) the thruster-index signals get value tables: each index's name, 63 = none."""
    nodes = sorted({n for f in catalog.frames for n in (f.sender, *f.receivers)})
    return Database(
        messages=[_message(f, thruster_names)
                  for f in sorted(catalog.frames, key=lambda f: f.frame_id)],
        nodes=[Node(_node_name(n), comment=None) for n in nodes],
        version=DBC_VERSION,
    )


@cache
def database() -> Database:
    """The cached cantools model of the catalog (used by the codecs)."""
    return build_database()


def dbc_text(catalog: Catalog = CATALOG, thruster_names: list[str] | None = None) -> str:
    return build_database(catalog, thruster_names).as_dbc_string()
