"""The system over LCM for real: a udpm provider, separate OS processes (docs/lcm.md).

Run through ``hil netns exec -- .venv/bin/python -m pytest -m lcm ...``: a private network
namespace whose loopback has the multicast route (the host's routes untouched). There
``HIL_REQUIRE_LCM=1`` makes a skip a failure (tests/conftest.py), so these never pass by
skipping. Each test takes its own udpm port, so tests do not hear one another.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bus.catalog import CATALOG
from bus.codec import Frame, ThrCmd
from bus.echo_peer import N_THRUSTERS, expected_command
from bus.lcm_transport import LcmPort
from bus.protocol import CommandReady, PlantLockstep
from hil.netns import NETNS_ENV

REPO = Path(__file__).resolve().parents[2]
HIL = [sys.executable, "-m", "hil.cli"]
SCENARIO = REPO / "configs/scenarios/S000-stuck.yaml"


def _udpm_works() -> bool:
    import lcm

    try:
        lcm.LCM("udpm://239.255.76.67:7667?ttl=0")
    except (OSError, RuntimeError):
        return False
    return True


pytestmark = [
    pytest.mark.lcm,
    pytest.mark.skipif(not os.environ.get(NETNS_ENV) or not _udpm_works(),
                       reason="needs hil's network namespace: run through `hil netns exec`"),
]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return s.getsockname()[1]


@pytest.fixture
def url() -> str:
    return f"udpm://239.255.76.67:{_free_port()}?ttl=0"


TICKS, CORRUPT_TICK, BAD_SYNC_TICK = 50, 25, 10


def test_two_process_lockstep_over_udpm(url):
    """The two-process lockstep suite (tests/bus/test_two_process.py) over LCM: a corrupted
    SYNC and a corrupted THR_CMD frame are counted and dropped; every command arrives."""
    peer = subprocess.Popen([sys.executable, "-m", "bus.echo_peer", "--interface", "lcm",
                             "--channel", url, "--ticks", str(TICKS), "--corrupt-tick",
                             str(CORRUPT_TICK)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO)
    port = LcmPort(url)
    assert peer.stdout.readline().strip() == "ready", peer.stderr.read()
    time.sleep(0.2)  # the peer subscribes right after "ready"
    plant = PlantLockstep(N_THRUSTERS, reply_timeout_s=5.0)
    got = []
    try:
        for n in range(TICKS):
            sync = plant.begin_tick(n, port.now_s())
            if n == BAD_SYNC_TICK:
                fr = port.protect(sync)[0]
                port.send_frame(Frame(fr.arbitration_id,
                                      fr.data[:3] + bytes([fr.data[3] ^ 4]) + fr.data[4:]))
                did = CATALOG.frame("SYNC").data_id
                port.protector.counters[did] = (port.protector.counters[did] - 1) % 16
            port.send(sync)
            while plant.result is None:
                for msg, rx_s in port.poll(0.1):
                    for ev in plant.on_message(msg, rx_s):
                        if isinstance(ev, CommandReady):
                            got.append(ev.command)
                plant.poll(port.now_s())
            assert not plant.result.safe, f"tick {n}: {plant.result.reason}"
        out, err = peer.communicate(timeout=30)
    finally:
        if peer.poll() is None:
            peer.kill()
        port.close()
    assert peer.returncode == 0, err
    peer_counts = json.loads(out.strip().splitlines()[-1])
    assert [c.tick for c in got] == list(range(TICKS))
    for n, cmd in enumerate(got):
        q, mask, seq = expected_command(n)
        assert cmd == ThrCmd(n, q, mask, seq)
    c = port.counts()
    # Tick 25: the set with a bad frame 2 (frames 0, 1, 3, 4 good), then the whole command
    # again with the next counters. Same rules as CAN: one CRC failure; the partial set is
    # dropped when frame 0 comes twice (incomplete_set); frame 2's counter skips the value
    # spent on the bad frame (counter_jump, used); 4 + 4 more frames accepted.
    assert c["bad_crc"] == 1 and c["incomplete_set"] == 1 and c["counter_jump"] == 1, c
    assert c["ok"] == 5 * TICKS + 3, c
    assert c["lost_frames"] == 1 and c["repeated_counter"] == 0, c
    assert peer_counts["replied"] == TICKS and peer_counts["bad_crc"] == 1
    assert peer_counts["ok"] == TICKS and peer_counts["repeated_counter"] == 0
    assert c["lcm_rx_bytes"] > 0 and c["lcm_malformed"] == 0


def _run(args: list[str], out: Path, env: dict | None = None) -> dict:
    r = subprocess.run([*HIL, "run", *args, "--out", str(out)], capture_output=True,
                       text=True, cwd=REPO, env=env, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads((out / "summary.json").read_text())


def _same_outcome(a: dict, b: dict) -> None:
    for key in ("detections", "faults", "false_alarms", "missed_faults", "fuel_kg",
                "max_attitude_error_deg", "max_rate_error_deg_s", "delta_v_B_m_s",
                "fdir_actions", "safe_events", "ticks", "verdict"):
        assert a[key] == b[key], key


def _log(path: Path) -> dict[str, list]:
    """The events of an LCM log by channel, read with LCM's own reader."""
    import lcm

    out: dict[str, list] = {}
    for ev in lcm.EventLog(str(path), "r"):
        out.setdefault(ev.channel, []).append(ev)
    return out


