"""`hil console`: the view model against the records it is fed (the oracle is what went in),
and the Textual app in its headless pilot at 80x24, attached to a run folder written by the
real plant shell, injecting through its fault panel (the panel bridge's path, as `hil up`)."""

from __future__ import annotations

import asyncio
import json
import re
import threading
import time

import pytest

from hil import panel_bridge
from hil.console import ConsoleModel, _app_classes, attach, phase_place
from hil.follow import JsonlFollower
from hil.panel import send_and_wait
from tests.hil.test_panel_running import _RunningPlant


def _plant(tick, **kw):
    r = {"tick": tick, "t_s": tick * 0.2, "events": [], "faults_injected": [],
         "series": {"truth/omega_deg_s": {"x": 0.3, "y": -0.01, "z": 0.0},
                    "truth/thrust_n": {"A": 0.0, "B": 10.0, "C": 10.0}}}
    r.update(kw)
    return r


def _flight(tick, **kw):
    r = {"tick": tick, "t_s": tick * 0.2, "events": [], "detection": None,
         "compute_s": 0.0021, "jitter_s": None, "overruns": 0, "safe": False,
         "fdir": {"state": "nominal", "closed_manifolds": [], "unavailable": [], "dropped": []},
         "series": {"flight/attitude_error_deg": {"x": 1.25, "y": -0.1, "z": 0.0},
                    "flight/rho_on": {"A": -2.7, "B": 0.0, "C": -0.3},
                    "flight/rho_off": {"A": 0.0, "B": 1.5, "C": 0.0},
                    "flight/thresholds": {"on": -3.0, "off": 3.0},
                    "flight/on_ms": {"A": 0, "B": 40, "C": 0}}}
    r.update(kw)
    return r


def test_panels_show_what_the_records_say():
    m = ConsoleModel()
    cfg = {"scenario": "T", "vehicle": "v", "mode": "lockstep", "thrusters": ["A", "B", "C"]}
    assert m.feed([_plant(0, config=cfg, events=["started"])], [_flight(0)])
    assert m.dead_zone == (None, None)  # no vehicle "v" to read its controller from
    m.dead_zone = (0.5, 0.12)
    fault = {"t_s": 0.4, "thruster": "C", "type": "stuck_on", "fraction": 1.0, "clear_t_s": None}
    det = {"t_s": 0.6, "tick": 3, "thruster": "C", "type": "stuck_on", "source": "residual",
           "rho": -3.1}
    act = {"t_s": 0.6, "action": "thruster_dropped", "thruster": "C"}
    m.feed([_plant(2, faults_injected=[fault])],
           [_flight(3, detection=det, fdir_actions=[act], events=["detection: x"],
                    fdir={"state": "reconfigured", "closed_manifolds": [],
                          "unavailable": ["C"], "dropped": ["C"]})])
    assert m.header() == "T  vehicle v  lockstep  tick 3  t 0.4 s"
    att = m.attitude().splitlines()
    assert att[0] == "ATT deg dz 0.5  rate deg/s dz 0.12"
    assert att[1] == "x roll    +1.250   +0.3000  out a+ r+"
    assert att[2] == "y yaw     -0.100   -0.0100  in"
    # Residuals: A is nearest its threshold (stuck-on side, 2.7 / 3), then B (1.5 / 3 off).
    res = m.residuals().splitlines()
    assert res[1] == f"       A on  {'█' * 14}{'·' * 2}  0.90"
    assert res[2] == f"       B off {'█' * 8}{'·' * 8}  0.50"
    grid = m.thrusters().splitlines()[2]
    # A idle, B commanded and thrusting, C off (dropped by the FDIR) over its fault.
    assert grid == " A. B# Cx"
    fd = m.fdir().splitlines()
    assert fd == ["FDIR reconfigured  closed: none  safe: no",
                  " detected stuck_on C 0.6 s",
                  " response thruster_dropped C 0.6 s",
                  " faults active: stuck_on C"]
    assert m.timing().splitlines()[0] == "TIMING compute 2.10 ms (max 2.1)"
    assert m.event_lines(5) == ["    0.0 plant  started", "    0.6 flight detection: x"]


