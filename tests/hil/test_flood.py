"""`hil flood` frames: each class is what it says to a receiver (independent oracle: the
receiver's classification and the SecOC check of ``bus.secoc``)."""

import numpy as np

from bus import e2e
from bus.catalog import CATALOG, FAULT_CMD_IDS, THR_CMD_IDS
from bus.codec import ThrCmd, encode
from bus.receiver import Receiver
from bus.secoc import Authenticator
from hil.flood import Listener, flood, make_frames

KEY = bytes(range(32))


def test_each_class_is_classified_as_it_claims():
    rng = np.random.default_rng(0)
    for kind, klass in (("foreign", "unknown_id"), ("catalog-bad-crc", "bad_crc")):
        rx = Receiver()
        for f in make_frames(kind, 300, rng, e2e.Protector()):
            rx.classify(f, 0.0)
        assert rx.counters[klass] == 300, (kind, rx.counts())
    forged = make_frames("catalog-forged", 300, rng, e2e.Protector())
    assert all(f.arbitration_id in CATALOG.by_id for f in forged)
    rx = Receiver()
    for f in forged:
        rx.classify(f, 0.0)
    assert rx.counters["bad_crc"] == 0  # valid CRCs: only authentication can refuse them


class _Genuine:
    """A genuine flight's THR_CMD with its authenticator, as a port sends them."""

    def __init__(self) -> None:
        self.protector = e2e.Protector()
        self.auth = Authenticator(KEY)

    def frames(self, tick: int) -> list:
        out = []
        msg = ThrCmd(tick, (0, 5, 0, 0, 3, 0), 0x3, tick)
        mac = self.auth.sign(msg, 0.0)
        for m in (msg, mac):
            for fr in encode(m):
                f_def = CATALOG.by_id[fr.arbitration_id]
                out.append(type(fr)(fr.arbitration_id,
                                    self.protector.protect(f_def.data_id, fr.data)))
        return out


def _receive(rx: Receiver, auth: Authenticator, frames: list, now: float) -> list:
    msgs = [(v.message, now) for v in (rx.classify(f, now) for f in frames)
            if v.message is not None]
    return auth.accept(msgs, now)


def test_forged_frames_pass_e2e_and_stop_at_authentication():
    genuine, rx, auth = _Genuine(), Receiver(), Authenticator(KEY)
    heard = Listener()
    for tick in range(3):
        frames = genuine.frames(tick)
        for f in frames:
            heard.see(f)
        assert len(_receive(rx, auth, frames, tick * 0.2)) == 1
    assert (heard.tick, heard.n_thr, heard.manifolds) == (2, 6, 0x3)
    forged = make_frames("forged", 40, np.random.default_rng(1), e2e.Protector(), heard)
    assert {f.arbitration_id for f in forged} >= {THR_CMD_IDS[0], FAULT_CMD_IDS[0],
                                                  CATALOG.frame("GYRO_1").frame_id}
    used = _receive(rx, auth, forged, 0.6)
    auth.expire(5.0)  # the forgeries without an authenticator are missing by now
    assert used == []
    bad = {k: v for k, v in rx.counts().items() if k in ("bad_crc", "counter_jump",
                                                          "repeated_counter", "unknown_id")}
    assert not any(bad.values()), bad  # every forged frame passed the E2E checks
    assert auth.counts["auth_fail"] > 0 and auth.counts["auth_missing"] > 0
    assert auth.counts["auth_ok"] == 3