def _check_telemetry(run: Path, summary: dict) -> None:
    """run.lcmlog (written by lcm-logger) holds one truth_t and one flight_view_t per tick,
    equal to the records; the detection is where flight.jsonl has it."""
    from hil.hil_telemetry import flight_view_t, truth_t

    log = _log(run / "run.lcmlog")
    plant = [json.loads(x) for x in (run / "plant.jsonl").read_text().splitlines()]
    plant = [r for r in plant if not r.get("final")]
    flight = [json.loads(x) for x in (run / "flight.jsonl").read_text().splitlines()]
    truth = [truth_t.decode(e.data) for e in log["HIL_TRUTH"]]
    view = [flight_view_t.decode(e.data) for e in log["HIL_FLIGHT_VIEW"]]
    assert [m.tick for m in truth] == [r["tick"] for r in plant]
    assert [m.fuel_kg for m in truth] == [r["fuel_kg"] for r in plant]
    assert [m.att_err_deg for m in truth] == [r["att_err_deg"] for r in plant]
    assert truth[-1].fuel_kg == summary["fuel_kg"]
    assert summary["lcm_log_telemetry"] == {"HIL_TRUTH": len(truth),
                                            "HIL_FLIGHT_VIEW": len(view)}
    assert [m.tick for m in view] == [r["tick"] for r in flight]
    got = [(m.tick, m.detection_type, m.detection_thruster) for m in view if m.detection_type]
    want = [(r["tick"], r["detection"]["type"], r["detection"]["thruster"]) for r in flight
            if r.get("detection")]
    assert got == want and got
    names = dict(zip(view[5].names, view[5].values, strict=True))
    assert names["flight/omega_meas_deg_s/x"] == \
        flight[5]["series"]["flight/omega_meas_deg_s"]["x"]


