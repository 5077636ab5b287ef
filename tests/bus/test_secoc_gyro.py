"""SecOC authentication of GYRO (bus.secoc): a forged sample with a valid E2E CRC and a wrong or
missing MAC is refused and counted, a replayed authentic sample is refused by its freshness
(clock and sample sequence), the genuine samples pass through the 16-bit sequence's wrap, a
flight that joins late and a restarted plant. Over python-can's virtual bus, and sans-IO on
``Authenticator`` with the clock as an argument."""

import time

import pytest

from bus.catalog import CATALOG
from bus.codec import Gyro, GyroMac, encode
from bus.faults import message_ids
from bus.secoc import (
    AUTHENTICATED_SETS,
    FAULT_FRESH_WINDOW_S,
    RESTART_S,
    Authenticator,
    compute_mac,
    fault_freshness,
)
from bus.transport import BusConfig, Port, open_bus

KEY = bytes(range(32))
OTHER = bytes(range(1, 33))
T0 = 1_800_000_000.0  # a CLOCK_REALTIME instant, s


def sample(seq: int, w: float = 1e-3) -> Gyro:
    return Gyro(seq & 0xFFFF, (w, -w, 2 * w), 1)


def signed(seq: int, t_s: float, key: bytes = KEY, w: float = 1e-3) -> list:
    """GYRO and its authenticator as the plant's port sends them at ``t_s``."""
    g = sample(seq, w)
    return [(g, t_s), (Authenticator(key).sign(g, t_s), t_s)]


def used(auth: Authenticator, items: list, now_s: float) -> list:
    return [m for m, _ in auth.accept(items, now_s)]


def test_gyro_and_its_authenticator_are_authenticated_sets():
    assert {"GYRO", "GYRO_MAC"} <= AUTHENTICATED_SETS
    mac = Authenticator(KEY).sign(sample(0x1234), T0)
    assert isinstance(mac, GyroMac) and mac.key_lo == 0x34
    assert mac.fresh_lo == fault_freshness(T0) & 0xFFFF
    assert mac.mac == compute_mac(KEY, sample(0x1234), fault_freshness(T0))
    # a bus fault limited to GYRO takes its authenticator along (the pair travels together)
    assert message_ids("GYRO") == {CATALOG.frame(n).frame_id for n in ("GYRO_1", "GYRO_2",
                                                                        "GYRO_MAC")}


def test_genuine_samples_pass_across_the_sequence_wrap_and_for_a_late_joiner():
    rx = Authenticator(KEY)
    seqs = [40_000 + 7, 65_534, 65_535, 0, 1, 2]  # the flight joins at an arbitrary sequence
    got = []
    for i, s in enumerate(seqs):
        t = T0 + 0.02 * i
        got += used(rx, signed(s, t), t)
    assert got == [sample(s) for s in seqs]
    assert rx.counts["auth_ok"] == len(seqs) and rx.counts["auth_fail"] == 0


def test_many_samples_in_one_clock_unit_pass_as_a_lockstep_plant_sends_them():
    rx = Authenticator(KEY)
    got = []
    for s in range(10):  # all within one 10 ms freshness unit
        got += used(rx, signed(s, T0 + 0.0001 * s), T0)
    assert len(got) == 10


@pytest.mark.parametrize("key", [OTHER, None], ids=["wrong-key", "no-mac"])
def test_forged_samples_are_refused_and_the_genuine_one_of_the_same_key_is_used(key):
    rx = Authenticator(KEY)
    forged = sample(5, w=0.05)
    items = [(forged, T0)]
    if key is not None:
        items.append((Authenticator(key).sign(forged, T0), T0))
    assert used(rx, items, T0) == []
    # the genuine sample of the same sequence number comes after the forgery
    assert used(rx, signed(5, T0 + 0.001), T0 + 0.001) == [sample(5)]
    used(rx, [], T0 + 1.5)  # nothing verifies the forgery: it times out
    c = rx.counts
    assert c["auth_ok"] == 1
    # counted once: failed (an authenticator of its key was tried on it) or missing
    assert c["auth_fail"] + c["auth_missing"] == 1


def test_a_mac_with_a_wrong_tag_is_refused():
    rx = Authenticator(KEY)
    g = sample(9)
    good = Authenticator(KEY).sign(g, T0)
    bad = GyroMac(good.key_lo, good.fresh_lo, good.mac ^ 1)
    assert used(rx, [(g, T0), (bad, T0)], T0) == []
    used(rx, [], T0 + 1.5)
    assert rx.counts["auth_fail"] == 1 and rx.counts["auth_ok"] == 0


def test_replays_are_refused_by_the_sequence_and_by_the_clock():
    rx = Authenticator(KEY)
    old = signed(100, T0)
    assert used(rx, old, T0) == [sample(100)]
    assert used(rx, signed(101, T0 + 0.02), T0 + 0.02) == [sample(101)]
    # within the window: the same authentic frames again, the sequence is not ahead
    assert used(rx, [(m, T0 + 0.1) for m, _ in old], T0 + 0.1) == []
    assert rx.counts["auth_replay"] == 1
    # later than the window: the clock refuses it even with a sequence ahead of the last
    later = T0 + FAULT_FRESH_WINDOW_S + 5.0
    stale = signed(200, T0 + 0.04)
    assert used(rx, [(m, later) for m, _ in stale], later) == []
    assert rx.counts["auth_replay"] == 2


def test_a_restarted_plant_counting_from_zero_is_taken_after_the_restart_time():
    rx = Authenticator(KEY)
    assert used(rx, signed(30_000, T0), T0) == [sample(30_000)]
    soon = T0 + 0.5 * RESTART_S
    assert used(rx, signed(0, soon), soon) == []  # sequence behind, clock too close: refused
    later = T0 + 1.5 * RESTART_S
    assert used(rx, signed(1, later), later) == [sample(1)]
    assert used(rx, signed(2, later + 0.02), later + 0.02) == [sample(2)]


def test_over_the_virtual_bus_the_flight_uses_only_authentic_samples():
    a = Port(open_bus(BusConfig(interface="virtual", channel="t_gyro_auth")))
    f = Port(open_bus(BusConfig(interface="virtual", channel="t_gyro_auth")))
    a.auth = Authenticator(KEY)
    f.auth = Authenticator(KEY)
    try:
        genuine = [sample(s) for s in range(3)]
        for g in genuine:
            a.send(g)
        a.auth = Authenticator(OTHER)  # a third node with a CRC-valid frame, the wrong key
        a.send(sample(3, w=0.05))
        got, t_end = [], time.monotonic() + 0.3
        while time.monotonic() < t_end:
            got += [m for m, _ in f.poll(0.02)]
        time.sleep(1.05)
        f.poll(0.0)
    finally:
        a.close()
        f.close()
    assert got == genuine
    c = f.counts()
    assert c["auth_ok"] == 3 and c["auth_fail"] == 1 and c["bad_crc"] == 0
    assert len(encode(genuine[0])) == 2