def test_replayed_authentic_sets_are_refused_by_freshness():
    genuine, rx, auth = _Genuine(), Receiver(), Authenticator(KEY)
    heard = Listener()
    assert make_frames("replay", 10, np.random.default_rng(1), e2e.Protector(), heard) == []
    frames = genuine.frames(7)
    for f in frames:
        heard.see(f)
    assert len(_receive(rx, auth, frames, 1.4)) == 1
    replay = make_frames("replay", 20, np.random.default_rng(1), e2e.Protector(), heard)
    assert len(replay) >= 20 and len(replay) % len(frames) == 0
    assert [f.data[2:] for f in replay[: len(frames)]] == [f.data[2:] for f in frames]
    assert _receive(rx, auth, replay, 1.5) == []
    assert auth.counts["auth_replay"] == len(replay) // len(frames)
    assert rx.counts()["bad_crc"] == 0 and rx.counts()["repeated_counter"] == 0


def test_flood_over_virtual_reaches_its_rate_and_counts_by_identifier():
    res = flood("foreign", 2000, 0.5, "virtual", "t_flood", 1)
    assert 0.45 < res["seconds"] < 1.5 and 700 < res["sent"] <= 1100
    assert sum(res["by_id"].values()) == res["sent"]
    assert not set(map(int, res["by_id"])) & {f.frame_id for f in CATALOG.frames}


def test_forged_flood_over_virtual_goes_through_every_secured_message_with_and_without_mac():
    """Groups are numbered across bursts, so a flood cycles THR_CMD, FAULT_CMD and GYRO, each
    in turn with a wrong authenticator and with none."""
    res = flood("forged", 600, 0.5, "virtual", "t_flood_forged", 1)
    by_id = {int(k): v for k, v in res["by_id"].items()}
    firsts = [CATALOG.frame(n).frame_id for n in ("THR_CMD_0", "FAULT_CMD_0", "GYRO_1")]
    macs = [CATALOG.frame(n).frame_id for n in ("THR_CMD_MAC", "FAULT_CMD_MAC", "GYRO_MAC")]
    assert all(by_id.get(i, 0) >= 2 for i in firsts), by_id
    assert all(0 < by_id.get(m, 0) < by_id[i] for i, m in zip(firsts, macs, strict=True)), by_id
    assert res["groups"] == sum(by_id[i] for i in firsts)


def test_frames_per_identifier_of_cycled_groups_match_sending_them_in_turn():
    """Oracle: send each group's frames in turn, one by one (itertools.cycle), and count."""
    from collections import Counter
    from itertools import cycle, islice

    from hil.flood import by_id_of_cycles

    rng = np.random.default_rng(3)
    groups = [make_frames("catalog-bad-crc", n, rng, e2e.Protector()) for n in (7, 256, 1)]
    for sent in ([0, 0, 0], [3, 255, 5], [7 * 4 + 2, 256 * 3, 0], [1000, 1, 9]):
        want: Counter[int] = Counter()
        for frames, m in zip(groups, sent, strict=True):
            want.update(f.arbitration_id for f in islice(cycle(frames), m))
        got = by_id_of_cycles(groups, sent)
        assert +got == +want and sum(got.values()) == sum(sent)


def test_sender_choice_is_said_and_a_kernel_sender_that_cannot_be_had_is_refused():
    import pytest

    res = flood("foreign", 200, 0.1, "virtual", "t_flood_sender", 1)  # auto on virtual
    assert res["sender"] == "python" and "broadcast manager" in res["sender_note"]
    res = flood("foreign", 200, 0.1, "virtual", "t_flood_sender", 1, sender="python")
    assert res["sender"] == "python" and "sender_note" not in res
    with pytest.raises(ValueError, match=r"^flood: sender kernel: expected .*got class "
                                         r"'foreign' on 'virtual'$"):
        flood("foreign", 200, 0.1, "virtual", "t_flood_sender", 1, sender="kernel")
    with pytest.raises(ValueError, match=r"got class 'replay' on 'socketcan'$"):
        flood("replay", 200, 0.1, "socketcan", "vcan0", 1, sender="kernel")
    with pytest.raises(ValueError, match=r"^flood: sender: expected one of auto, kernel, "
                                         r"python, got 'bcm'$"):
        flood("foreign", 200, 0.1, "virtual", "t_flood_sender", 1, sender="bcm")