def _jsonl(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def lcm_run(tmp_path_factory) -> Path:
    """S000-stuck in lockstep over LCM with --lcm-log (shared by the tests that read it)."""
    out = tmp_path_factory.mktemp("lcm-run") / "lcm"
    _run([str(SCENARIO), "--bus", "lcm", "--lcm-url",
          f"udpm://239.255.76.67:{_free_port()}?ttl=0", "--lcm-log"], out)
    return out


def test_lockstep_over_lcm_equals_lockstep_over_can(lcm_run, tmp_path):
    """S000-stuck in lockstep over LCM and over python-can's udp_multicast (the CAN
    interface the tests use between processes): the same detections, truth, delta-v and
    fuel. Both write run.lcmlog with lcm-logger: the LCM run its control channels and
    telemetry, the CAN run its telemetry alone."""
    lcm_s = json.loads((lcm_run / "summary.json").read_text())
    env = dict(os.environ, CAN_CONFIG=json.dumps({"port": _free_port()}))
    can_s = _run([str(SCENARIO), "--interface", "udp_multicast", "--channel",
                  "239.74.163.2", "--lcm-log", "--lcm-url",
                  f"udpm://239.255.76.67:{_free_port()}?ttl=0"], tmp_path / "can", env=env)
    _check_telemetry(lcm_run, lcm_s)
    _check_telemetry(tmp_path / "can", can_s)
    ticks = lcm_s["ticks"]
    lcm_log, can_log = _log(lcm_run / "run.lcmlog"), _log(tmp_path / "can/run.lcmlog")
    for ch in ("HIL_SYNC", "HIL_GYRO", "HIL_THR_CMD", "HIL_FDIR_STATUS"):
        assert len(lcm_log[ch]) == ticks, ch
    assert set(can_log) == {"HIL_TRUTH", "HIL_FLIGHT_VIEW", "HIL_RUN_END"}
    assert lcm_s["bus_kind"] == "lcm" and can_s["bus_kind"] == "can"
    assert lcm_s["detections"] and lcm_s["detections"][0]["thruster"] == "X+"
    _same_outcome(lcm_s, can_s)
    # tick by tick: what the flight measured, estimated and commanded, and the plant's truth
    la, ca = _jsonl(lcm_run / "flight.jsonl"), _jsonl(tmp_path / "can/flight.jsonl")
    series = ("flight/omega_meas_deg_s", "flight/omega_est_deg_s", "flight/rho_off",
              "flight/on_ms")
    assert len(la) == len(ca) == ticks
    for a, b in zip(la, ca, strict=True):
        assert (a["tick"], a["detection"]) == (b["tick"], b["detection"])
        assert {k: a["series"][k] for k in series} == {k: b["series"][k] for k in series}
    lp = [x for x in _jsonl(lcm_run / "plant.jsonl") if not x.get("final")]
    cp = [x for x in _jsonl(tmp_path / "can/plant.jsonl") if not x.get("final")]
    truth = ("tick", "att_err_deg", "rate_err_deg_s", "fuel_kg", "dv_B_m_s")
    assert [{k: x[k] for k in truth} | {"omega": x["series"]["truth/omega_deg_s"]} for x in lp] \
        == [{k: x[k] for k in truth} | {"omega": x["series"]["truth/omega_deg_s"]} for x in cp]
    # bus.log of the LCM run holds the CAN frames the messages stand for
    first = (lcm_run / "bus.log").read_text().splitlines()[0]
    assert " lcm " in first and "#" in first


def test_the_log_replayed_gives_the_records_recording_and_report(lcm_run, tmp_path):
    """run.lcmlog played by the real lcm-logplayer (`hil record --from-lcm-log`, `hil report
    --from-lcm-log`) rebuilds the per-tick records the run wrote itself: plant.jsonl and
    flight.jsonl (the oracle) agree on every field the telemetry carries, the inputs of
    run.rrd (ticks, series, events) are equal, and the report's plots and table are the same
    bytes as those made from the JSON lines."""
    url = f"udpm://239.255.76.67:{_free_port()}?ttl=0"
    r = subprocess.run([*HIL, "record", "--from-lcm-log", str(lcm_run / "run.lcmlog"),
                        "--out", str(tmp_path / "rec"), "--lcm-url", url],
                       capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "150 plant and 150 flight records" in r.stdout and "lcm-logplayer" in r.stdout
    plant = [x for x in _jsonl(lcm_run / "plant.jsonl") if not x.get("final")]
    flight = _jsonl(lcm_run / "flight.jsonl")
    for own, rebuilt in ((plant, _jsonl(tmp_path / "rec/plant.jsonl")),
                         (flight, _jsonl(tmp_path / "rec/flight.jsonl"))):
        assert len(rebuilt) == len(own) == 150
        for a, b in zip(own, rebuilt, strict=True):
            assert {k: a[k] for k in b} == b, a["tick"]
            assert {k: a[k] for k in ("tick", "t_s", "series", "events")} == \
                {k: b[k] for k in ("tick", "t_s", "series", "events")}
    assert [x["detection"]["thruster"] for x in _jsonl(tmp_path / "rec/flight.jsonl")
            if x["detection"]] == ["X+"]
    assert (tmp_path / "rec/run.rrd").stat().st_size > 10_000
    reports = {}
    for name, extra in (("json", []), ("lcm", ["--from-lcm-log", "--lcm-url", url])):
        r = subprocess.run([*HIL, "report", str(lcm_run), "--out", str(tmp_path / name),
                            *extra], capture_output=True, text=True, cwd=REPO, timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr
        reports[name] = {p.name: p.read_bytes() for p in (tmp_path / name).iterdir()
                         if p.suffix in (".png", ".json")}
    assert len(reports["json"]) == 5 and reports["lcm"] == reports["json"]
    assert "per-tick data: run.lcmlog replayed by lcm-logplayer" in \
        (tmp_path / "lcm/report.md").read_text()


def test_reference_scenario_over_lcm_has_its_verdict(url, tmp_path):
    """S000-nofire (a reference scenario) through `hil run-all --bus lcm`, in lockstep over
    LCM: its expectations met, the verdict the reference tier asserts over vcan, and the
    report of the set."""
    r = subprocess.run([*HIL, "run-all", "--bus", "lcm", "--lcm-url", url, "--only",
                        "S000-nofire", "--out", str(tmp_path / "all")], capture_output=True,
                       text=True, cwd=REPO, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "run-all: every expectation holds" in r.stdout
    s = json.loads((tmp_path / "all/S000-nofire/summary.json").read_text())
    assert (s["bus_kind"], s["lcm_url"], s["mode"]) == ("lcm", url, "lockstep")
    assert s["verdict"] == "passed" and s["expectations_met"], s["expectation_failures"]
    rows = json.loads((tmp_path / "all/report/report.json").read_text())["rows"]
    assert [(x["scenario"], x["correct"]) for x in rows] == [("S000-nofire", True)]


def test_campaign_sample_over_lcm_agrees_with_in_process(tmp_path):
    """`hil campaign --bus lcm`: a sampled run over LCM detects what the in-process run
    did (the same comparison `--bus` makes over vcan)."""
    text = (REPO / "configs/campaigns/ci-generic.yaml").read_text()
    c = tmp_path / "c.yaml"
    c.write_text(text.replace("runs: 24", "runs: 2") + "bus_sample: 1\n")
    out = tmp_path / "out"
    r = subprocess.run([*HIL, "campaign", str(c), "--workers", "1", "--out", str(out),
                        "--no-progress", "--bus", "lcm"], capture_output=True, text=True,
                       cwd=REPO, timeout=600)
    assert "bus: 1/1 sampled runs agree with the in-process result" in r.stdout, (
        r.stdout + r.stderr)
    [res] = json.loads((out / "bus.json").read_text())
    assert res["agree"] and res["bus_kind"] == "lcm"


def test_real_time_over_lcm_detects_the_fault(url, tmp_path):
    """S000-nofire in real time over LCM: a whole run (no run failure), the fault detected
    and named right, no frame failing its checks. Its false-alarm expectation is judged by
    the reference tier's real-time pass, not here: on a loaded machine a late gyro sample can
    read as a gyro fault whatever the bus (a test never fails because the machine is slow)."""
    r = subprocess.run([*HIL, "run", str(REPO / "configs/scenarios/S000-nofire.yaml"),
                        "--bus", "lcm", "--lcm-url", url, "--mode", "realtime", "--out",
                        str(tmp_path / "rt")], capture_output=True, text=True, cwd=REPO,
                       timeout=600)
    assert r.returncode in (0, 1), r.stdout + r.stderr  # 3 would be a failed run
    s = json.loads((tmp_path / "rt/summary.json").read_text())
    assert s["verdict"] != "run_failed" and s["mode"] == "realtime"
    first = [d for d in s["detections"] if d["thruster"] is not None][0]
    assert (first["thruster"], first["type"], first["correct"]) == ("X+", "fail_to_fire", True)
    for node in ("plant", "flight"):
        assert s["bus"][node]["bad_crc"] == 0 and s["bus"][node]["lcm_malformed"] == 0


def test_fault_from_the_panel_over_lcm(url, tmp_path):
    """`hil up --bus lcm`, then `hil fault inject --bus lcm` from another process: the plant
    accepts it over LCM and the flight detects it."""
    out = tmp_path / "up"
    up = subprocess.Popen([*HIL, "up", "--vehicle", "generic", "--mode", "realtime",
                           "--duration", "60", "--out", str(out), "--bus", "lcm",
                           "--lcm-url", url], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, cwd=REPO)
    try:
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end:
            recs = (out / "plant.jsonl").read_text().splitlines() \
                if (out / "plant.jsonl").exists() else []
            if len(recs) > 10:
                break
            time.sleep(0.2)
        r = subprocess.run([*HIL, "fault", "inject", "--thruster", "X+", "--type",
                            "stuck_on", "--run", str(out), "--bus", "lcm", "--lcm-url", url],
                           capture_output=True, text=True, cwd=REPO, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr
        assert "ok: plant accepted inject stuck_on X+" in r.stdout
        detected = False
        t_end = time.monotonic() + 30
        while time.monotonic() < t_end and not detected:
            text = (out / "flight.jsonl").read_text()
            detected = "detection: stuck_on of X+" in text
            time.sleep(0.3)
        assert detected
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(30)
        except subprocess.TimeoutExpired:
            up.kill()
            up.wait()
