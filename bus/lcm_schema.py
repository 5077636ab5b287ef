"""LCM types generated from the message catalog (docs/lcm.md): the catalog stays the one source.

Every logical message of ``bus.catalog`` (a frame set, or a single frame) becomes one LCM
struct of package ``hil_lcm`` on one channel (``HIL_<SET>``). Its fields are the catalog's
signals in engineering units, derived by rule, never written by hand:

* a signal with a scale or a physical unit is a ``double`` named with its unit
  (``rate_x`` in rad/s -> ``double rate_x_rad_s``); ``10ms`` quanta become integer
  milliseconds (``on_q_NN`` -> ``int16_t on_ms[32]``);
* a plain integer signal keeps its name and gets the smallest LCM integer type that holds its
  range (``tick`` -> ``int32_t tick``);
* consecutive ``NAME_00, NAME_01, ...`` signals become one fixed-size array;
* signals that only repeat a set's key (``tick_lo``, ``seq_lo``, ``request_id`` in a second
  frame) are left out: the receiver derives them from the full key.

Then the E2E block: ``e2e_counter[n]`` and ``e2e_crc[n]`` are the alive counter and CRC-8 of
each of the ``n`` CAN frames of the set, computed by the very same ``bus.e2e.Protector`` over
the frames the message would be on CAN. A receiver rebuilds the frames from the typed fields
and this block and hands them to the same ``bus.receiver.Receiver`` as on CAN, so tick,
sequence, counter, CRC, range, completeness and staleness rules are the same on both buses: a
changed typed field fails its frame's CRC; a lost or repeated message shows in the counters.

``lcm_files()`` writes the ``.lcm`` text; ``lcm-gen --python`` makes ``bus/hil_lcm/`` from it
(``hil lcm-types``; a test regenerates both and diffs). ``to_fields`` / ``to_frames`` convert
between CAN frames and the field values of a struct (pure; ``bus.lcm_transport`` does I/O).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from bus.catalog import CATALOG, Catalog, FrameDef, Node, SignalDef
from bus.codec import Frame, pack, unpack

PACKAGE = "hil_lcm"
CHANNEL_PREFIX = "HIL_"
LCM_DIR = Path(__file__).with_name("lcm")  # the generated .lcm files (committed)
PY_DIR = Path(__file__).parent  # lcm-gen --ppath: makes bus/hil_lcm/
_ARRAY_RE = re.compile(r"^(?P<base>.+)_(?P<idx>\d{2})$")
# Units whose name is a multiple of another: the LCM field gets the base unit.
_UNIT_MULTIPLES = {"10ms": ("ms", 10)}
_UNIT_SUFFIX = {"rad/s": "rad_s", "s": "s", "ms": "ms"}


@dataclass(frozen=True)
class FieldDef:
    """One field of an LCM struct.

    ``sources``: (frame name, signal name) for each element (one for a scalar).
    ``factor``: field value = physical catalog value * factor (integers stay integers).
    """

    name: str
    lcm_type: str
    sources: tuple[tuple[str, str], ...]
    factor: int = 1
    is_array: bool = False
    comment: str = ""


@dataclass(frozen=True)
class StructDef:
    """One LCM struct: the typed form of one logical message of the catalog."""

    name: str  # e.g. thr_cmd_t
    set_name: str  # the catalog's logical message, e.g. THR_CMD
    frames: tuple[FrameDef, ...]
    fields: tuple[FieldDef, ...]
    derived: tuple[tuple[str, str, str], ...]  # (frame, signal, full-key signal): value & mask

    @property
    def channel(self) -> str:
        return CHANNEL_PREFIX + self.set_name


def _int_type(s: SignalDef, factor: int) -> str:
    lo = s.raw_min * factor if s.signed else 0
    hi = s.raw_max * factor
    for t, bits in (("int8_t", 8), ("int16_t", 16), ("int32_t", 32)):
        if -(1 << (bits - 1)) <= lo and hi < (1 << (bits - 1)):
            return t
    return "int64_t"


def _field_for(s: SignalDef) -> tuple[str, str, int]:
    """(field name, LCM type, factor) of one signal."""
    if s.unit in _UNIT_MULTIPLES and s.scale == 1 and s.offset == 0:
        unit, factor = _UNIT_MULTIPLES[s.unit]
        base = s.name[:-2] if s.name.endswith("_q") else s.name  # on_q (quanta) -> on_ms
        return f"{base}_{_UNIT_SUFFIX[unit]}", _int_type(s, factor), factor
    if s.scale == 1 and s.offset == 0:
        return s.name, _int_type(s, 1), 1
    suffix = _UNIT_SUFFIX.get(s.unit)
    return (f"{s.name}_{suffix}" if suffix else s.name), "double", 1


def _with_unit(comment: str, field_name: str) -> str:
    for unit, suffix in _UNIT_SUFFIX.items():
        if field_name.endswith("_" + suffix):
            return f"{comment} [{unit}]".strip()
    return comment


def _set_names(catalog: Catalog) -> list[str]:
    names: list[str] = []
    for f in catalog.frames:
        n = f.set_name or f.name
        if n not in names:
            names.append(n)
    return names


def _struct_name(set_name: str) -> str:
    # The three heartbeats carry the same signals: one struct, one channel per node.
    if set_name in {f"HEARTBEAT_{n.name}" for n in Node}:
        return "heartbeat_t"
    if set_name in {f"HEARTBEAT_{n.name}_MAC" for n in Node}:
        return "heartbeat_mac_t"
    return set_name.lower() + "_t"


def _derived_keys(frames: tuple[FrameDef, ...]) -> dict[tuple[str, str], str]:
    """Key signals that hold only the low bits of the set's full key -> the full key's name."""
    keys = [(f, f.signal(f.key_signal)) for f in frames if f.key_signal]
    if not keys:
        return {}
    full_f, full = max(keys, key=lambda k: k[1].length)
    out = {}
    for f, s in keys:
        if (f.name, s.name) != (full_f.name, full.name):
            out[(f.name, s.name)] = full.name
    return out


def build_struct(set_name: str, catalog: Catalog = CATALOG) -> StructDef:
    frames = catalog.set_frames(set_name)
    derived = _derived_keys(frames)
    fields: list[FieldDef] = []
    arrays: dict[str, list] = {}
    for f in frames:
        for s in f.signals:
            if (f.name, s.name) in derived:
                continue
            m = _ARRAY_RE.match(s.name)
            if m:
                base = m.group("base")
                if base not in arrays:
                    arrays[base] = []
                    fields.append(FieldDef(base, "", (), is_array=True))  # placeholder
                arrays[base].append((f, s))
                continue
            name, typ, factor = _field_for(s)
            fields.append(FieldDef(name, typ, ((f.name, s.name),), factor,
                                   comment=_with_unit(s.comment, name)))
    out = []
    for fd in fields:
        if not fd.is_array:
            out.append(fd)
            continue
        members = arrays[fd.name]
        f0, s0 = members[0]
        name, typ, factor = _field_for(SignalDef(fd.name, s0.start_bit, s0.length,
                                                 s0.scale, s0.offset, signed=s0.signed,
                                                 unit=s0.unit))
        comment = re.sub(r"thruster index \d+", "thruster index i", s0.comment or "")
        comment = re.sub(r" in 10 ms quanta", "", comment)
        out.append(FieldDef(name, typ, tuple((f.name, s.name) for f, s in members), factor,
                            is_array=True, comment=_with_unit(comment, name)))
    # A full key first in the set is the struct's first field already; keep catalog order.
    return StructDef(_struct_name(set_name), set_name, frames, tuple(out),
                     tuple((fn, sn, full) for (fn, sn), full in derived.items()))


def structs(catalog: Catalog = CATALOG) -> tuple[StructDef, ...]:
    """Every logical message's struct, in catalog order (heartbeats share one struct)."""
    return tuple(build_struct(n, catalog) for n in _set_names(catalog))


