"""`hil report`: table rows, plots and exit codes from synthetic run folders (no bus, no runs)."""

from __future__ import annotations

import argparse
import json
import struct
from pathlib import Path

import pytest

import hil.cli
from hil.errors import UsageError
from hil.report import register, write_report

H_S = 0.2
N_TICKS = 100          # 20 s
T_FAULT_S = 10.0
T_DETECT_S = 11.2      # tick 56
SEED_LATENCY_S = 3.7   # only in the scenario file: the report must read it from there
NAMES = ("X+", "X-", "Y+", "Y-", "Z+", "Z-")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _xyz(x: float, y: float = 0.0, z: float = 0.0) -> dict[str, float]:
    return {"x": x, "y": y, "z": z}


def _scenario(d: Path, fault: bool) -> Path:
    lines = ["name: T-stuck", "vehicle: generic", "duration_s: 20.0"]
    if fault:
        lines += ["faults:", f"  - {{kind: stuck_on, thruster: X+, t_s: {T_FAULT_S}}}",
                  "expect:", "  detections:",
                  f"    - {{thruster: X+, type: stuck_on, within_s: {SEED_LATENCY_S}, "
                  f"seed_latency_s: {SEED_LATENCY_S}}}"]
    path = d / "T-stuck.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def make_run(tmp: Path, name: str = "run", *, fault: bool = True, correct: bool = True,
             met: bool = True, scenario_file: bool = True) -> Path:
    """A run folder as `hil run` writes it: X+ stuck on at 10 s, detected at 11.2 s."""
    d = tmp / name
    d.mkdir(parents=True)
    plant, flight = [], []
    w = a = 0.0
    rho_off = 0.0
    for n in range(N_TICKS):
        t_end = (n + 1) * H_S
        stuck = fault and t_end > T_FAULT_S
        w += 0.02 if stuck else (-0.01 if n % 10 < 5 else 0.01)
        a += w * H_S
        plant.append({"tick": n, "t_s": round(t_end, 6), "series": {
            "truth/omega_deg_s": _xyz(w), "truth/attitude_error_deg": _xyz(a),
            "truth/thrust_n": {k: 10.0 if (k == "X+" and stuck) else 0.0 for k in NAMES}},
            "events": [], "faults_injected": [], "att_err_deg": abs(a), "rate_err_deg_s": abs(w)})
        t = round(n * H_S, 6)
        rho_off = 0.8 * rho_off + (1.0 if fault and t > T_FAULT_S else 0.0)
        det = None
        if fault and abs(t - T_DETECT_S) < 1e-9:
            det = {"t_s": t, "tick": n, "thruster": "X+" if correct else "X-",
                   "type": "stuck_on", "source": "residual", "rho": rho_off}
        flight.append({"tick": n, "t_s": t, "series": {
            "flight/omega_meas_deg_s": _xyz(w + 0.001),
            "flight/rho_on": {k: (-0.5 * rho_off if k == "X-" else 0.0) for k in NAMES},
            "flight/rho_off": {k: (rho_off if k == "X+" else 0.01 * (n % 3)) for k in NAMES},
            "flight/thresholds": {"off": 2.5, "on": -2.5},
            "flight/on_ms": {k: (200.0 if k == "X-" and n % 4 == 0 else
                                 30.0 if k == "Y+" and n % 7 == 0 else 0.0) for k in NAMES}},
            "events": [], "detection": det})
    plant.append({**plant[-1], "final": True})
    (d / "plant.jsonl").write_text("".join(json.dumps(r) + "\n" for r in plant))
    (d / "flight.jsonl").write_text("".join(json.dumps(r) + "\n" for r in flight))
    faults = [{"t_s": T_FAULT_S, "thruster": "X+", "type": "stuck_on", "fraction": 1.0}]
    det = {"t_s": T_DETECT_S, "tick": 56, "thruster": "X+" if correct else "X-",
           "type": "stuck_on", "source": "residual", "rho": 2.6,
           "latency_s": round(T_DETECT_S - T_FAULT_S, 6) if correct else None,
           "correct": correct}
    summary = {
        "scenario": "T-stuck", "vehicle": "generic", "mode": "lockstep",
        "faults": faults if fault else [],
        "detections": [det] if fault else [],
        "false_alarms": [] if correct or not fault else [det],
        "missed_faults": [] if correct or not fault else faults,
        "max_attitude_error_deg": 1.25, "max_rate_error_deg_s": 0.4, "fuel_kg": 0.01,
        "ticks": N_TICKS, "flight_ticks": N_TICKS, "overruns": 0, "run_failures": [],
        "verdict": "passed" if met else "not_met",
        "compute_ms": {"p50": 1.0, "p99": 2.0, "max": 3.0},
        "sim_s": 20.0, "wall_s": 2.0, "where": "native",
        "expectations_met": met,
        "expectation_failures": [] if met else ["detection of X+ stuck_on within 3.7 s: ..."],
    }
    if scenario_file:
        summary["scenario_path"] = str(_scenario(d, fault))
    (d / "summary.json").write_text(json.dumps(summary, indent=2))
    return d


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path.name} is not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="hil")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


