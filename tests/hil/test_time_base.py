"""A real-time flight's records, detections included, carry the plant's time of each tick's
sample (``FlightShell.t_of``), not the flight's own count ``n h``.

Seen in the real-time reference set: S003-progress's stuck-on, detected 0.2 s after its fault at
60.0 s, was written at 59.6 s (the flight's count runs three samples behind the plant's) and
judged a false alarm before the fault. The records had the plant's time; the detection did not.

Oracle: the plant's clock set by hand (``t0_plant_s``, what the real-time shell takes from the
first sample's sequence number); the made-up gyro of the bench raises detections by itself.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from test_safe_states import _FlightBench  # same folder (on sys.path under pytest)


def test_detections_carry_the_plant_time_of_their_tick(tmp_path: Path) -> None:
    b = _FlightBench(tmp_path, "")
    b.shell.t0_plant_s = 0.6  # the flight's tick 0 is the plant's sample 3
    try:
        for n in range(40):
            b.gyro()
            b.tick(n)
    finally:
        b.close()
    recs = b.records()
    dets = [r for r in recs if r["detection"] is not None]
    assert dets, "the bench's made-up gyro raises detections (the test needs one)"
    for r in recs:
        assert r["t_s"] == pytest.approx(0.6 + 0.2 * r["tick"], abs=1e-9)
    for r in dets:
        assert r["detection"]["t_s"] == pytest.approx(r["t_s"], abs=1e-9), r["detection"]
        assert r["detection"]["tick"] == r["tick"]
