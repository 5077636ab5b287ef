"""Fault panel: bad requests are refused before anything is sent."""

from __future__ import annotations

import pytest

from bus.catalog import FaultAction, FaultKind
from bus.codec import encode
from hil.cli import main
from hil.errors import FaultCommandError
from hil.panel import build_command


def test_good_request_builds_fault_cmd() -> None:
    c = build_command("generic", "inject", "X-", "degraded", 0.4, 3.0, None, 7)
    assert (c.action, c.kind, c.thruster, c.fraction, c.start_time_s) == (
        FaultAction.INJECT, FaultKind.DEGRADED, 1, 0.4, 3.0)


@pytest.mark.parametrize(("thr", "kind", "frac", "at", "msg"), [
    ("X9", "stuck_on", None, None,
     "fault: --thruster: expected one of ['X+', 'X-', 'Y+', 'Y-', 'Z+', 'Z-'], got 'X9'"),
    ("X+", "stuck_on", 1.5, None, "fault: --fraction: expected a value in [0, 1], got 1.5"),
    ("X+", "degraded", None, None,
     "fault: --fraction: expected a value in [0, 1] for a degraded thruster, got nothing"),
    ("X+", "stuck_on", None, -1.0, "fault: --at: expected a time >= 0 s, got -1.0"),
])
def test_bad_requests_refused(thr, kind, frac, at, msg) -> None:
    with pytest.raises(FaultCommandError) as info:
        build_command("generic", "inject", thr, kind, frac, at, None, 1)
    assert str(info.value) == msg


def test_cli_refuses_without_touching_the_bus(capsys, tmp_path) -> None:
    # The interface does not exist: reaching it would be a BusError, not this message.
    rc = main(["fault", "inject", "--thruster", "Q", "--type", "stuck_on", "--vehicle",
               "generic", "--run", str(tmp_path), "--interface", "nonexistent"])
    assert rc == 2
    assert capsys.readouterr().err.startswith("error: fault: --thruster: expected one of")


def test_without_a_running_system_or_vehicle_nothing_is_sent(capsys, tmp_path) -> None:
    for action in (["inject", "--thruster", "X+", "--type", "stuck_on"], ["clear"], ["list"]):
        rc = main(["fault", *action, "--run", str(tmp_path), "--interface", "nonexistent"])
        assert rc == 2
        assert capsys.readouterr().err == (
            f"error: fault: --vehicle: expected the vehicle of a running `hil up`, got no "
            f"plant record in {tmp_path}: give --run DIR (the --out of hil up) or "
            f"--vehicle V\n")


def test_clear_builds_a_clear_command() -> None:
    every = build_command("generic", "clear", None, None, None, None, None, 9)
    assert (every.action, every.kind, every.thruster, every.request_id) == (
        FaultAction.CLEAR, FaultKind.NONE, None, 9)
    encode(every)  # the catalog takes kind "none" (it once refused it: no clear ever went)
    one = build_command("orel", "clear", "17", None, None, None, None, 10)
    assert (one.action, one.thruster) == (FaultAction.CLEAR, 16)
    with pytest.raises(FaultCommandError, match="--thruster: expected one of"):
        build_command("generic", "clear", "17", None, None, None, None, 11)