# ------------------------------------------------------------------------------- table


def test_row_has_latency_correct_flag_and_seed_latency_from_scenario(tmp_path: Path) -> None:
    res = write_report([make_run(tmp_path)], tmp_path / "rep", plots=False)
    (row,) = res.rows
    assert row["scenario"] == "T-stuck" and row["fault"] == "stuck_on X+ 100 %"
    assert row["fault_t_s"] == T_FAULT_S and row["detection_t_s"] == T_DETECT_S
    assert row["latency_s"] == pytest.approx(T_DETECT_S - T_FAULT_S)
    assert row["seed_latency_s"] == SEED_LATENCY_S
    assert (row["detected_thruster"], row["detected_type"], row["correct"]) == (
        "X+", "stuck_on", True)
    assert row["false_alarms"] == 0 and row["expectations_met"] is True
    assert res.exit_code == 0
    assert json.loads(res.json.read_text())["rows"] == json.loads(json.dumps(res.rows))
    md = res.markdown.read_text()
    assert "| T-stuck | generic | stuck_on X+ 100 % | 10.0 | stuck_on X+ | 11.2 | 1.2 | 3.7 " \
           "| yes | 0 | 1.25 | met |" in md
    assert "faster than the seed's 3.7 s" in md


def test_wrong_thruster_is_not_correct_and_counts_as_false_alarm(tmp_path: Path) -> None:
    d = make_run(tmp_path, correct=False, met=False)
    res = write_report([d], tmp_path / "rep", plots=False)
    (row,) = res.rows
    assert row["detected_thruster"] == "X-" and row["correct"] is False and row["missed"]
    assert row["false_alarms"] == 1
    assert "**NO** (fault missed)" in res.markdown.read_text()


def test_seed_latency_from_summary_expect_block_when_no_scenario_file(tmp_path: Path) -> None:
    d = make_run(tmp_path, scenario_file=False)
    s = json.loads((d / "summary.json").read_text())
    s["expect"] = {"detections": [{"thruster": "X+", "type": "stuck_on", "within_s": 9.0,
                                   "seed_latency_s": 4.6}]}
    (d / "summary.json").write_text(json.dumps(s))
    res = write_report([d], tmp_path / "rep", plots=False)
    assert res.rows[0]["seed_latency_s"] == 4.6


def test_no_fault_run_has_one_row_and_all_plots(tmp_path: Path) -> None:
    res = write_report([make_run(tmp_path, fault=False)], tmp_path / "rep")
    (row,) = res.rows
    assert row["fault"] is None and row["latency_s"] is None and row["correct"] is None
    assert "| T-stuck | generic | no fault |" in res.markdown.read_text()
    assert sorted(p.name for p in res.plots["T-stuck"]) == [
        f"T-stuck_{k}.png" for k in ("firing", "phase", "rates", "residuals")]
    for p in res.plots["T-stuck"]:
        _png_size(p)


