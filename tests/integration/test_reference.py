"""Every reference scenario (docs/design.md 8) through the real processes over vcan0, in lockstep.

Marked ``reference``: the test command runs these on the host; ``hil run-all`` itself uses the
native vcan0, or boots user-mode Linux instances (real vcan0 in each) where the kernel has no
CAN. One run-all for the module; one test per scenario asserts its expectations: the right
thruster and type, a latency no worse than the seed's, no false alarm where none is expected
(and the false alarm where one is: S003-flex-rigid), the attitude, rate, delta-v and recovery
bounds. Each over-the-bus verdict is also compared with the in-process lockstep of the same
scenario (``hil.sim``): the bus must not change what the flight detects.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.config import SCENARIO_DIR, load_scenario
from hil.sim import simulate

pytestmark = pytest.mark.reference
SCENARIOS = sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


@pytest.fixture(scope="module")
def run_all(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run-all")
    r = subprocess.run([sys.executable, "-m", "hil.cli", "run-all", "--out", str(out),
                        "--jobs", "2"], capture_output=True, text=True, timeout=3600)
    print(r.stdout[-4000:], r.stderr[-4000:])
    assert r.returncode in (0, 1), r.stdout[-2000:] + r.stderr[-2000:]
    assert (out / "report" / "report.md").exists()
    return out


@pytest.mark.parametrize("name", SCENARIOS)
def test_reference_scenario_over_the_bus(run_all: Path, name: str) -> None:
    s = json.loads((run_all / name / "summary.json").read_text())
    exp = load_scenario(SCENARIO_DIR / f"{name}.yaml").cfg.expect
    assert s["mode"] == "lockstep" and s["bus"]["flight"]["bad_crc"] == 0
    for e in exp.detections:  # right thruster, right type, latency within the seed's
        hits = [d for d in s["detections"] if d["correct"] and d["type"] == e.type
                and e.thruster in (d["thruster"] if isinstance(d["thruster"], list)
                                   else [d["thruster"]])]
        assert hits, (name, s["detections"])
        assert hits[0]["latency_s"] <= e.within_s + 1e-9, (name, hits[0])
    if exp.no_false_alarm:
        assert s["false_alarms"] == [], (name, s["false_alarms"])
    assert s["expectations_met"], (name, s["expectation_failures"])
    # The bus changes nothing the flight decides: same detections as in-process.
    ref = simulate(SCENARIO_DIR / f"{name}.yaml").summary
    key = [(d["thruster"], d["type"], d["t_s"]) for d in s["detections"]]
    assert key == [(d["thruster"], d["type"], d["t_s"]) for d in ref["detections"]], name