def by_channel(catalog: Catalog = CATALOG) -> dict[str, StructDef]:
    return {s.channel: s for s in structs(catalog)}


def by_set(catalog: Catalog = CATALOG) -> dict[str, StructDef]:
    return {s.set_name: s for s in structs(catalog)}


# --- .lcm text ---------------------------------------------------------------------------


def lcm_text(st: StructDef) -> str:
    """The ``.lcm`` definition of one struct (deterministic: diffed by the tests)."""
    senders = sorted({f.sender.name.lower() for f in st.frames})
    lines = [
        "// Generated from bus/catalog.py by bus/lcm_schema.py (`hil lcm-types`); do not edit.",
        f"// Logical message {st.set_name}, in engineering units; its CAN frames:",
        *(f"//   0x{f.frame_id:03X} {f.name}: {f.comment}" for f in st.frames),
        f"// Sent by {', '.join(senders)}; channel {CHANNEL_PREFIX}{st.set_name}"
        + (" (and the other nodes' heartbeat channels)"
           if st.name in ("heartbeat_t", "heartbeat_mac_t") else "")
        + ".",
        f"package {PACKAGE};",
        "",
        f"struct {st.name}",
        "{",
    ]
    for fd in st.fields:
        dim = f"[{len(fd.sources)}]" if fd.is_array else ""
        if fd.comment:  # before the field: lcm-gen gives a leading comment to its field
            lines.append(f"    // {fd.comment}")
        lines.append(f"    {fd.lcm_type} {fd.name}{dim};")
    lines += [
        "",
        "    // E2E: alive counter (0..15) and CRC-8/SAE-J1850 of each CAN frame of the set,",
        "    // in set order, as bus.e2e computes them over the frame the message would be.",
        "    int8_t n_frames;",
        "    int8_t e2e_counter[n_frames];",
        "    byte e2e_crc[n_frames];",
        "}",
        "",
    ]
    return "\n".join(lines)


