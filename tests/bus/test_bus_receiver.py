"""Receiver: every corruption is rejected, counted, never raised, never returned as a message."""

import random

from hypothesis import given
from hypothesis import strategies as st

from bus.catalog import CATALOG
from bus.codec import Frame, Sync, ThrCmd, encode, pack, unpack
from bus.e2e import Protector, protect
from bus.receiver import Receiver, ThrCmdAssembler

NOW = 1000.0


def protected(msg, protector=None):
    protector = protector or Protector()
    out = []
    for fr in encode(msg):
        data = protector.protect(CATALOG.by_id[fr.arbitration_id].data_id, fr.data)
        out.append(Frame(fr.arbitration_id, data, timestamp_s=NOW))
    return out


CMD = ThrCmd(7, tuple([3, 0, 20, 17] * 7 + [4, 5]), 0b0011, 70)


def test_valid_set_is_assembled():
    rx = Receiver()
    verdicts = [rx.classify(f, NOW) for f in protected(CMD)]
    assert [v.kind for v in verdicts] == ["ok"] * 5
    assert [v.message for v in verdicts[:-1]] == [None] * 4
    assert verdicts[-1].message == CMD
    assert rx.thr_cmd.take(7) == CMD and rx.thr_cmd.take(7) is None


def test_every_single_bit_flip_is_rejected():
    for fr in protected(CMD) + protected(Sync(3, 600)):
        for bit in range(64):
            rx = Receiver()
            data = bytearray(fr.data)
            data[bit // 8] ^= 1 << (bit % 8)
            v = rx.classify(Frame(fr.arbitration_id, bytes(data), timestamp_s=NOW), NOW)
            assert v.kind == "bad_crc" and v.message is None and not v.usable
            assert rx.counts()["bad_crc"] == 1


@given(st.integers(0, 0x7FF), st.binary(max_size=8))
def test_random_payloads_never_raise_and_never_pass_unchecked(can_id, data):
    rx = Receiver()
    v = rx.classify(Frame(can_id, data, timestamp_s=NOW), NOW)
    assert v.kind in rx.counts()
    if v.usable:  # only possible with a correct CRC for that id's data ID (1 in 256)
        f = CATALOG.by_id[can_id]
        assert protect(f.data_id, data, data[1] & 15) == data
    assert rx.counts()["internal"] == 0


def test_fuzz_many_random_frames_counted():
    rng = random.Random(1)
    rx = Receiver()
    n = 5000
    for _ in range(n):
        can_id = rng.choice(list(CATALOG.by_id) + [0x123, 0x7FF])
        data = bytes(rng.getrandbits(8) for _ in range(rng.choice([0, 3, 8, 8, 8])))
        rx.classify(Frame(can_id, data, timestamp_s=NOW), NOW)
    c = rx.counts()
    assert sum(v for k, v in c.items() if k != "lost_frames") >= n
    assert c["internal"] == 0 and c["bad_crc"] > 0 and c["unknown_id"] > 0


def test_wrong_length_unknown_id_extended_fd():
    rx = Receiver()
    good = protected(Sync(1, 200))[0]
    assert (
        rx.classify(Frame(good.arbitration_id, good.data[:7], timestamp_s=NOW), NOW).detail
        == "SYNC: expected 8 bytes, got 7"
    )
    assert (
        rx.classify(Frame(0x123, good.data, timestamp_s=NOW), NOW).detail
        == "bus: expected a catalog id, got 0x123"
    )
    assert (
        rx.classify(
            Frame(good.arbitration_id, good.data, is_extended_id=True, timestamp_s=NOW), NOW
        ).kind
        == "unknown_id"
    )
    assert (
        rx.classify(Frame(good.arbitration_id, good.data, is_fd=True, timestamp_s=NOW), NOW).kind
        == "unknown_id"
    )
    c = rx.counts()
    assert c["wrong_length"] == 1 and c["unknown_id"] == 3 and c["ok"] == 0


def test_replayed_and_skipped_counters():
    p = Protector()
    rx = Receiver(max_delta_counter=3)
    frames = [protected(Sync(t, 200 * t), p)[0] for t in range(12)]
    assert rx.classify(frames[0], NOW).kind == "ok"
    v = rx.classify(frames[0], NOW)
    assert (v.kind, v.message, v.detail) == (
        "repeated_counter",
        None,
        "SYNC: expected counter 1, got 0",
    )
    v = rx.classify(frames[2], NOW)  # one lost: still used, counted
    assert (v.kind, v.lost, v.message) == ("counter_jump", 1, Sync(2, 400))
    v = rx.classify(frames[9], NOW)  # six lost: beyond max delta, not used
    assert (v.kind, v.lost, v.message, v.usable) == ("counter_jump", 6, None, False)
    assert rx.classify(frames[10], NOW).kind == "ok"  # resynchronised
    v = rx.classify(frames[5], NOW)  # an old frame replayed: large jump, not used
    assert v.kind == "counter_jump" and v.message is None
    assert rx.counts()["lost_frames"] == 1 + 6 + 10


def test_stale_frame():
    rx = Receiver()
    fr = protected(Sync(1, 200))[0]
    v = rx.classify(fr, NOW + 0.5)
    assert v.kind == "stale" and v.message is None
    assert v.detail == "SYNC: expected age <= 0.1 s, got 0.500000 s"


def test_out_of_range_with_valid_crc():
    f = CATALOG.frame("THR_CMD_1")
    raws = unpack(f, encode(CMD)[1].data)
    raws["on_q_03"] = 18
    data = protect(f.data_id, pack(f, raws), 0)
    rx = Receiver()
    v = rx.classify(Frame(f.frame_id, data, timestamp_s=NOW), NOW)
    assert (v.kind, v.message) == ("out_of_range", None)
    assert v.detail == "THR_CMD_1.on_q_03: expected one of 0, 3..17, 20, got 18"


def test_incomplete_set_superseded_and_expired():
    rx = Receiver()
    p = Protector()
    a = protected(CMD, p)
    b = protected(ThrCmd(8, CMD.on_quanta, 3, 80), p)
    for fr in a[:3]:  # tick 7 loses its last two frames
        rx.classify(fr, NOW)
    results = [rx.classify(fr, NOW) for fr in b]
    assert results[-1].message.tick == 8
    assert rx.counts()["incomplete_set"] == 1
    ev = [e for e in rx.events if e.kind == "incomplete_set"][0]
    assert ev.detail == (
        "THR_CMD: expected frames THR_CMD_0, THR_CMD_1, THR_CMD_2, THR_CMD_3, "
        "THR_CMD_4, got THR_CMD_0, THR_CMD_1, THR_CMD_2 (superseded by key 8)"
    )
    assert rx.thr_cmd.take(7) is None and rx.thr_cmd.take(8) is not None
    c = protected(ThrCmd(9, CMD.on_quanta, 3, 90), p)
    rx.classify(c[0], NOW)
    assert rx.expire(NOW + 0.05) == []
    assert [v.kind for v in rx.expire(NOW + 0.2)] == ["incomplete_set"]
    assert rx.counts()["incomplete_set"] == 2


def test_set_inconsistency_nonzero_beyond_n_thrusters():
    short = ThrCmd(4, (3, 4), 1, 0)
    frames = encode(short)
    f = CATALOG.frame("THR_CMD_1")
    raws = unpack(f, frames[1].data)
    raws["on_q_05"] = 3
    frames[1] = Frame(f.frame_id, pack(f, raws))
    p = Protector()
    rx = Receiver()
    out = [
        rx.classify(
            Frame(
                fr.arbitration_id,
                p.protect(CATALOG.by_id[fr.arbitration_id].data_id, fr.data),
                timestamp_s=NOW,
            ),
            NOW,
        )
        for fr in frames
    ]
    assert all(v.message is None for v in out)
    assert rx.counts()["incomplete_set"] == 1


def test_assembler_take_drops_older():
    a = ThrCmdAssembler()
    assert a.take(0) is None
