"""E2E protection: CRC-8/SAE-J1850 against published check values and a bitwise oracle."""

from hypothesis import given
from hypothesis import strategies as st

from bus import e2e


def crc8_bitwise(data: bytes) -> int:
    """Independent oracle: the textbook bit-at-a-time CRC (poly 0x1D, init/xorout 0xFF)."""
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def test_check_value_123456789():
    assert e2e.crc8_sae_j1850(b"123456789") == 0x4B


def test_autosar_crc8_vectors():
    # AUTOSAR SWS CRC Library, Crc_CalculateCRC8 (SAE J1850) examples.
    vectors = {
        bytes([0x00, 0x00, 0x00, 0x00]): 0x59,
        bytes([0xF2, 0x01, 0x83]): 0x37,
        bytes([0x0F, 0xAA, 0x00, 0x55]): 0x79,
        bytes([0x00, 0xFF, 0x55, 0x11]): 0xB8,
        bytes([0x33, 0x22, 0x55, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF]): 0xCB,
        bytes([0x92, 0x6B, 0x55]): 0x8C,
        bytes([0xFF, 0xFF, 0xFF, 0xFF]): 0x74,
    }
    for data, crc in vectors.items():
        assert e2e.crc8_sae_j1850(data) == crc, data.hex()


@given(st.binary(max_size=64))
def test_table_crc_matches_bitwise(data):
    assert e2e.crc8_sae_j1850(data) == crc8_bitwise(data)


@given(st.integers(0, 0xFFFF), st.binary(min_size=8, max_size=8), st.integers(0, 15))
def test_protect_then_check(data_id, data, counter):
    out = e2e.protect(data_id, data, counter)
    assert e2e.crc_ok(data_id, out)
    assert e2e.counter_of(out) == counter
    assert out[0] == crc8_bitwise(bytes([data_id & 0xFF, data_id >> 8]) + out[1:])
    assert out[1] >> 4 == data[1] >> 4 and out[2:] == data[2:]


def test_data_id_is_covered():
    out = e2e.protect(0x1080, bytes(8), 0)
    assert not e2e.crc_ok(0x1081, out)


def test_protector_counts_per_data_id():
    p = e2e.Protector()
    got = [e2e.counter_of(p.protect(1, bytes(8))) for _ in range(18)]
    assert got == list(range(16)) + [0, 1]
    assert e2e.counter_of(p.protect(2, bytes(8))) == 0
    assert e2e.counter_delta(15, 0) == 1 and e2e.counter_delta(3, 3) == 0
