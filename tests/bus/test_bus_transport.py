"""Transport: open errors, Port over python-can's virtual bus, candump log round trip."""

import can
import pytest

from bus.catalog import CATALOG
from bus.codec import Frame, Sync, ThrCmd, decode, encode
from bus.transport import BusConfig, BusLogger, Port, from_can_message, open_bus
from hil.errors import BusError


def test_open_error_is_one_line():
    with pytest.raises(BusError) as err:
        open_bus(BusConfig(interface="no_such_interface", channel="x"))
    assert str(err.value) == (
        'bus: cannot open no_such_interface channel x: Unknown interface type "no_such_interface"'
    )


def test_config_forbids_unknown_fields():
    with pytest.raises(ValueError):
        BusConfig(interfase="virtual")
    assert BusConfig().interface == "socketcan" and BusConfig().channel == "vcan0"


def test_port_over_virtual_and_log(tmp_path):
    log = tmp_path / "bus.log"
    a = Port(
        open_bus(BusConfig(interface="virtual", channel="t_port")),
        logger=BusLogger(log, channel="vcan0"),
    )
    b = Port(open_bus(BusConfig(interface="virtual", channel="t_port")))
    try:
        cmd = ThrCmd(3, (3, 20, 0), 1, 30)
        assert a.clock == "realtime"
        a.send(cmd)
        a.send(Sync(3, 600))
        bad = a.protect(Sync(4, 800))[0]
        a.send_frame(Frame(bad.arbitration_id, bytes([bad.data[0] ^ 0xFF]) + bad.data[1:]))
        got = b.poll(1.0)
        while len(got) < 2:
            more = b.poll(1.0)
            assert more
            got += more
        assert [m for m, _ in got] == [cmd, Sync(3, 600)]
        now = b.now_s()
        assert all(abs(now - t) < 60 for _, t in got)  # rx times in the port's (wall) clock
        assert abs(b.to_monotonic_s(now) - __import__("time").monotonic()) < 1.0
        assert b.counts()["bad_crc"] == 1 and b.counts()["ok"] == 6
        assert a.counts()["tx_frames"] == 7
    finally:
        a.close()
        b.close()
    frames = [from_can_message(m) for m in can.LogReader(str(log))]
    assert len(frames) == 7
    assert decode(frames[:5]) == cmd and decode(frames[5:6]) == Sync(3, 600)
    assert [f.arbitration_id for f in frames[:5]] == [fr.arbitration_id for fr in encode(cmd)]
    assert log.read_text().splitlines()[0].split()[1:] == [
        "vcan0",
        f"{CATALOG.frame('THR_CMD_0').frame_id:03X}#{frames[0].data.hex().upper()}",
        "T",
    ]


class _Clocks:
    """A scripted pair of clocks for ``bus.transport``'s ``time``: monotonic and wall readings
    in call order, so the stall between two reads and a wall-clock step are ours to place."""

    def __init__(self, mono: list[float], wall: list[float]):
        self.mono, self.wall = list(mono), list(wall)

    def monotonic(self) -> float:
        return self.mono.pop(0)

    def time(self) -> float:
        return self.wall.pop(0)


def test_clock_offset_takes_the_narrowest_bracket_and_is_sampled_again(monkeypatch):
    import bus.transport as tr

    # Five (monotonic, wall, monotonic) reads; the first is stalled 8 ms between its wall read
    # and the second monotonic read (a descheduled process): true offset 100.0 s.
    mono = [1.000, 1.0081, 2.0, 2.00001, 3.0, 3.00002, 4.0, 4.00002, 5.0, 5.00003]
    wall = [-99.0, -98.0, -97.0, -96.0, -95.0]
    monkeypatch.setattr(tr, "time", _Clocks(mono, wall))
    off, width = tr.clock_offset_s()
    assert off == pytest.approx(100.0 + 0.000005, abs=1e-9) and width == pytest.approx(1e-5)
    # The single stalled read alone would have been 4 ms off:
    assert abs((0.5 * (1.000 + 1.0081) + 99.0) - off) > 0.004

    port = object.__new__(Port)
    port.monotonic_offset_s, port.monotonic_offset_width_s, port._offset_at = 100.0, 0.0, 10.0
    # Within OFFSET_RESAMPLE_S: the same offset, one monotonic read.
    monkeypatch.setattr(tr, "time", _Clocks([10.5], []))
    assert port.to_monotonic_s(-90.0) == pytest.approx(10.0)
    # The wall clock stepped 2 s forward; once the offset is old it is sampled again.
    step = [11.6] + [x for k in range(5) for x in (11.6 + k, 11.6 + k)]
    monkeypatch.setattr(tr, "time", _Clocks(step, [-88.4 + 2.0 + k for k in range(5)]))
    assert port.to_monotonic_s(-86.4) == pytest.approx(11.6)
    assert port.monotonic_offset_s == pytest.approx(98.0) and port._offset_at == 11.6
