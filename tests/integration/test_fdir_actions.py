"""FDIR responses by name, from the real processes over a bus (udp_multicast: no CAN needed):
the event, the summary's ``fdir_actions`` and the report's line; delta-v in the report.

Oracles: the scenario's fault and the vehicle file (the faulty thruster's manifold, the FDIR
response configured for the fault kind); the scenario's expected delta-v.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from hil.config import REPO_ROOT, SCENARIO_DIR, load_scenario
from hil.records import fdir_actions
from tests.udp import private_udp_channel

pytestmark = pytest.mark.slow


def _run(name: str, out) -> dict:
    group = private_udp_channel("239.76")
    r = subprocess.run([sys.executable, "-m", "hil.cli", "run", name, "--out", str(out),
                        "--interface", "udp_multicast", "--channel", group],
                       capture_output=True, text=True, timeout=900, cwd=REPO_ROOT,
                       env=dict(os.environ, RERUN_ANALYTICS="0"))
    assert r.returncode in (0, 1), r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads((out / "summary.json").read_text())


def _report(out) -> str:
    r = subprocess.run([sys.executable, "-m", "hil.cli", "report", str(out), "--out",
                        str(out / "report")], capture_output=True, text=True, timeout=300,
                       cwd=REPO_ROOT)
    assert r.returncode in (0, 1), r.stderr
    return (out / "report" / "report.md").read_text()


@pytest.mark.parametrize("name", ["REC-stuck", "REC-nofire"])
def test_the_fdir_response_is_named_in_events_summary_and_report(tmp_path, name):
    sc = load_scenario(SCENARIO_DIR / f"{name}.yaml")
    [fault] = sc.cfg.faults
    response = getattr(sc.vehicle.flight.fdir, f"on_{fault.kind}")
    manifold = next(t.manifold for t in sc.vehicle.thrusters if t.name == fault.thruster)
    s = _run(name, tmp_path)
    det = next(d for d in s["detections"] if d["correct"])
    if response == "close_manifold":
        want = {"action": "manifold_closed", "manifold": manifold}
        line = f"- FDIR response: manifold {manifold} closed at {det['t_s']:.1f} s"
        event = f"fdir: manifold {manifold} closed at {det['t_s']:.1f} s"
    else:
        assert response == "drop_thruster"
        want = {"action": "thruster_dropped", "thruster": fault.thruster}
        line = f"- FDIR response: thruster {fault.thruster} dropped at {det['t_s']:.1f} s"
        event = f"fdir: thruster {fault.thruster} dropped at {det['t_s']:.1f} s"
    assert s["fdir_actions"] == [{"t_s": det["t_s"], **want}]
    events = [e for x in (tmp_path / "flight.jsonl").read_text().splitlines()
              for e in json.loads(x).get("events", [])]
    assert event in events
    assert line in _report(tmp_path)


def test_delta_v_is_in_the_report_beside_the_expected(tmp_path):
    sc = load_scenario(SCENARIO_DIR / "S004-polar.yaml")
    s = _run("S004-polar", tmp_path)
    dv = ", ".join(f"{x:.3f}" for x in s["delta_v_B_m_s"])
    want = ", ".join(f"{x:g}" for x in sc.cfg.expect.delta_v_B_m_s)
    assert f"- delta-v (body) [{dv}] m/s, expected [{want}] m/s" in _report(tmp_path)


def _view(state="nominal", closed=(), dropped=()):
    return {"state": state, "closed_manifolds": list(closed), "unavailable": [],
            "dropped": list(dropped)}


def test_actions_are_the_changes_between_two_ticks():
    assert fdir_actions(None, _view(closed=["I"]), 1.0) == []  # the first tick: no change
    assert fdir_actions(_view(), _view(closed=["II"], dropped=["4"]), 2.0) == [
        {"t_s": 2.0, "action": "manifold_closed", "manifold": "II"},
        {"t_s": 2.0, "action": "thruster_dropped", "thruster": "4"}]
    assert fdir_actions(_view(closed=["II"], dropped=["4"]), _view(), 3.0) == [
        {"t_s": 3.0, "action": "manifold_opened", "manifold": "II"},
        {"t_s": 3.0, "action": "thruster_restored", "thruster": "4"}]
    # Safe mode turns every thruster off: not a drop of each.
    assert fdir_actions(_view(), _view(state="safe"), 4.0) == []
