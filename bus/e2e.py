"""End-to-end protection of every frame (docs/design.md section 4).

Layout of AUTOSAR E2E profile 1 (CRC in byte 0, 4-bit alive counter in the low nibble of
byte 1, data ID mode "both bytes"), with the counter range of profile 2 (0..15, wrapping):

* ``crc = CRC-8/SAE-J1850(data_id_lo, data_id_hi, byte1, ..., byte7)`` in one pass, with
  polynomial 0x1D, init 0xFF, xorout 0xFF, no reflection (check value of "123456789": 0x4B).
  The data ID never travels on the bus, so a frame that lands on the wrong identifier (or a
  sender mixing up two messages) fails the CRC.
* The counter lets the receiver detect repeated (delta 0) and lost (delta > 1) frames.

This is the profile-1 structure, not a bit-exact AUTOSAR implementation (AUTOSAR chains three
CRC calls with its own start-value convention). Its strength is that of profile 1: a CRC-8
detects every 1-, 2- and 3-bit error in a 9-byte message, and a 4-bit counter detects up to
14 consecutive lost frames (longer gaps alias; the staleness check covers them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

CRC8_POLY = 0x1D
CRC8_INIT = 0xFF
CRC8_XOROUT = 0xFF
COUNTER_MODULO = 16


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ CRC8_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _make_table()


def crc8_sae_j1850(
    data: bytes | bytearray, init: int = CRC8_INIT, xorout: int = CRC8_XOROUT
) -> int:
    """CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF, not reflected)."""
    crc = init
    for b in data:
        crc = _TABLE[crc ^ b]
    return crc ^ xorout


def frame_crc(data_id: int, data: bytes | bytearray) -> int:
    """CRC of an 8-byte frame: over data ID (low byte, high byte) and bytes 1..7."""
    return crc8_sae_j1850(bytes((data_id & 0xFF, (data_id >> 8) & 0xFF)) + bytes(data[1:]))


def counter_of(data: bytes | bytearray) -> int:
    return data[1] & 0x0F


def protect(data_id: int, data: bytes | bytearray, counter: int) -> bytes:
    """Return ``data`` with the alive counter and the CRC written in."""
    buf = bytearray(data)
    buf[1] = (buf[1] & 0xF0) | (counter & 0x0F)
    buf[0] = frame_crc(data_id, buf)
    return bytes(buf)


def crc_ok(data_id: int, data: bytes | bytearray) -> bool:
    return len(data) >= 2 and data[0] == frame_crc(data_id, data)


@dataclass
class Protector:
    """Sender side: one alive counter per data ID, starting at 0."""

    counters: dict[int, int] = field(default_factory=dict)

    def protect(self, data_id: int, data: bytes | bytearray) -> bytes:
        c = self.counters.get(data_id, 0)
        self.counters[data_id] = (c + 1) % COUNTER_MODULO
        return protect(data_id, data, c)


def counter_delta(previous: int, current: int) -> int:
    """Steps from ``previous`` to ``current`` modulo 16 (0 = repeated, 1 = next)."""
    return (current - previous) % COUNTER_MODULO
