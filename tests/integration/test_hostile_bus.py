"""Bus faults over a real vcan0, plant and flight as separate OS processes (``hil run``).

Marked ``vcan``: run through ``hil vcan exec`` (inside user-mode Linux where the kernel has
no CAN). Behaviour only, no figure against a time limit (docs/hostile-bus.md): bus faults,
and the shortened form of ``hil bench --parts hostile`` (floods of each class, forged and
replayed frames, into one running system).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.flood import flood
from hil.hostile import DIED, expected_at, forged_used
from hil.vcan import vcan_present

pytestmark = pytest.mark.vcan
HIL = [sys.executable, "-m", "hil.cli"]
BASE = ("name: hostile\nvehicle: generic\nduration_s: {d}\nseed: 0\n"
        "initial: {{attitude: {{axis: [1.0, 0.0, 0.0], angle_deg: 22.5}}}}\n")


def _ticks(path: Path) -> list[str]:
    try:
        return path.read_text().splitlines()
    except OSError:
        return []


def _run(tmp_path: Path, body: str, duration_s: float, *extra: str) -> tuple[dict, list, list]:
    scen = tmp_path / "s.yaml"
    scen.write_text(BASE.format(d=duration_s) + body)
    out = tmp_path / "run"
    r = subprocess.run(HIL + ["run", str(scen), "--out", str(out), *extra],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode in (0, 1), r.stdout + r.stderr  # 1: expectations (none here) unmet
    s = json.loads((out / "summary.json").read_text())
    precs = [json.loads(x) for x in (out / "plant.jsonl").read_text().splitlines()]
    frecs = [json.loads(x) for x in (out / "flight.jsonl").read_text().splitlines()]
    return s, precs, frecs


def test_gyro_drop_30_percent_over_vcan_raises_no_detection(tmp_path) -> None:
    s, _, frecs = _run(tmp_path, "faults:\n  - {kind: bus_drop, node: plant, message: GYRO, "
                                 "probability: 0.3, t_s: 2.0}\n", 30.0)
    assert s["run_failures"] == []
    assert s["detections"] == []
    assert [(f["type"], f["node"]) for f in s["faults"]] == [("bus_drop", "plant")]
    assert s["bus_faults"]["plant"]["injected"]["dropped"] > 20
    assert s["bus_faults"]["plant"]["seen_by_peer"]["counter_jump"] > 0
    assert frecs[-1]["no_evidence_ticks"] > 10


def test_flight_silent_2_s_over_vcan_plant_safe_then_recovers(tmp_path) -> None:
    s, precs, _ = _run(tmp_path, "faults:\n  - {kind: node_silent, node: flight, t_s: 4.0, "
                                 "clear_t_s: 6.0}\n", 12.0)
    safe = [r["t_s"] for r in precs if r.get("safe")]
    assert safe and 4.4 <= safe[0] <= 5.0 and safe[-1] <= 7.2
    assert not precs[-1]["safe"]
    assert s["detections"] == []
    assert s["bus_faults"]["flight"]["injected"]["silenced"] >= 70


def _last_counts(out: Path) -> dict[str, dict[str, int]]:
    """Each node's bus counters in its newest complete record (counted since its start)."""
    counts = {}
    for node in ("plant", "flight"):
        try:
            text = (out / f"{node}.jsonl").read_text()
        except OSError:
            text = ""
        lines = [x for x in text.split("\n")[:-1] if x.strip()]  # a line being written: next
        counts[node] = json.loads(lines[-1]).get("bus", {}) if lines else {}
    return counts


def _delta(after: dict, before: dict, node: str, *classes: str) -> int:
    return sum(after[node].get(c, 0) - before[node].get(c, 0) for c in classes)


@pytest.mark.skipif(not vcan_present("vcan0"), reason="the flood sends on vcan0 from here")
def test_floods_forgeries_and_replays_into_a_running_system(tmp_path) -> None:
    """One real-time run; while it runs a third node (``hil.flood``, in this process) sends
    each class in turn, 1.2 s each. Behaviour only: no process dies, nothing forged is used,
    and each class moves the counters it must (no figure against a time limit)."""
    scen = tmp_path / "s.yaml"
    scen.write_text(BASE.format(d=16.0))
    out = tmp_path / "run"
    run = subprocess.Popen(HIL + ["run", str(scen), "--out", str(out), "--mode", "realtime"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    phases = (("foreign", 2000), ("catalog-bad-crc", 300), ("catalog-forged", 200),
              ("forged", 150), ("replay", 150))
    sent, deltas = {}, {}
    try:
        t_end = time.monotonic() + 120
        while len(_ticks(out / "plant.jsonl")) < 5:  # the system runs: the flood may begin
            assert run.poll() is None and time.monotonic() < t_end, run.stdout.read()
            time.sleep(0.2)
        for k, (kind, rate) in enumerate(phases):
            before = _last_counts(out)
            sent[kind] = flood(kind, rate, 1.2, "socketcan", "vcan0", seed=k + 1)
            time.sleep(1.0)  # drained, and the authenticators waited for have expired
            deltas[kind] = (before, _last_counts(out))
        stdout = run.communicate(timeout=300)[0]
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode in (0, 1, 3), stdout  # 3: releases missed under load, judged below
    s = json.loads((out / "summary.json").read_text())
    crashed = [f for f in s["run_failures"] if any(w in f for w in (*DIED, "stopped"))]
    assert crashed == [], s["run_failures"]
    precs = [json.loads(x) for x in (out / "plant.jsonl").read_text().splitlines()]
    frecs = [json.loads(x) for x in (out / "flight.jsonl").read_text().splitlines()]
    used = forged_used(s, precs, frecs)
    assert used["fault_cmd"] == 0 and used["thr_cmd"] == 0, used  # nothing forged was used
    assert used["thr_cmd_applied"] > 0 and s["faults"] == []
    assert all(sent[k]["sent"] > 0 for k, _ in phases), sent
    bus = s["bus"]
    # Foreign identifiers never reach a node: the kernel's receive filters drop them.
    assert bus["plant"]["unknown_id"] == bus["flight"]["unknown_id"] == 0
    # Every bad CRC that reached a node's socket is counted: those the kernel did not drop.
    for node, n in expected_at(sent["catalog-bad-crc"]["by_id"]).items():
        assert n - bus[node].get("kernel_drops", 0) <= bus[node]["bad_crc"] <= n, (node, n, bus)
    assert min(n for n in expected_at(sent["catalog-bad-crc"]["by_id"]).values()) > 0
    b, a = deltas["catalog-forged"]  # valid CRCs over random payloads: later checks refuse
    assert _delta(a, b, "plant", "out_of_range", "incomplete_set", "counter_jump",
                  "repeated_counter") + _delta(a, b, "flight", "out_of_range", "incomplete_set",
                                               "counter_jump", "repeated_counter") > 0
    b, a = deltas["forged"]  # wrong MAC and missing MAC, for THR_CMD and FAULT_CMD
    assert _delta(a, b, "plant", "auth_fail") > 0 and _delta(a, b, "plant", "auth_missing") > 0
    assert _delta(a, b, "flight", "auth_fail", "auth_missing") > 0  # FAULT_CMD reaches both
    b, a = deltas["replay"]  # authentic sets, fresh E2E: only their freshness refuses them
    assert _delta(a, b, "plant", "auth_replay") > 0
