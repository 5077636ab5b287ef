"""`hil dbc --vehicle V`: the thruster-index signals decode to the vehicle's thruster names and
63 to "none" in cantools (the oracle: the vehicle file's thruster order); the committed
vehicle-free bus/hil.dbc is unchanged."""

from __future__ import annotations

import cantools

from bus.catalog import DetectedFault
from bus.codec import FdirStatus, encode
from bus.dbc import DBC_PATH, dbc_text
from hil.cli import main
from hil.config import load_vehicle


def test_orel_dbc_names_thruster_indices_and_none(tmp_path, capsys):
    out = tmp_path / "orel.dbc"
    assert main(["dbc", "--vehicle", "orel", "--out", str(out)]) == 0
    db = cantools.database.load_file(str(out))
    names = [t.name for t in load_vehicle("orel").thrusters]
    idx = names.index("3")
    [fr] = encode(FdirStatus(155, DetectedFault.STUCK_ON, idx, None, 1, False, 2))
    d = db.decode_message(fr.arbitration_id, fr.data)
    assert str(d["thruster_a"]) == "3" and str(d["thruster_b"]) == "none"
    assert str(d["fault_type"]) == "stuck_on"


def test_the_vehicle_free_dbc_is_the_committed_one():
    assert dbc_text().encode() == DBC_PATH.read_bytes()
    assert main(["dbc", "--check"]) == 0
