"""Codecs: hypothesis round trips, cantools (bus/hil.dbc alone) as the oracle, error texts."""

import cantools
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bus.catalog import (
    ALLOWED_ON_QUANTA,
    CATALOG,
    AckReason,
    AckStatus,
    DetectedFault,
    FaultAction,
    FaultKind,
    Node,
    NodeState,
)
from bus.codec import (
    FaultAck,
    FaultCmd,
    FdirStatus,
    FlightTiming,
    Gyro,
    Heartbeat,
    Sync,
    ThrCmd,
    decode,
    encode,
)
from bus.dbc import DBC_PATH
from bus.e2e import Protector
from hil.errors import EncodeError

DB = cantools.database.load_file(str(DBC_PATH))

u = st.integers
rate = u(-2_000_000, 2_000_000).map(lambda r: r * 1e-7)
thr = st.one_of(st.none(), u(0, 62))


def quantised(scale):
    return lambda r: r * scale


messages = st.one_of(
    st.builds(Sync, u(0, 2**24 - 1), u(0, 2**28 - 1)),
    st.builds(Gyro, u(0, 65535), st.tuples(rate, rate, rate), u(0, 7)),
    st.builds(
        lambda tick, q, mask, seq: ThrCmd(tick, tuple(q), mask, seq),
        u(0, 2**24 - 1),
        st.lists(st.sampled_from(ALLOWED_ON_QUANTA), min_size=1, max_size=32),
        u(0, 15),
        u(0, 65535),
    ),
    st.builds(
        FdirStatus,
        u(0, 2**24 - 1),
        st.sampled_from(DetectedFault),
        thr,
        thr,
        u(0, 15),
        st.booleans(),
        u(0, 255),
    ),
    st.builds(
        FaultCmd,
        u(0, 255),
        st.sampled_from(FaultAction),
        st.sampled_from(list(FaultKind)[1:]),
        thr,
        u(0, 10000).map(quantised(1e-4)),
        u(0, 2**22 - 1).map(quantised(0.01)),
        st.one_of(st.none(), u(1, 2**22 - 1).map(quantised(0.01))),
    ),
    st.builds(
        FaultAck,
        u(0, 255),
        st.sampled_from(AckStatus),
        st.sampled_from(AckReason),
        st.sampled_from(FaultKind),
    ),
    st.builds(FlightTiming, u(0, 2**24 - 1), u(0, 2**20 - 1).map(quantised(1e-6)), u(0, 255)),
    st.builds(
        Heartbeat,
        st.sampled_from(Node),
        st.sampled_from(NodeState),
        u(0, 65535),
        u(0, 65535),
        u(0, 4095),
    ),
)


@given(messages)
def test_round_trip(msg):
    assert decode(encode(msg)) == msg


@given(messages)
def test_cantools_decodes_our_frames_from_the_dbc_alone(msg):
    protector = Protector()
    ours = {}
    for fr in encode(msg):
        f = CATALOG.by_id[fr.arbitration_id]
        data = protector.protect(f.data_id, fr.data)
        theirs = DB.get_message_by_frame_id(fr.arbitration_id).decode(
            data, decode_choices=False, scaling=True
        )
        assert theirs.pop("E2E_CRC") == data[0]
        assert theirs.pop("E2E_COUNTER") == data[1] & 0x0F
        ours[f.name] = theirs
    # Rebuild the typed message from cantools' physical values.
    assert type(msg).from_signals(ours) == msg


@given(messages)
def test_cantools_encodes_what_we_decode(msg):
    for fr in encode(msg):
        m = DB.get_message_by_frame_id(fr.arbitration_id)
        values = m.decode(fr.data, decode_choices=False, scaling=False)
        assert m.encode(values, scaling=False, strict=False) == fr.data


def test_gyro_precision():
    g = decode(encode(Gyro(1, (0.0610865238, -1.23456789e-5, 2e-7))))
    assert g.omega_B_rad_s[0] == pytest.approx(0.0610865238, abs=0.5e-7)
    assert g.omega_B_rad_s[1] == pytest.approx(-1.23456789e-5, abs=0.5e-7)


@pytest.mark.parametrize(
    "msg, text",
    [
        (ThrCmd(1, (18,), 1, 0), "THR_CMD.on_q_00: expected one of 0, 3..17, 20, got 18"),
        (ThrCmd(1, (3,) * 33, 1, 0), "THR_CMD.on_quanta: expected 1..32 thrusters, got 33"),
        (ThrCmd(1, (3,), 16, 0), "THR_CMD.manifold_enable: expected 0 <= value <= 15, got 16"),
        (Gyro(1, (0.25, 0.0, 0.0)), "GYRO.rate_x: expected -0.2 <= value <= 0.2 rad/s, got 0.25"),
        (
            Gyro(1, (0.0, float("nan"), 0.0)),
            "GYRO.rate_y: expected -0.2 <= value <= 0.2 rad/s, got nan",
        ),
        (Sync(2**24, 0), "SYNC.tick: expected 0 <= value <= 16777215 tick, got 16777216"),
        (Sync(1.5, 0), "SYNC.tick: expected an integer, got 1.5"),
        (
            FaultCmd(1, FaultAction.INJECT, FaultKind.STUCK_ON, 3, 1.5),
            "FAULT_CMD.fraction: expected 0 <= value <= 1, got 1.5",
        ),
        (
            FaultAck(1, AckStatus.ACCEPTED, 99),
            "FAULT_ACK.reason: expected one of 0 (none), "
            "1 (unknown_kind), 2 (bad_thruster), 3 (bad_fraction), 4 (bad_time), 5 (not_active), "
            "6 (busy), got 99",
        ),
    ],
)
def test_encode_error_texts(msg, text):
    with pytest.raises(EncodeError) as err:
        encode(msg)
    assert str(err.value) == text
