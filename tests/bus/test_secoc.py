"""SecOC authentication of THR_CMD and FAULT_CMD (bus.secoc; GYRO: test_secoc_gyro.py) over
python-can's virtual bus: forged frames with a valid E2E CRC and a wrong or missing MAC are
refused and counted, a replayed authentic message is refused by its freshness, an authentic
one is used."""

import hashlib
import hmac
import time

import pytest

from bus.catalog import FaultAction, FaultKind
from bus.codec import FaultCmd, FaultCmdMac, FlightTiming, Sync, ThrCmd, encode
from bus.secoc import WAIT_LIMIT_S, Authenticator, compute_mac, message_key
from bus.transport import BusConfig, Port, open_bus

KEY = bytes(range(32))
OTHER = bytes(range(1, 33))


def ports(name, tx_key, rx_key=KEY):
    a = Port(open_bus(BusConfig(interface="virtual", channel=name)))
    b = Port(open_bus(BusConfig(interface="virtual", channel=name)))
    a.auth = None if tx_key is None else Authenticator(tx_key)
    b.auth = Authenticator(rx_key)
    return a, b


def take(port, wait_s=0.3):
    got, t_end = [], time.monotonic() + wait_s
    while time.monotonic() < t_end:
        got += [m for m, _ in port.poll(0.02)]
    return got


def test_mac_is_truncated_hmac_sha256_over_id_payload_and_freshness():
    cmd = ThrCmd(7, (3, 0, 20), 1, 4)
    frames = encode(cmd)
    data = frames[0].arbitration_id.to_bytes(2, "big") + b"".join(f.data for f in frames) + \
        (7).to_bytes(8, "big")
    want = int.from_bytes(hmac.new(KEY, data, hashlib.sha256).digest()[:3], "big")
    assert compute_mac(KEY, cmd, 7) == want
    assert compute_mac(KEY, cmd, 8) != want and compute_mac(OTHER, cmd, 7) != want


def test_authentic_commands_pass_and_unsecured_messages_are_untouched():
    a, b = ports("t_auth_ok", KEY)
    try:
        cmds = [ThrCmd(n, (3, 0, 20), 1, n) for n in range(5)]
        fault = FaultCmd(9, FaultAction.INJECT, FaultKind.STUCK_ON, 1, 1.0, 0.0, None)
        for c in cmds:
            a.send(c)
        a.send(fault, Sync(4, 800), FlightTiming(4, 0.001, 0))
        got = take(b)
    finally:
        a.close()
        b.close()
    assert got == [*cmds, fault, Sync(4, 800), FlightTiming(4, 0.001, 0)]
    assert b.counts()["auth_ok"] == 7 and b.counts()["auth_fail"] == 0


@pytest.mark.parametrize("tx_key", [OTHER, None], ids=["wrong-key", "no-mac"])
def test_forged_commands_with_valid_crc_are_refused_and_counted(tx_key):
    a, b = ports(f"t_forge_{tx_key is None}", tx_key)
    try:
        for n in range(4):
            a.send(ThrCmd(n, (20, 20, 20), 1, n))
        a.send(FaultCmd(3, FaultAction.INJECT, FaultKind.STUCK_ON, 1, 1.0, 0.0, None))
        got = take(b)
        time.sleep(1.05)
        b.poll(0.0)  # nothing followed: the missing authenticators time out (WAIT_LIMIT_S)
    finally:
        a.close()
        b.close()
    c = b.counts()
    assert got == []
    assert c["bad_crc"] == 0 and c["ok"] > 0  # E2E passed: only authentication stops them
    if tx_key is None:
        assert c["auth_missing"] == 5
    else:
        assert c["auth_fail"] == 5