# ------------------------------------------------------------------------------- plots


def test_pngs_exist_are_valid_and_linked(tmp_path: Path) -> None:
    res = write_report([make_run(tmp_path)], tmp_path / "rep")
    md = res.markdown.read_text()
    for kind in ("rates", "phase", "residuals", "firing"):
        p = tmp_path / "rep" / f"T-stuck_{kind}.png"
        w, h = _png_size(p)
        assert 700 <= w <= 1000 and 300 <= h <= 800, (kind, w, h)  # ~9 x 4 in at 100 dpi
        assert f"]({p.name})" in md
    assert "note:" not in md  # scenario and vehicle found, nothing failed to plot


def test_same_scenario_twice_gets_separate_plots(tmp_path: Path) -> None:
    a, b = make_run(tmp_path / "a"), make_run(tmp_path / "b")
    res = write_report([a, b], tmp_path / "rep", plots=False)
    assert list(res.plots) == ["T-stuck", "T-stuck-run"]  # PNG name prefixes


def test_folder_of_runs_expands_and_skips_the_report_folder(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    make_run(runs, "one")
    make_run(runs, "two", fault=False)
    res = write_report([runs], runs / "report", plots=False)
    assert [r["run_dir"] for r in res.rows] == [str(runs / "one"), str(runs / "two")]
    # `hil report runs/*` once more: runs/report is among the arguments now.
    res = write_report([*runs.iterdir()], runs / "report", plots=False)
    assert len(res.rows) == 2


# ------------------------------------------------------------------------------- exit codes


def test_exit_1_when_a_run_did_not_meet_expectations(tmp_path: Path, capsys) -> None:
    good = make_run(tmp_path, "good")
    bad = make_run(tmp_path, "bad", met=False)
    assert _cli(["report", str(good), "--out", str(tmp_path / "r1"), "--no-plots"]) == 0
    assert _cli(["report", str(good), str(bad), "--out", str(tmp_path / "r2"),
                 "--no-plots"]) == 1
    out = capsys.readouterr().out
    assert "NOT passed: T-stuck" in out
    assert "**1 of 2 run(s) did NOT pass**" in (tmp_path / "r2" / "report.md").read_text()


def test_a_malformed_summary_fails_the_report(tmp_path: Path, capsys) -> None:
    """Issue 17: a summary holding only the scenario's name is not "all expectations met"."""
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "summary.json").write_text('{"scenario": "x"}')
    assert _cli(["report", str(bare), "--out", str(tmp_path / "r"), "--no-plots"]) == 3
    md = (tmp_path / "r" / "report.md").read_text()
    assert "**RUN FAILED**" in md
    assert "summary: verdict: expected a field, got nothing" in md
    assert "NOT passed: x" in capsys.readouterr().out


def test_a_failed_run_fails_the_report_with_exit_3(tmp_path: Path) -> None:
    dead = make_run(tmp_path, "dead")
    s = json.loads((dead / "summary.json").read_text())
    s.update(run_failures=["flight process died (exit code 1); see flight.log"],
             verdict="run_failed", expectations_met=False)
    (dead / "summary.json").write_text(json.dumps(s))
    assert _cli(["report", str(dead), "--out", str(tmp_path / "r"), "--no-plots"]) == 3
    assert "flight process died (exit code 1)" in (tmp_path / "r" / "report.md").read_text()
    # A summary that says "passed" while it lists a run failure contradicts itself.
    s.update(verdict="passed", expectations_met=True)
    (dead / "summary.json").write_text(json.dumps(s))
    assert _cli(["report", str(dead), "--out", str(tmp_path / "r2"), "--no-plots"]) == 3