def lcm_files(catalog: Catalog = CATALOG) -> dict[str, str]:
    """File name -> text of every ``.lcm`` file."""
    out: dict[str, str] = {}
    for st in structs(catalog):
        out.setdefault(f"{st.name}.lcm", lcm_text(st))
    return out


# --- frames <-> field values (pure) ------------------------------------------------------


def to_fields(st: StructDef, frames: list[Frame]) -> dict:
    """Field values of ``st`` from the set's protected CAN frames (in set order)."""
    raws = {f.name: unpack(f, fr.data) for f, fr in zip(st.frames, frames, strict=True)}
    out: dict = {}
    for fd in st.fields:
        vals = []
        for fname, sname in fd.sources:
            f = next(x for x in st.frames if x.name == fname)
            s = f.signal(sname)
            raw = raws[fname][sname]
            if fd.lcm_type == "double":
                vals.append(raw * s.scale + s.offset)
            else:
                vals.append(raw * fd.factor)
        out[fd.name] = vals if fd.is_array else vals[0]
    out["n_frames"] = len(frames)
    out["e2e_counter"] = [fr.data[1] & 0x0F for fr in frames]
    out["e2e_crc"] = bytes(fr.data[0] for fr in frames)
    return out


def _raw_of(s: SignalDef, value, factor: int, is_double: bool) -> int:
    if is_double:
        return round((float(value) - s.offset) / s.scale)
    v = int(value)
    return v // factor if factor != 1 else v


def to_frames(st: StructDef, values: dict, rx_time_s: float | None = None) -> list[Frame]:
    """The CAN frames a received struct stands for (E2E header from its E2E block).

    The frames go to ``bus.receiver.Receiver`` unchanged; a field out of its signal's bits
    is masked by ``pack`` (and then fails the CRC), never raised here. A message whose E2E
    block does not have one entry per frame of the set yields no frames (ValueError).
    """
    n = len(st.frames)
    counters, crcs = list(values["e2e_counter"]), bytes(values["e2e_crc"])
    if values["n_frames"] != n or len(counters) != n or len(crcs) != n:
        raise ValueError(f"{st.name}: expected {n} frames in the E2E block, "
                         f"got {values['n_frames']}")
    raws: dict[str, dict[str, int]] = {f.name: {} for f in st.frames}
    frame_by_name = {f.name: f for f in st.frames}
    for fd in st.fields:
        vals = values[fd.name] if fd.is_array else [values[fd.name]]
        for (fname, sname), v in zip(fd.sources, vals, strict=True):
            s = frame_by_name[fname].signal(sname)
            raws[fname][sname] = _raw_of(s, v, fd.factor, fd.lcm_type == "double")
    for fname, sname, full in st.derived:
        src = next(r[full] for r in raws.values() if full in r)
        raws[fname][sname] = src & ((1 << frame_by_name[fname].signal(sname).length) - 1)
    out = []
    for k, f in enumerate(st.frames):
        data = bytearray(pack(f, raws[f.name]))
        data[1] = (data[1] & 0xF0) | (counters[k] & 0x0F)
        data[0] = crcs[k]
        out.append(Frame(f.frame_id, bytes(data), timestamp_s=rx_time_s))
    return out


def generated_class(st: StructDef):
    """The ``lcm-gen`` Python class of ``st`` (``bus.hil_lcm``)."""
    import importlib

    mod = importlib.import_module(f"bus.{PACKAGE}.{st.name}")
    return getattr(mod, st.name)


def encode_struct(st: StructDef, values: dict) -> bytes:
    """LCM wire bytes of ``values`` through the generated class."""
    obj = generated_class(st)()
    for k, v in values.items():
        setattr(obj, k, v)
    return obj.encode()


def decode_struct(st: StructDef, data: bytes) -> dict:
    """Field values of LCM wire bytes through the generated class (ValueError when the bytes
    are not this struct: wrong fingerprint or too short)."""
    obj = generated_class(st).decode(data)
    names = [fd.name for fd in st.fields] + ["n_frames", "e2e_counter", "e2e_crc"]
    return {k: getattr(obj, k) for k in names}