def test_replayed_authentic_frames_are_refused_by_freshness():
    a, b = ports("t_replay", KEY)
    try:
        a.send(ThrCmd(10, (3, 0, 0), 1, 10))
        a.send(FaultCmd(5, FaultAction.INJECT, FaultKind.STUCK_ON, 0, 1.0, 0.0, None))
        first = take(b)
        assert [type(m).__name__ for m in first] == ["ThrCmd", "FaultCmd"]
        a.send(ThrCmd(11, (3, 0, 0), 1, 11))
        assert [m.tick for m in take(b)] == [11]
        # An attacker replays tick 10's authentic message and authenticator (a THR_CMD's MAC
        # depends only on the message and its tick: these are the bytes that went out), with
        # E2E counters of its own so that the CRC and counter checks pass.
        atk = Port(open_bus(BusConfig(interface="virtual", channel="t_replay")))
        atk.auth = None
        atk.protector.counters = dict(a.protector.counters)  # it watched the counters
        for m in (ThrCmd(10, (3, 0, 0), 1, 10),):
            atk.send(m, Authenticator(KEY).sign(m, atk.now_s()))
        assert take(b) == []
        atk.close()
    finally:
        a.close()
        b.close()
    assert b.counts()["auth_replay"] == 1


def test_fault_cmd_freshness_window_and_replay():
    tx, rx = Authenticator(KEY), Authenticator(KEY)
    f = FaultCmd(5, FaultAction.INJECT, FaultKind.STUCK_ON, 0, 1.0, 0.0, None)
    now = 1_000_000.0
    mac = tx.sign(f, now)
    assert rx.accept([(f, now), (mac, now)], now + 0.01) == [(f, now)]
    # The same frames again: not newer than the last one taken.
    assert rx.accept([(f, now), (mac, now)], now + 0.02) == []
    # Signed 5 s ago (outside the 2 s window), and never seen: refused too.
    old = tx.sign(f, now + 10.0 - 5.0)
    assert rx.accept([(f, now + 10), (old, now + 10)], now + 10.0) == []
    assert rx.counts["auth_replay"] == 2 and rx.counts["auth_ok"] == 1
    assert "key" not in repr(rx).replace("counts", "") or KEY.hex() not in repr(rx)


def test_a_slow_reader_does_not_lose_a_message_whose_authenticator_waits_in_the_queue():
    tx, rx = Authenticator(KEY), Authenticator(KEY)
    cmd = ThrCmd(3, (3, 0, 0), 1, 3)
    mac = tx.sign(cmd, 0.0)
    # Read 0.5 s after they arrived, in two polls (a loaded machine, a bounded poll).
    assert rx.accept([(cmd, 10.0)], 10.5) == []
    assert rx.accept([(mac, 10.001)], 10.6) == [(cmd, 10.0)]
    # A forged one: a frame received 0.2 s later shows its authenticator is not coming.
    forged = ThrCmd(4, (20, 20, 20), 1, 4)
    assert rx.accept([(forged, 11.0)], 11.0) == []
    assert rx.accept([(FlightTiming(5, 0.001, 0), 11.2)], 11.2) == [
        (FlightTiming(5, 0.001, 0), 11.2)]
    assert rx.counts["auth_missing"] == 1 and rx.counts["auth_ok"] == 1


def test_a_fault_freshness_before_the_clocks_zero_fails_and_never_raises():
    """A forged FAULT_CMD authenticator whose 16 freshness bits put the sender's clock before
    the receiver's zero (receiver clock 0.6 s, fresh_lo far above it): counted as failed
    once the message's wait is over, never an exception in the receiving node."""
    auth = Authenticator(bytes(range(32)))
    msg = FaultCmd(request_id=131, action=FaultAction.INJECT, kind=FaultKind.STUCK_ON,
                   thruster=0, fraction=1.0, start_time_s=0.0, clear_time_s=None, message=0)
    forged = FaultCmdMac(message_key(msg), 0x9000, 0x123456)
    assert auth.accept([(msg, 0.6), (forged, 0.6)], 0.6) == []
    assert auth.accept([], 0.6 + WAIT_LIMIT_S + 0.1) == []
    assert auth.counts["auth_fail"] == 1 and auth.counts["auth_missing"] == 0
