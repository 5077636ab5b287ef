"""SecOC authentication of SYNC and the heartbeats (bus.secoc, issue 13).

SYNC: a forged tick far ahead made a lockstep flight take it and then refuse every genuine
SYNC as a duplicate (``bus.protocol.FlightLockstep``); authenticated, it is refused and the
genuine ticks go on.

A third node that sends a node's heartbeat frame with a valid CRC and the alive counter the
genuine sender is about to use made the genuine beat "repeated" and dropped it: the plant went
safe for a flight that was beating (`hil bench --parts hostile`, catalog-forged). With the
heartbeats authenticated their counter does not gate, forged beats are refused and counted,
replayed ones are refused by their freshness. Oracle: the HMAC of ``bus.secoc`` built here
from the genuine sender's message, and the plain receiver's verdict on the same frames.
"""

from __future__ import annotations

from bus.catalog import CATALOG, Node, NodeState
from bus.codec import Frame, Heartbeat, HeartbeatMac, Sync, SyncMac, decode, encode
from bus.e2e import Protector
from bus.protocol import FlightLockstep, TickRequest
from bus.receiver import Receiver
from bus.secoc import (
    AUTHENTICATED_SETS,
    FAULT_FRESH_WINDOW_S,
    Authenticator,
    compute_mac,
    fault_freshness,
)

KEY = bytes(range(32))
OTHER = bytes(range(1, 33))
T0 = 1_800_000_000.0  # a CLOCK_REALTIME instant, s
BEAT = Heartbeat(Node.FLIGHT, NodeState.RUN, 120, 0, 0)
FORGED = Heartbeat(Node.FLIGHT, NodeState.SAFE, 9, 9, 9)


def frames(msgs, protector: Protector, t: float = T0) -> list[Frame]:
    out = []
    for msg in msgs:
        for fr in encode(msg):
            data = protector.protect(CATALOG.by_id[fr.arbitration_id].data_id, fr.data)
            out.append(Frame(fr.arbitration_id, data, timestamp_s=t))
    return out


def receive(rx: Receiver, auth: Authenticator | None, frs: list[Frame], now: float) -> list:
    out = []
    for fr in frs:
        v = rx.classify(fr, now)
        if v.message is not None:
            out += [(m, now) for m in (v.message, *v.messages)]
    return [m for m, _ in (auth.accept(out, now) if auth is not None else out)]


def signed(beat: Heartbeat, t_s: float, key: bytes = KEY) -> list:
    return [beat, Authenticator(key).sign(beat, t_s)]


def test_the_authenticator_names_the_node_and_is_the_hmac_of_the_beat():
    mac = Authenticator(KEY).sign(BEAT, T0)
    assert isinstance(mac, HeartbeatMac) and mac.key_lo == int(Node.FLIGHT)
    assert mac.mac == compute_mac(KEY, BEAT, fault_freshness(T0))
    (fr,) = encode(mac)
    assert CATALOG.by_id[fr.arbitration_id].name == "HEARTBEAT_FLIGHT_MAC"
    assert decode([fr]) == mac
    assert {"HEARTBEAT", "HEARTBEAT_MAC"} <= AUTHENTICATED_SETS


def test_a_forged_beat_with_the_next_counter_no_longer_drops_the_genuine_one():
    genuine, forger = Protector(), Protector()
    forger.counters = dict(genuine.counters)  # the attacker listened
    f = frames([FORGED], forger)
    g = frames(signed(BEAT, T0), genuine)
    plain = Receiver()
    assert receive(plain, None, [f[0], g[0]], T0) == [FORGED]  # the genuine beat is denied
    assert plain.counts()["repeated_counter"] == 1
    rx, auth = Receiver(), Authenticator(KEY)
    rx.authenticate(AUTHENTICATED_SETS)
    assert receive(rx, auth, [*f, *g], T0) == [BEAT]
    auth.expire(T0 + 5.0)
    assert rx.counts()["repeated_counter"] == 1  # counted all the same
    assert auth.counts["auth_ok"] == 1
    assert auth.counts["auth_fail"] + auth.counts["auth_missing"] == 1


