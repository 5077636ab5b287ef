"""LCM types from the catalog: regenerated and diffed, round trips through lcm-gen's classes,
and the same E2E rules as on CAN (docs/lcm.md)."""

from __future__ import annotations

import copy

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bus.catalog import ALLOWED_ON_QUANTA, CATALOG, GYRO_RATE_LSB_RAD_S, AckReason, AckStatus
from bus.codec import (
    FaultAck,
    FdirStatus,
    FlightTiming,
    Gyro,
    Heartbeat,
    Sync,
    ThrCmd,
    decode,
)
from bus.e2e import Protector
from bus.hil_lcm import gyro_t, heartbeat_t, sync_t, thr_cmd_t
from bus.lcm_schema import (
    LCM_DIR,
    PY_DIR,
    by_set,
    decode_struct,
    encode_struct,
    to_fields,
    to_frames,
)
from bus.lcm_transport import LcmPort
from bus.receiver import Receiver
from bus.transport import Port
from hil.binding import fault_cmd_inject
from hil.cli import main as hil_main
from hil.lcm_cmd import differences

STRUCTS = by_set()


def protected(msg, protector=None):
    """The message's CAN frames with E2E, as ``Port.protect`` makes them."""
    p = Port.__new__(Port)
    p.receiver = Receiver()
    p.protector = protector or Protector()
    return Port.protect(p, msg)


def test_committed_types_match_a_fresh_generation():
    """bus/lcm/*.lcm and bus/hil_lcm/ are exactly what the catalog and lcm-gen give now."""
    assert differences(LCM_DIR, PY_DIR) == []
    assert hil_main(["lcm-types", "--check"]) == 0


def test_every_logical_message_has_a_struct_and_a_channel():
    sets = {f.set_name or f.name for f in CATALOG.frames}
    assert set(STRUCTS) == sets
    assert STRUCTS["THR_CMD"].channel == "HIL_THR_CMD"
    assert STRUCTS["HEARTBEAT_FLIGHT"].name == "heartbeat_t"
    # the CAN key fragments are derived, not carried
    names = {fd.name for fd in STRUCTS["THR_CMD"].fields}
    assert names == {"tick", "manifold_enable", "gyro_seq", "n_thrusters", "on_ms"}
    assert {fd.name for fd in STRUCTS["GYRO"].fields} == {
        "rate_x_rad_s", "rate_y_rad_s", "rate_z_rad_s", "sample_seq", "status"}


def test_generated_fields_are_engineering_units():
    """Our codec encodes; lcm-gen's classes decode; the fields read in SI / ms."""
    q = tuple(ALLOWED_ON_QUANTA[i % len(ALLOWED_ON_QUANTA)] for i in range(30))
    cmd = ThrCmd(1234, q, 0b0101, 777)
    st_ = STRUCTS["THR_CMD"]
    obj = thr_cmd_t.decode(encode_struct(st_, to_fields(st_, protected(cmd))))
    assert obj.tick == 1234 and obj.gyro_seq == 777 and obj.manifold_enable == 5
    assert obj.n_thrusters == 30
    assert list(obj.on_ms) == [10 * x for x in q] + [0, 0]
    assert obj.n_frames == 5 and list(obj.e2e_counter) == [0] * 5

    g = Gyro(65535, (0.0123456, -0.19, 3e-7), 1)
    st_ = STRUCTS["GYRO"]
    obj = gyro_t.decode(encode_struct(st_, to_fields(st_, protected(g))))
    assert obj.sample_seq == 65535 and obj.status == 1
    assert obj.rate_x_rad_s == pytest.approx(0.0123456, abs=GYRO_RATE_LSB_RAD_S / 2)
    assert obj.rate_y_rad_s == pytest.approx(-0.19, abs=1e-12)
    assert obj.rate_z_rad_s == pytest.approx(3e-7, abs=1e-15)

    obj = sync_t.decode(encode_struct(STRUCTS["SYNC"],
                                      to_fields(STRUCTS["SYNC"], protected(Sync(9, 1800)))))
    assert (obj.tick, obj.sim_time_ms) == (9, 1800)


def _round_trip(msg):
    frames = protected(msg)
    st_ = STRUCTS[type(msg).SET if type(msg).SET != "HEARTBEAT" else f"HEARTBEAT_{msg.node.name}"]
    wire = encode_struct(st_, to_fields(st_, frames))
    back = to_frames(st_, decode_struct(st_, wire))
    assert [(f.arbitration_id, f.data) for f in back] == [(f.arbitration_id, f.data)
                                                          for f in frames]
    assert decode(back) == decode(frames)  # what CAN delivers, quantised alike
    return st_, wire


MESSAGES = [
    Sync(0, 0),
    Sync(2**24 - 1, 2**28 - 1),
    ThrCmd(77, (0, 3, 17, 20), 0b1111, 65535),
    Gyro(5, (-0.2, 0.2, 0.0), 3),
    FdirStatus(120, 1, 4, None, 0b10, False, 3),
    fault_cmd_inject(200, "degraded", 7, 0.4321, 12.5, 30.25),
    FaultAck(200, AckStatus.REJECTED, AckReason.BAD_THRUSTER, 3),
    FlightTiming(4000, 0.000731, 12),
    Heartbeat(__import__("bus.catalog", fromlist=["Node"]).Node.FLIGHT, 1, 65535, 3, 4095),
]


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip_every_message(msg):
    """codec -> frames -> generated struct -> bytes -> generated struct -> frames -> codec."""
    _round_trip(msg)


