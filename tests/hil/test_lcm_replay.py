"""Records rebuilt from an LCM telemetry log, without a network (hil.lcm_replay): a log
written with LCM's own ``lcm.EventLog`` from hand-made records gives those records back;
the one-line errors of ``hil record`` and ``hil report --from-lcm-log``. The replay through
the real ``lcm-logplayer`` is in tests/integration/test_lcm_bus.py (marker ``lcm``)."""

from __future__ import annotations

import json
from pathlib import Path

import lcm
import pytest

from hil.cli import main as hil_main
from hil.errors import UsageError
from hil.lcm_replay import count_log, paced_speed, read_log
from hil.telemetry import FLIGHT_CHANNEL, TRUTH_CHANNEL, flight_view_message, truth_message

PLANT = [
    {"tick": 0, "t_s": 0.2, "att_err_deg": 22.5, "rate_err_deg_s": 0.0, "fuel_kg": 0.0,
     "dv_B_m_s": [0.0, 0.0, 0.0], "safe": False,
     "series": {"truth/omega_deg_s": {"x": 0.125, "y": -1e-9, "z": 3.0},
                "truth/thrust_n": {"X+": 0.0, "a/b": 1.5}},
     "events": []},
    {"tick": 1, "t_s": 0.4, "att_err_deg": 22.25, "rate_err_deg_s": 0.1, "fuel_kg": 0.002,
     "dv_B_m_s": [0.01, 0.0, -0.02], "safe": True,
     "series": {"truth/omega_deg_s": {"x": 0.5, "y": 0.0, "z": 2.5}},
     "events": ["fault active: stuck_on X+ at 0.40 s", "safe: thr_cmd lost"]},
]
FLIGHT = [
    {"tick": 0, "t_s": 0.0, "detection": None, "compute_s": 0.004, "overruns": 0,
     "safe": False, "series": {"flight/rho_on": {"X+": -0.5}}, "events": []},
    {"tick": 1, "t_s": 0.2, "detection": {"t_s": 0.2, "tick": 1, "thruster": ["X+", "X-"],
                                          "type": "stuck_on", "source": "residual",
                                          "rho": 3.25},
     "compute_s": 0.005, "overruns": 1, "safe": False,
     "series": {"flight/rho_on": {"X+": -0.25}}, "events": ["detection: stuck_on of X+"]},
    {"tick": 2, "t_s": 0.4, "detection": {"t_s": 0.4, "tick": 2, "thruster": None,
                                          "type": "gyro_fault", "source": "gyro_check",
                                          "rho": 0.0},
     "overruns": 1, "safe": True, "series": {}, "events": []},
]


def _write_log(path: Path, extra: list[tuple[str, bytes]] = ()) -> Path:
    log = lcm.EventLog(str(path), "w", overwrite=True)
    t = 1_000_000
    for p, f in zip(PLANT, FLIGHT, strict=False):
        log.write_event(t, TRUTH_CHANNEL, truth_message(p).encode())
        log.write_event(t + 10, FLIGHT_CHANNEL, flight_view_message(f).encode())
        t += 200_000
    log.write_event(t, FLIGHT_CHANNEL, flight_view_message(FLIGHT[2]).encode())
    for ch, data in extra:
        log.write_event(t, ch, data)
    log.close()
    return path


def test_a_log_gives_its_records_back(tmp_path):
    recs = read_log(_write_log(tmp_path / "run.lcmlog", [("HIL_RUN_END", b"")]))
    assert recs.plant == PLANT
    assert recs.flight == FLIGHT
    counts = count_log(tmp_path / "run.lcmlog")
    assert (counts[TRUTH_CHANNEL], counts[FLIGHT_CHANNEL]) == (2, 3)
    assert counts["span_s"] == pytest.approx(0.4)
    assert paced_speed(counts) == pytest.approx(0.4 * 300 / 5)


def test_a_compute_time_not_measured_is_left_out(tmp_path):
    (tmp_path / "a").mkdir()
    recs = read_log(_write_log(tmp_path / "a/run.lcmlog"))
    assert "compute_s" not in recs.flight[2] and recs.flight[0]["compute_s"] == 0.004


def test_record_errors_are_one_line(tmp_path, capsys):
    assert hil_main(["record", "--from-lcm-log", str(tmp_path / "none.lcmlog")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"error: {tmp_path / 'none.lcmlog'}: expected an LCM log (hil run --lcm-log writes "
        "RUN/run.lcmlog), got no such file")
    empty = tmp_path / "empty.lcmlog"
    log = lcm.EventLog(str(empty), "w", overwrite=True)
    log.write_event(0, "HIL_SYNC", b"\x00")
    log.close()
    assert hil_main(["record", "--from-lcm-log", str(empty)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"error: {empty}: expected HIL_TRUTH / HIL_FLIGHT_VIEW telemetry (hil run --lcm-log), "
        "got none in the log")
    good = _write_log(tmp_path / "run.lcmlog")
    assert hil_main(["record", "--from-lcm-log", str(good), "--out", str(tmp_path)]) == 2
    assert "expected a folder other than the log's run folder" in capsys.readouterr().err
    assert hil_main(["record", "--from-lcm-log", str(good), "--speed", "0"]) == 2
    assert "--speed: expected a finite number > 0 and <= 10000, got '0'" in \
        capsys.readouterr().err


def test_report_options_of_the_log_need_it(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"scenario": "x"}))
    assert hil_main(["report", str(run), "--out", str(tmp_path / "r"), "--speed", "2"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: report: --speed: expected it with --from-lcm-log, got 2.0 without it")
    assert hil_main(["report", str(run), "--out", str(tmp_path / "r"), "--from-lcm-log",
                     "--no-plots"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: report: --from-lcm-log: expected it with the plots (the log's data feeds only "
        "them; the table is summary.json's), got --no-plots")
    assert hil_main(["report", str(run), "--out", str(tmp_path / "r"), "--from-lcm-log"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"error: {run / 'run.lcmlog'}: expected an LCM log (hil run --lcm-log writes "
        "RUN/run.lcmlog), got no such file")


def test_junk_on_a_telemetry_channel_is_an_error_not_a_record(tmp_path):
    path = _write_log(tmp_path / "run.lcmlog", [(TRUTH_CHANNEL, b"not a truth_t")])
    with pytest.raises(UsageError) as exc:
        read_log(path)
    assert str(exc.value) == (f"{path}: expected only telemetry structs on HIL_TRUTH / "
                              "HIL_FLIGHT_VIEW, got 1 other message(s)")