def test_beats_signed_with_another_key_are_refused():
    rx, auth, p = Receiver(), Authenticator(KEY), Protector()
    rx.authenticate(AUTHENTICATED_SETS)
    assert receive(rx, auth, frames(signed(FORGED, T0, OTHER), p), T0) == []
    auth.expire(T0 + 5.0)
    assert auth.counts["auth_fail"] == 1 and auth.counts["auth_ok"] == 0


def test_replayed_beats_are_refused_by_their_freshness():
    auth = Authenticator(KEY)
    old = signed(BEAT, T0)
    assert [m for m, _ in auth.accept([(m, T0) for m in old], T0)] == [BEAT]
    later = Heartbeat(Node.FLIGHT, NodeState.RUN, 121, 0, 0)
    assert [m for m, _ in auth.accept([(m, T0) for m in signed(later, T0 + 0.5)],
                                      T0 + 0.5)] == [later]
    # the first beat again, within the window: older than the last one taken
    assert auth.accept([(m, T0 + 0.6) for m in old], T0 + 0.6) == []
    # the last one again, later than the window: the clock refuses it
    late = T0 + FAULT_FRESH_WINDOW_S + 3.0
    assert auth.accept([(m, late) for m in signed(later, T0 + 0.5)], late) == []
    assert auth.counts["auth_replay"] == 2


def test_a_lockstep_node_may_beat_twice_within_one_clock_unit_but_not_repeat_itself():
    auth = Authenticator(KEY)
    b2 = Heartbeat(Node.PLANT, NodeState.RUN, 7, 0, 1)
    b3 = Heartbeat(Node.PLANT, NodeState.RUN, 8, 0, 1)
    got = []
    for b in (b2, b3, b3):
        got += [m for m, _ in auth.accept([(m, T0) for m in signed(b, T0)], T0)]
    assert got == [b2, b3] and auth.counts["auth_replay"] == 1
    # the beats of the two nodes are judged apart
    assert [m for m, _ in auth.accept([(m, T0) for m in signed(BEAT, T0)], T0)] == [BEAT]


def test_a_forged_sync_far_ahead_stops_a_plain_lockstep_flight_but_not_an_authenticating_one():
    forged = Sync(50_000, 10_000_000)
    genuine = [Sync(n, 200 * n) for n in range(1, 4)]
    plain = FlightLockstep()
    plain.on_message(Sync(0, 0), T0)
    plain.on_message(forged, T0)
    assert not any(isinstance(e, TickRequest)
                   for g in genuine for e in plain.on_message(g, T0))  # all "duplicates"
    auth, fl = Authenticator(KEY), FlightLockstep()
    ticks = []
    for msg in [Sync(0, 0), forged, *genuine]:
        items = [(msg, T0)]
        if msg is not forged:
            items.append((Authenticator(KEY).sign(msg, T0), T0))
        else:
            items.append((SyncMac(msg.tick & 0xFF, msg.tick & 0xFFFF, 0x123456), T0))
        for m, _ in auth.accept(items, T0):
            ticks += [e.tick for e in fl.on_message(m, T0) if isinstance(e, TickRequest)]
    auth.expire(T0 + 5.0)
    assert ticks == [0, 1, 2, 3]
    assert auth.counts["auth_fail"] == 1 and auth.counts["auth_ok"] == 4


def test_a_replayed_sync_is_refused_by_its_tick():
    auth = Authenticator(KEY)
    s3 = Sync(3, 600)
    mac = Authenticator(KEY).sign(s3, T0)
    assert isinstance(mac, SyncMac) and mac.key_lo == 3 and mac.fresh_lo == 3
    assert mac.mac == compute_mac(KEY, s3, 3)
    assert [m for m, _ in auth.accept([(s3, T0), (mac, T0)], T0)] == [s3]
    assert auth.accept([(s3, T0 + 1), (mac, T0 + 1)], T0 + 1) == []
    assert auth.counts["auth_replay"] == 1
