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