def test_phase_place_names_the_sides_out_of_the_dead_zone():
    assert phase_place(0.1, 0.0, 0.5, 0.1) == "in"
    assert phase_place(-0.6, 0.2, 0.5, 0.1) == "out a- r+"
    assert phase_place(0.0, -0.11, 0.5, 0.1) == "out r-"
    assert phase_place(9.0, 9.0, None, None) == ""


def test_the_follower_takes_whole_lines_and_starts_over_on_a_new_file(tmp_path):
    f = tmp_path / "plant.jsonl"
    follow = JsonlFollower(f)
    assert follow.read() == []
    f.write_text('{"tick": 0}\n{"tick": 1')
    assert follow.read() == [{"tick": 0}]
    with f.open("a") as h:
        h.write('}\n')
    assert follow.read() == [{"tick": 1}]
    f.unlink()
    f.write_text('{"tick": 0}\n')  # a new run in the same folder
    assert follow.read() == [{"tick": 0}] and follow.restarts == 1


@pytest.fixture
def plant(tmp_path):
    p = _RunningPlant(tmp_path)
    yield p
    p.close()


def test_console_fault_panel_injects_through_the_run_folder_at_80x24(plant):
    halt = threading.Event()
    bridge = threading.Thread(target=panel_bridge.serve, daemon=True, args=(
        plant.run, "virtual", plant.channel, halt.is_set, send_and_wait))
    bridge.start()
    ConsoleApp, FaultPanel = _app_classes()
    # The panel's bus options point nowhere: the request must go through the bridge.
    app = ConsoleApp(plant.run, "virtual", "nobody-listens-here", period_s=0.05)

    async def drive():
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.pause(0.2)
            # Everything on screen fits 80x24.
            for wid in ("head", "attitude", "residuals", "fdir", "thrusters", "timing", "log"):
                r = app.query_one(f"#{wid}").region
                assert r.right <= 80 and r.bottom <= 24 and r.height > 0, (wid, r)
            assert "vehicle orel" in str(app.query_one("#head").render())
            await pilot.press("f")
            await pilot.pause(0.1)
            assert isinstance(app.screen, FaultPanel)
            await pilot.click("#thruster")
            await pilot.press(*"17")
            await pilot.click("#inject")
            t_end = time.monotonic() + 10
            # the ack arrives, then the panel shows it (a later event: on a busy host the
            # result line still said "waiting" right after the ack)
            while time.monotonic() < t_end and not (
                    app.acks and str(app.screen.query_one("#result").render()) == app.acks[0]):
                await pilot.pause(0.05)
            result = str(app.screen.query_one("#result").render())
            await pilot.press("escape")
            await pilot.pause(0.3)
            return result

    try:
        result = asyncio.run(drive())
    finally:
        halt.set()
        bridge.join(5)
    assert re.fullmatch(r"ok: plant accepted inject stuck_on 17 \(request \d+, vehicle orel\)",
                        app.acks[0]), app.acks
    assert result == app.acks[0]
    plant.settle(1)
    recs = [json.loads(x) for x in (plant.run / "plant.jsonl").read_text().splitlines()]
    assert [(f["thruster"], f["type"]) for r in recs for f in r.get("faults_injected", [])] == \
        [("17", "stuck_on")]
    # The console read that record back: the fault is active on its screen.
    model, _ = attach(plant.run)
    assert "faults active: stuck_on 17" in model.fdir()
    assert app.render_ms, "the console refreshed"


def test_a_bad_request_from_the_panel_is_the_cli_error_and_nothing_is_sent(plant):
    from hil.console import fault_request

    text = fault_request(plant.run, "inject", "99", "stuck_on", None, None, None,
                         "virtual", plant.channel, 1.0)
    assert text.startswith("error: fault: --thruster: expected one of ['1', '2',")
    assert text.endswith("got '99'")