@settings(max_examples=200, deadline=None)
@given(
    tick=st.integers(0, 2**24 - 1),
    q=st.lists(st.sampled_from(ALLOWED_ON_QUANTA), min_size=1, max_size=32),
    mask=st.integers(0, 15),
    seq=st.integers(0, 65535),
    rates=st.tuples(*[st.integers(-2_000_000, 2_000_000)] * 3),
)
def test_round_trip_property(tick, q, mask, seq, rates):
    _round_trip(ThrCmd(tick, tuple(q), mask, seq))
    _round_trip(Gyro(seq, tuple(r * GYRO_RATE_LSB_RAD_S for r in rates), 1))


def test_changed_typed_field_fails_the_crc_and_counters_hold():
    """The E2E rules of CAN hold on LCM: a field changed in transit fails its frame's CRC
    (the set is then incomplete); a repeated message is a repeated counter."""
    lc = __import__("lcm").LCM("memq://")
    tx, rx = LcmPort("memq://", lc=lc), LcmPort("memq://", lc=lc)
    st_ = STRUCTS["GYRO"]
    frames = tx.protect(Gyro(10, (0.01, 0.02, 0.03), 1))
    vals = to_fields(st_, frames)
    bad = encode_struct(st_, {**vals, "rate_y_rad_s": vals["rate_y_rad_s"] + 1e-7})
    lc.publish(st_.channel, bad)
    assert rx.poll(0.2) == []
    c = rx.receiver.counts()
    assert (c["bad_crc"], c["ok"]) == (1, 1)  # GYRO_1 (rate_x, rate_y) fails, GYRO_2 is ok
    good = encode_struct(st_, to_fields(st_, tx.protect(Gyro(11, (0.01, 0.02, 0.03), 1))))
    lc.publish(st_.channel, good)
    lc.publish(st_.channel, good)
    got = rx.poll(0.2)
    assert [m for m, _ in got] == [Gyro(11, (0.01, 0.02, 0.03), 1)]
    c = rx.receiver.counts()
    assert (c["ok"], c["repeated_counter"]) == (3, 2)  # the copy: both frames repeated
    # bytes that are not a gyro_t: counted, never raised
    lc.publish(st_.channel, b"\x00" * 5)
    assert rx.poll(0.2) == []
    assert rx.counts()["lcm_malformed"] == 1 and rx.receiver.counts()["wrong_length"] == 1
    tx.close()
    rx.close()


def test_own_messages_are_not_received_and_heartbeats_share_a_struct():
    lc = __import__("lcm").LCM("memq://")
    a, b = LcmPort("memq://", lc=lc), LcmPort("memq://", lc=lc)
    from bus.catalog import Node

    hb = Heartbeat(Node.PLANT, 1, 2, 3, 4)
    a.send(hb)
    channel, wire = a._sent[-1]
    assert channel == "HIL_HEARTBEAT_PLANT" and heartbeat_t.decode(wire).rx_ok == 2
    assert a.poll(0.1) == []
    assert a.echoes_dropped == 1
    assert [m for m, _ in b.poll(0.1)] == [hb]
    a.close()
    b.close()


def test_thr_cmd_is_authenticated_over_lcm_as_over_can():
    """SecOC over LCM: the authenticator travels as a message of its own channel; a THR_CMD
    signed with the run's key is used, one signed with another key or sent without its
    authenticator is counted (``auth_fail``, ``auth_missing``) and never handed on."""
    from bus.secoc import Authenticator

    key = bytes(range(32))
    lc = __import__("lcm").LCM("memq://")
    tx, rx, forger, bare = (LcmPort("memq://", lc=lc) for _ in range(4))
    tx.auth, rx.auth, forger.auth = (Authenticator(key), Authenticator(key),
                                     Authenticator(bytes(32)))
    genuine = ThrCmd(5, (0, 5, 0, 0, 3, 0), 0x3, 5)
    tx.send(genuine)
    assert [m for m, _ in rx.poll(0.2)] == [genuine]
    # The forgers continue the genuine sender's E2E counters (valid CRC, next counter), so
    # only the authenticator can stop them (the forged class of `hil flood`).
    forger.protector = copy.deepcopy(tx.protector)
    forger.send(ThrCmd(6, (20, 20, 20, 20, 20, 20), 0x3, 6))
    assert rx.poll(0.2) == []
    bare.protector = copy.deepcopy(forger.protector)
    bare.send(ThrCmd(7, (20, 20, 20, 20, 20, 20), 0x3, 7))
    assert rx.poll(0.2) == []
    rx.auth.expire(rx.now_s() + 5.0)
    c = rx.auth.counts
    assert (c["auth_ok"], c["auth_fail"], c["auth_missing"]) == (1, 1, 1)
    for p in (tx, rx, forger, bare):
        p.close()
