"""A forger with valid E2E cannot deny the genuine secured messages (issue 13).

Anyone on the bus can send THR_CMD frames with a correct CRC and the alive counter that makes
the genuine frame after it look repeated, or a frame of the same set with other contents, or
an authenticator that does not verify. For the messages a node authenticates, the receiver
counts those counter faults without dropping the frame, keeps variants of a set, and the
authenticator keeps a message waiting until its own authenticator arrives. Oracle: the
genuine sender's message and its HMAC (``bus.secoc``), built independently here.
"""

from __future__ import annotations

from bus.catalog import CATALOG
from bus.codec import Frame, ThrCmd, ThrCmdMac, encode
from bus.e2e import Protector
from bus.receiver import Receiver
from bus.secoc import AUTHENTICATED_SETS, Authenticator, compute_mac, message_key

KEY = bytes(range(32))
NOW = 100.0
GENUINE = ThrCmd(7, (20, 0, 0, 10, 0, 0), 0b11, 7)
FORGED = ThrCmd(7, (20,) * 6, 0b11, 6)  # same tick (key), other contents


def frames(msg, protector: Protector, t: float = NOW) -> list[Frame]:
    out = []
    for fr in encode(msg):
        data = protector.protect(CATALOG.by_id[fr.arbitration_id].data_id, fr.data)
        out.append(Frame(fr.arbitration_id, data, timestamp_s=t))
    return out


def mac_of(msg: ThrCmd, key: bytes = KEY) -> ThrCmdMac:
    return ThrCmdMac(message_key(msg), msg.tick & 0xFFFF, compute_mac(key, msg, msg.tick))


def receive(rx: Receiver, auth: Authenticator | None, frs: list[Frame]) -> list:
    out = []
    for fr in frs:
        v = rx.classify(fr, NOW)
        if v.message is not None:
            out += [(m, NOW) for m in (v.message, *v.messages)]
    return auth.accept(out, NOW) if auth is not None else out


def test_a_forged_frame_with_the_next_counter_does_not_drop_the_genuine_one() -> None:
    genuine, forger = Protector(), Protector()
    # The forger learnt the counters: its copy of the header goes first with the counter the
    # genuine header is about to use, so the genuine header repeats it.
    forger.counters = dict(genuine.counters)  # the attacker's knowledge
    f = frames(FORGED, forger)
    g = frames(GENUINE, genuine)
    plain = Receiver()
    got = [m for m, _ in receive(plain, None, [f[0], *g])]
    assert GENUINE not in got and plain.counts()["repeated_counter"] == 1  # denied
    rx, auth = Receiver(), Authenticator(KEY)
    rx.authenticate(AUTHENTICATED_SETS)
    mac = frames(mac_of(GENUINE), genuine)
    got = receive(rx, auth, [f[0], *g, *mac])
    assert [m for m, _ in got] == [GENUINE]
    assert rx.counts()["repeated_counter"] == 1  # counted all the same
    assert auth.counts["auth_ok"] == 1


def test_a_forged_set_interleaved_with_the_genuine_one_keeps_both_variants() -> None:
    # Each forged frame right after its genuine one, with the counter that follows it (one
    # protector for both: the attacker listens), so every frame passes E2E.
    shared = Protector()
    mixed = []
    for gf, ff in zip(encode(GENUINE), encode(FORGED), strict=True):
        for fr in (gf, ff):
            data = shared.protect(CATALOG.by_id[fr.arbitration_id].data_id, fr.data)
            mixed.append(Frame(fr.arbitration_id, data, timestamp_s=NOW))
    rx, auth = Receiver(), Authenticator(KEY)
    rx.authenticate(AUTHENTICATED_SETS)
    got = receive(rx, auth, mixed + frames(mac_of(GENUINE), shared))
    assert [m for m, _ in got] == [GENUINE]
    # Without authentication a frame twice drops what was pending: the genuine command is
    # not delivered (a mix of the two is).
    plain = Receiver()
    assert GENUINE not in [m for m, _ in receive(plain, None, mixed)]


def test_a_forged_authenticator_does_not_fail_the_message_before_its_own_arrives() -> None:
    auth = Authenticator(KEY)
    wrong = ThrCmdMac(message_key(GENUINE), GENUINE.tick, 0x123456)
    assert auth.accept([(GENUINE, NOW), (wrong, NOW)], NOW) == []
    assert auth.accept([(mac_of(GENUINE), NOW + 0.01)], NOW + 0.01) == [(GENUINE, NOW)]
    assert auth.counts["auth_ok"] == 1 and auth.counts["auth_fail"] == 0
    # Authenticators that came first wait too: the wrong one does not stop the right one.
    auth = Authenticator(KEY)
    later = ThrCmd(8, GENUINE.on_quanta, 0b11, 8)
    assert auth.accept([(ThrCmdMac(message_key(later), 8, 0xABCDEF), NOW),
                        (mac_of(later), NOW), (later, NOW)], NOW) == [(later, NOW)]
    # A message no authenticator verifies is failed when its wait is over, never used.
    auth = Authenticator(KEY)
    assert auth.accept([(FORGED, NOW), (mac_of(GENUINE, bytes(32)), NOW)], NOW) == []
    assert auth.accept([], NOW + 5.0) == []
    assert auth.counts["auth_fail"] == 1 and auth.counts["auth_ok"] == 0


def test_variants_and_keys_are_bounded() -> None:
    from bus.receiver import VARIANT_KEYS, VARIANTS

    rx = Receiver()
    rx.authenticate(AUTHENTICATED_SETS)
    header = frames(GENUINE, Protector())[0]
    for k in range(20):  # headers of one key, each different: variants, at most VARIANTS
        p = Protector()
        msg = ThrCmd(7, GENUINE.on_quanta, 0b11, k)
        rx.classify(frames(msg, p)[0], NOW)
    a = rx.assemblers["THR_CMD"]
    assert sum(len(v) for v in a.variants.values()) <= VARIANTS
    for t in range(20):  # many keys: at most VARIANT_KEYS held
        rx.classify(frames(ThrCmd(t, GENUINE.on_quanta, 0b11, t), Protector())[0], NOW)
    assert len(a.variants) <= VARIANT_KEYS
    assert rx.counts()["incomplete_set"] > 0 and header is not None