def test_missing_run_folder_is_a_usage_error(tmp_path: Path) -> None:
    missing = tmp_path / "nope"
    with pytest.raises(UsageError) as info:
        _cli(["report", str(missing), "--out", str(tmp_path / "rep")])
    assert str(info.value) == (f"report: {missing}: expected a run folder (hil run --out), "
                               f"got no such folder")
    assert not (tmp_path / "rep").exists()  # nothing written


def test_broken_summary_is_a_usage_error(tmp_path: Path) -> None:
    d = make_run(tmp_path)
    (d / "summary.json").write_text('{"scenario": "T-stuck",')
    with pytest.raises(UsageError, match=r"summary.json: expected JSON, got invalid JSON at "
                                         r"line 1 column \d+"):
        write_report([d], tmp_path / "rep")
    (d / "summary.json").unlink()
    with pytest.raises(UsageError, match="summary.json: expected the run's summary, got no such"):
        write_report([d], tmp_path / "rep")


def test_cli_exit_2_with_one_error_line(tmp_path: Path, monkeypatch, capsys) -> None:
    if "hil.report" not in hil.cli.COMMAND_MODULES:
        monkeypatch.setattr(hil.cli, "COMMAND_MODULES", (*hil.cli.COMMAND_MODULES, "hil.report"))
    rc = hil.cli.main(["report", str(tmp_path / "nope"), "--out", str(tmp_path / "rep")])
    assert rc == 2
    err = capsys.readouterr().err
    assert err == (f"error: report: {tmp_path / 'nope'}: expected a run folder "
                   f"(hil run --out), got no such folder\n")


def test_torn_or_missing_recordings_cost_plots_not_the_report(tmp_path: Path) -> None:
    d = make_run(tmp_path)
    with (d / "flight.jsonl").open("a") as f:
        f.write('{"tick": 100, "t_s": 20.0, "ser')  # killed mid-line
    (d / "plant.jsonl").unlink()
    res = write_report([d], tmp_path / "rep")
    assert res.rows[0]["latency_s"] == pytest.approx(1.2)
    names = {p.name for p in res.plots["T-stuck"]}
    assert {"T-stuck_residuals.png", "T-stuck_firing.png"} <= names
    assert "T-stuck_phase.png" not in names
    assert "note: plant.jsonl missing or empty" in res.markdown.read_text()


def test_group_detection_and_unknown_vehicle_still_report(tmp_path: Path) -> None:
    d = make_run(tmp_path, scenario_file=False)
    s = json.loads((d / "summary.json").read_text())
    s["vehicle"] = "not-a-vehicle"  # no config: channel from the rates, no dead-zone band
    s["detections"][0]["thruster"] = ["X+", "X-"]
    (d / "summary.json").write_text(json.dumps(s))
    res = write_report([d], tmp_path / "rep")
    assert res.rows[0]["correct"] is True and res.rows[0]["seed_latency_s"] is None
    md = res.markdown.read_text()
    assert "| stuck_on one of {X+, X-} | 11.2 | 1.2 | - | yes |" in md
    assert len(res.plots["T-stuck"]) == 4 and "plot failed" not in md


def test_gyro_fault_only_is_named_but_not_judged_as_a_thruster_fault(tmp_path: Path) -> None:
    d = make_run(tmp_path, fault=False)
    s = json.loads((d / "summary.json").read_text())
    s["faults"] = [{"t_s": 5.0, "thruster": None, "type": "gyro_spike", "fraction": 1.0}]
    (d / "summary.json").write_text(json.dumps(s))
    res = write_report([d], tmp_path / "rep", plots=False)
    (row,) = res.rows
    assert (row["fault"], row["fault_t_s"], row["thruster_fault"]) == ("gyro_spike", 5.0, False)
    assert "| T-stuck | generic | gyro_spike | 5.0 | - | - | - | - | - | 0 |" in (
        res.markdown.read_text())
