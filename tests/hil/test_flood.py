"""`hil flood` frames: each class is what it says to a receiver (independent oracle: the
receiver's classification)."""

import numpy as np

from bus import e2e
from bus.catalog import CATALOG
from bus.receiver import Receiver
from hil.flood import flood, make_frames


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


def test_flood_over_virtual_reaches_its_rate():
    sent, took = flood("foreign", 2000, 0.5, "virtual", "t_flood", 1)
    assert 0.45 < took < 1.5 and 700 < sent <= 1100
