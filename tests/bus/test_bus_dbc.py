"""The committed DBC is what the catalog generates; bus load by an independent formula."""

import cantools

from bus.catalog import CATALOG, bus_load
from bus.dbc import DBC_PATH, dbc_text
from hil.cli import main
from hil.dbc_cmd import load_table


def test_committed_dbc_matches_catalog():
    assert DBC_PATH.read_bytes() == dbc_text().encode()


def test_dbc_load_dump_load_round_trip():
    db = cantools.database.load_file(str(DBC_PATH))
    again = cantools.database.load_string(db.as_dbc_string(), "dbc")
    assert [(m.frame_id, m.name, [s.name for s in m.signals]) for m in db.messages] == [
        (m.frame_id, m.name, [s.name for s in m.signals]) for m in again.messages
    ]
    assert {m.frame_id for m in db.messages} == set(CATALOG.by_id)
    for m in db.messages:
        f = CATALOG.by_id[m.frame_id]
        assert m.length == 8 and m.senders == [f.sender.name]
        assert m.cycle_time == (None if f.cycle_s is None else round(f.cycle_s * 1000))


def test_cli_check_and_out(tmp_path, capsys):
    assert main(["dbc", "--check"]) == 0
    out = tmp_path / "x.dbc"
    assert main(["dbc", "--out", str(out)]) == 0
    assert out.read_bytes() == DBC_PATH.read_bytes()


def test_cli_check_detects_difference(monkeypatch, tmp_path):
    stale = tmp_path / "hil.dbc"
    stale.write_text('VERSION "old"\n')
    monkeypatch.setattr("hil.dbc_cmd.DBC_PATH", stale)
    assert main(["dbc", "--check"]) == 1


def test_bus_load_independent_formula(capsys):
    # Classic standard-ID data frame, 8 bytes: SOF 1, ID 11, RTR 1, IDE 1, r0 1, DLC 4,
    # data 64, CRC 15 -> 98 bits exposed to stuffing, at most one stuff bit per 4 after the
    # first 5: (98 - 1) // 4 = 24; then CRC delimiter 1, ACK 2, EOF 7, IFS 3 = 13.
    exposed = 1 + 11 + 1 + 1 + 1 + 4 + 64 + 15
    bits = exposed + (exposed - 1) // 4 + 13
    assert bits == 135
    expected = {f.name: bits / f.cycle_s for f in CATALOG.frames if f.cycle_s}
    got = {name: bps for name, bps, _ in bus_load(1_000_000)}
    assert got == expected
    total = sum(expected.values())
    assert total / 1e6 < 0.05  # far below 100 % (docs/design.md section 4)
    assert main(["dbc", "--load", "--bitrate", "1000000"]) == 0
    assert f"{total:.0f}" in capsys.readouterr().out
    assert "total" in load_table(500_000)


def test_cli_bad_bitrate(capsys):
    assert main(["dbc", "--load", "--bitrate", "0"]) == 2
    assert capsys.readouterr().err == "error: hil dbc: --bitrate: expected > 0, got 0\n"
