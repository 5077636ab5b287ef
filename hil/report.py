"""`hil report`: a one-minute report from run folders (Markdown table and PNG plots).

``hil report DIR... [--out REPORT_DIR]`` reads each run folder written by ``hil run``
(``summary.json``, ``plant.jsonl``, ``flight.jsonl``; see ``hil.recorder``) and writes
``REPORT_DIR/report.md``, ``REPORT_DIR/report.json`` (the table rows) and, per scenario, PNGs
named ``<scenario>_<plot>.png``. A DIR without ``summary.json`` whose sub-folders have one stands
for those sub-folders (``hil report runs``). Exit 0 when every run met its expectations, 1 when
one did not, 2 when a folder is missing or its summary unreadable. ``write_report`` does the same
from code (``hil run-all``).

How to read it
--------------
The table has one row per injected thruster fault (one row for a run without one: "no fault",
or its gyro/bus faults, which name no thruster):
fault time, the detection that answered it (time, thruster and type named), latency = detection
time minus fault time, the seed's latency (the scenario's
``expect.detections[].seed_latency_s``, "-" where the seed gives no figure; the verdict uses
``within_s``), whether the named thruster and type are right (a group "one of {i, j}" counts
when it holds the faulted thruster, docs/design.md 6.4), false alarms, the largest attitude error
and the verdict of the run's expectations (failures listed under the table). A fault answered
only by a wrong detection shows that detection with correct = NO; none at all shows
MISSED.

Per scenario, in every plot: a red vertical line marks a fault, green a correct detection, dark
orange (dash-dot) a false alarm; a grey band on a full-run panel marks the zoomed window. The
"faulted channel" is the body axis on which the faulted thruster's angular acceleration
``mu = J^-1 (r x F)`` is largest (``VehicleArrays.mu_B_rad_s2``).

* ``_rates``: the faulted channel's true rate (plant, relative to the orbit frame) and measured
  rate (gyro, one dot per tick; inertial, so on vehicles in orbit the two differ by the orbit
  rate; seed 002's integrating gyro gives the mean rate over the tick, not the rate at its end)
  against time; a zoom panel around the fault on long runs (seed 002's 700 s faults). Mirrors
  seed 000 figs. 9 and 13 (omega_x, fault red, detection green), seed 002 figs. 2-3. Without a
  fault: true rates and attitude errors of all three axes, with the controller's rate dead zone.
* ``_phase``: attitude error (abscissa, deg) against rate error (ordinate, deg/s) of the faulted
  channel, states after the fault in red (seed 000 figs. 7, 8 and 12; seed 004 fig. 2), with the
  controller's dead-zone band (half-width ``rate_deadband_deg_s``, 0.12 deg/s, about its
  switching line; drawn below the Euler-turn angle only) and the fault and detection states
  marked. The right panel zooms on the states from 5 s before the fault to 5 s after detection.
  Without a fault: one panel per channel.
* ``_residuals``: integral residuals around the fault, ``rho_off`` (stuck on; crosses ``+thr``)
  above, ``rho_on`` (fails to fire; crosses ``-thr``) below, with the thresholds dashed: the
  faulted thruster, the thruster the detection named, and the others that came closest to their
  thresholds; a star where the detection was raised. Mirrors seed 000 figs. 10, 11 and 14 and
  seed 003 figs. 5b and 6b. Where the vehicle's FDIR responds to a detection, it rebaselines the
  detector and the residuals drop to zero.
* ``_firing``: commanded on-time per thruster and tick (THR_CMD) in 10 ms quanta, 20 = the whole
  200 ms tick, around the fault (the whole run without a fault); on vehicles with more than 8
  thrusters only those commanded in the window, plus the faulted one. The faulted thruster's name
  is red and its row hatched red from the fault on: the chart is the command, not the thrust (a
  stuck-on thruster burns whatever it says). Mirrors seed 004 figs. 6, 9 and 12.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from hil.argtypes import number
from hil.errors import UsageError
from hil.report_figures import PLOTS, fmt_num, fmt_s
from hil.report_load import (
    Run,
    answer_to,
    expand_run_dirs,
    fault_text,
    load_run,
    read_summary,
    seed_latency,
    thruster_text,
)
from hil.verdict import EXIT_RUN_FAILED, judge_summary

# =============================================================================== table


def table_rows(run: Run) -> list[dict[str, Any]]:
    """The report's rows for one run (``report.json``), one per thruster fault or 'no fault'."""
    s = run.summary
    common = {
        "scenario": run.name,
        "vehicle": s.get("vehicle"),
        "false_alarms": len(s.get("false_alarms") or []),
        "max_attitude_error_deg": s.get("max_attitude_error_deg"),
        "max_rate_error_deg_s": s.get("max_rate_error_deg_s"),
        "expectations_met": s.get("expectations_met"),
        "expectation_failures": list(s.get("expectation_failures") or []),
        "verdict": judge_summary(s)[0],
        "verdict_reasons": judge_summary(s)[1],
        "run_dir": str(run.path),
    }
    faults = run.thruster_faults
    if not faults:  # fault-free, or only gyro / bus faults (no thruster to name)
        other = [f for f in s.get("faults") or [] if f.get("t_s") is not None]
        return [{**common, "thruster_fault": False,
                 "fault": ", ".join(fault_text(f) for f in other) or None,
                 "fault_t_s": float(other[0]["t_s"]) if other else None,
                 "detected_thruster": None, "detected_type": None, "detection_t_s": None,
                 "latency_s": None, "seed_latency_s": None, "correct": None}]
    rows = []
    for f in faults:
        d = answer_to(run, f)
        t_f = float(f["t_s"])
        rows.append({
            **common,
            "thruster_fault": True,
            "fault": fault_text(f),
            "fault_thruster": f["thruster"],
            "fault_type": f.get("type"),
            "fault_t_s": t_f,
            "detected_thruster": d.get("thruster") if d else None,
            "detected_type": d.get("type") if d else None,
            "detection_source": d.get("source") if d else None,
            "detection_t_s": float(d["t_s"]) if d else None,
            "latency_s": round(float(d["t_s"]) - t_f, 6) if d else None,
            "seed_latency_s": seed_latency(run, f),
            "correct": bool(d.get("correct")) if d else False,
            "missed": not (d is not None and d.get("correct")),  # no correct detection
        })
    return rows


# =============================================================================== report


@dataclass(frozen=True)
class ReportResult:
    """What ``write_report`` wrote. ``exit_code``: 0 every run passed, 1 some expectations
    not met, 3 some run failed or its summary is incomplete (``hil.verdict``)."""

    out_dir: Path
    markdown: Path
    json: Path
    rows: list[dict[str, Any]]
    plots: dict[str, list[Path]]
    failed: list[str]
    run_failed: list[str] = field(default_factory=list)

    @property
    def all_met(self) -> bool:
        return not self.failed

    @property
    def exit_code(self) -> int:
        if self.run_failed:
            return EXIT_RUN_FAILED
        return 0 if self.all_met else 1


def _slug(name: str, run_dir: Path, used: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9._+-]+", "_", name) or "run"
    slug = base
    if slug in used:
        slug = f"{base}-{re.sub(r'[^A-Za-z0-9._+-]+', '_', run_dir.name)}"
    k = 2
    while slug in used:
        slug, k = f"{base}-{k}", k + 1
    used.add(slug)
    return slug


def _verdict(verdict: str) -> str:
    return {"passed": "met", "not_met": "**NOT met**"}.get(verdict, "**RUN FAILED**")


def _correct(row: dict[str, Any]) -> str:
    if not row.get("thruster_fault"):
        return "-"
    if row["detection_t_s"] is None:
        return "**MISSED**"
    if row["correct"]:
        return "yes"
    return "**NO** (fault missed)"


def _markdown(runs: list[Run], rows: list[dict[str, Any]], plots: dict[str, list[Path]],
              failed: list[str]) -> str:
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    verdict = ("all expectations met" if not failed
               else f"**{len(failed)} of {len(runs)} run(s) did NOT pass** (expectations not "
                    "met, or the run itself failed): " + ", ".join(failed))
    out = [
        "# Thruster HIL report", "",
        f"{len(runs)} run(s), written {when}. Verdict: {verdict}.", "",
        "| scenario | vehicle | fault | fault at [s] | detected as | detected at [s] "
        "| latency [s] | seed latency [s] | correct | false alarms | max att. error [deg] "
        "| verdict |",
        "|---|---|---|--:|---|--:|--:|--:|---|--:|--:|---|",
    ]
    for r in rows:
        if not r.get("thruster_fault"):
            det = "-"
        elif r["detection_t_s"] is None:
            det = "none"
        else:
            det = f"{r['detected_type']} {thruster_text(r['detected_thruster'])}"
        out.append(
            f"| {r['scenario']} | {r['vehicle'] or '-'} | {r['fault'] or 'no fault'} "
            f"| {fmt_s(r['fault_t_s'])} | {det} | {fmt_s(r['detection_t_s'])} "
            f"| {fmt_s(r['latency_s'])} "
            f"| {fmt_s(r['seed_latency_s'])} | {_correct(r)} | {r['false_alarms']} "
            f"| {fmt_num(r['max_attitude_error_deg'])} | {_verdict(r['verdict'])} |")
    out += [
        "",
        "Latency = detection time - fault time. Seed latency = the seed's own figure "
        "(`expect.detections[].seed_latency_s`; - where the seed gives none; the run is judged "
        "against `within_s`). "
        "Correct = the named thruster (or group \"one of {...}\") and type match the injected "
        "fault. Max attitude error is over the judged part of the run (after "
        "`expect.settle_after_s`).", "",
        "Plots: red line = fault, green = correct detection, orange dash-dot = false alarm; "
        "the faulted channel is the body axis of the faulted thruster's largest torque.", "",
    ]
    fails = [(run, f) for run in runs for f in run.summary.get("expectation_failures") or []]
    if fails:
        out += ["## Expectations not met", ""]
        out += [f"- {run.name}: {f}" for run, f in fails]
        out.append("")
    for run in runs:
        out += _run_section(run, plots.get(run.slug, []))
    return "\n".join(out) + "\n"


def _run_section(run: Run, pngs: list[Path]) -> list[str]:
    s = run.summary
    desc = run.scenario.cfg.description if run.scenario is not None else ""
    out = [f"## {run.name}", ""]
    if desc:
        out += [desc, ""]
    cm = s.get("compute_ms") or {}
    out.append(
        f"- run: `{run.path}`, vehicle {s.get('vehicle', '-')}, {s.get('mode', '-')}, "
        f"{fmt_s(s.get('sim_s'))} s simulated in {fmt_s(s.get('wall_s'))} s wall "
        f"({s.get('where', '-')}), {s.get('ticks', '-')} ticks")
    for f in s.get("faults") or []:
        out.append(f"- fault: {fault_text(f)} at {fmt_s(f.get('t_s'))} s")
    if not s.get("faults"):
        out.append("- fault: none injected")
    for d in run.detections:
        lat = f", latency {fmt_s(d.get('latency_s'))} s" if d.get("latency_s") is not None else ""
        rho = f", ρ = {d['rho']:.2f}" if isinstance(d.get("rho"), int | float) else ""
        out.append(f"- {'detection' if d.get('correct') else '**false alarm**'}: "
                   f"{d.get('type')} {thruster_text(d.get('thruster'))} at {fmt_s(d.get('t_s'))} s "
                   f"({d.get('source', '-')}{rho}){lat}")
    for f in s.get("missed_faults") or []:
        out.append(f"- **missed**: {fault_text(f)} at {fmt_s(f.get('t_s'))} s")
    if not run.detections:
        out.append("- detections: none")
    for a in s.get("fdir_actions") or []:
        what = (f"manifold {a['manifold']}" if "manifold" in a
                else f"thruster {thruster_text(a.get('thruster'))}")
        out.append(f"- FDIR response: {what} {str(a.get('action', '')).split('_', 1)[-1]} at "
                   f"{fmt_s(a.get('t_s'))} s")
    if s.get("interrupted"):
        out.append(f"- interrupted: {s.get('interrupted_by') or 'yes'}, after "
                   f"{s.get('ticks', '-')} ticks")
    dv = s.get("delta_v_B_m_s")
    if isinstance(dv, list) and len(dv) == 3 and any(abs(float(x)) > 0 for x in dv):
        want = (run.scenario.cfg.expect.delta_v_B_m_s if run.scenario is not None
                and run.scenario.cfg.expect is not None else None)
        out.append(f"- delta-v (body) [{', '.join(f'{float(x):.3f}' for x in dv)}] m/s"
                   + (f", expected [{', '.join(f'{float(x):g}' for x in want)}] m/s"
                      if want is not None else ""))
    for f in run.thruster_faults:
        seed = seed_latency(run, f)
        d = answer_to(run, f)
        if seed is not None and d is not None and d.get("correct"):
            lat = float(d["t_s"]) - float(f["t_s"])
            cmp = "faster than" if lat < seed - 1e-9 else (
                "as fast as" if lat <= seed + 1e-9 else "**slower** than")
            out.append(f"- {f['thruster']}: latency {fmt_s(lat)} s, {cmp} the seed's "
                       f"{fmt_s(seed)} s")
    out.append(
        f"- max attitude error {fmt_num(s.get('max_attitude_error_deg'))} deg, max rate error "
        f"{fmt_num(s.get('max_rate_error_deg_s'), '.3f')} deg/s, fuel "
        f"{fmt_num(s.get('fuel_kg'), '.3f')} kg; flight compute p50/p99/max "
        f"{fmt_num(cm.get('p50'), '.1f')}/{fmt_num(cm.get('p99'), '.1f')}/"
        f"{fmt_num(cm.get('max'), '.1f')}"
        f" ms, overruns {s.get('overruns', '-')}; safe events {len(s.get('safe_events') or [])}")
    verdict, reasons = judge_summary(s)
    out.append(f"- verdict: {_verdict(verdict)}" if verdict == "run_failed"
               else f"- verdict: expectations {_verdict(verdict)}")
    for f in reasons:
        out.append(f"  - {f}")
    for note in run.notes:
        out.append(f"- note: {note}")
    out.append("")
    captions = {kind: text for kind, _, text in PLOTS}
    for p in pngs:
        kind = p.stem.rsplit("_", 1)[-1]
        out += [f"![{run.name}: {captions.get(kind, kind)}]({p.name})", ""]
    return out


def write_report(run_dirs: list[Path], out_dir: Path, *, plots: bool = True,
                 progress: Callable[[str], None] | None = None,
                 records_of: Callable[[Path], Any] | None = None) -> ReportResult:
    """Read every run folder (all checked first), write plots, ``report.md`` and ``report.json``.

    Raises ``UsageError`` (one line) for a missing folder or an unreadable summary before
    anything is written. Missing per-tick files only cost plots (a note says so).
    ``plots=False`` writes the table alone (fast). ``progress`` gets one line per run.
    ``records_of(run_dir)``: the per-tick records of a run from elsewhere than its JSON lines
    (``hil report --from-lcm-log``: its LCM log replayed, ``hil.lcm_replay``).
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"report: --out {out_dir}: expected a folder, got a file")
    dirs = expand_run_dirs([Path(d) for d in run_dirs], skip=out_dir)
    if not dirs:
        raise UsageError("report: DIR: expected at least one run folder, got none")
    for d in dirs:
        read_summary(d)  # fail fast, before the slow part
        if records_of is not None:
            from hil.lcm_replay import LOG_NAME, count_log

            count_log(d / LOG_NAME)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs: list[Run] = []
    used: set[str] = set()
    rows: list[dict[str, Any]] = []
    pngs_of: dict[str, list[Path]] = {}
    for d in dirs:
        t0 = time.monotonic()
        run = load_run(d, records_of(d) if records_of is not None else None)
        run.slug = _slug(run.name, run.path, used)
        runs.append(run)
        rows.extend(table_rows(run))
        pngs = []
        for kind, fn, _ in PLOTS if plots else ():
            try:
                p = fn(run, out_dir / f"{run.slug}_{kind}.png")
            except Exception as exc:  # noqa: BLE001 - one bad plot must not lose the report
                run.notes.append(f"{kind} plot failed: {type(exc).__name__}: {exc}")
                p = None
            if p is not None:
                pngs.append(p)
        pngs_of[run.slug] = pngs
        if progress:
            progress(f"  {run.name}: {len(pngs)} plots ({time.monotonic() - t0:.1f} s)")
    verdicts = {r.name: judge_summary(r.summary)[0] for r in runs}
    failed = [n for n, v in verdicts.items() if v != "passed"]
    md = out_dir / "report.md"
    md.write_text(_markdown(runs, rows, pngs_of, failed), encoding="utf-8")
    js = out_dir / "report.json"
    js.write_text(json.dumps({
        "all_met": not failed,
        "failed": failed,
        "run_failed": [n for n, v in verdicts.items() if v == "run_failed"],
        "rows": rows,
        "plots": {k: [p.name for p in v] for k, v in pngs_of.items()},
    }, indent=2) + "\n", encoding="utf-8")
    return ReportResult(out_dir=out_dir, markdown=md, json=js, rows=rows, plots=pngs_of,
                        failed=failed,
                        run_failed=[n for n, v in verdicts.items() if v == "run_failed"])


def _lcm_log_source(args, out: Path) -> tuple[int | None, Callable[[Path], Any] | None]:
    """``--from-lcm-log``: each run's ``run.lcmlog`` replayed by ``lcm-logplayer`` in a private
    network namespace (``hil.lcm_replay``); (exit code of the re-run there, or None; the
    records source)."""
    if not args.from_lcm_log:
        for flag, val in (("--speed", args.speed), ("--lcm-url", args.lcm_url)):
            if val is not None:
                raise UsageError(f"report: {flag}: expected it with --from-lcm-log, got "
                                 f"{val!r} without it")
        return None, None
    if args.no_plots:
        raise UsageError("report: --from-lcm-log: expected it with the plots (the log's data "
                         "feeds only them; the table is summary.json's), got --no-plots")
    from bus.lcm_transport import DEFAULT_URL
    from hil.lcm_replay import LOG_NAME, count_log, replay
    from hil.netns import run_in_namespace

    url = args.lcm_url or DEFAULT_URL
    speed = args.speed  # None: paced (hil.lcm_replay.paced_speed)
    dirs = expand_run_dirs([Path(d) for d in args.runs], skip=out)
    for d in dirs:
        read_summary(d)
        count_log(d / LOG_NAME)  # one line before the namespace
    argv = ["report", *[str(d.resolve()) for d in dirs], "--out", str(out.resolve()),
            "--from-lcm-log", "--lcm-url", url]
    rc = run_in_namespace(argv + (["--speed", repr(speed)] if speed else []), url)
    return rc, lambda d: replay(d / LOG_NAME, url, speed=speed)


def _cmd(args) -> int:
    out = Path(args.out) if args.out else Path("runs") / "report"
    rc, records_of = _lcm_log_source(args, out)
    if rc is not None:
        return rc
    result = write_report([Path(d) for d in args.runs], out, plots=not args.no_plots,
                          progress=print, records_of=records_of)
    n = len(result.plots)
    if result.all_met:
        print(f"report: {result.markdown} ({n} run(s), all expectations met)")
    else:
        print(f"report: {result.markdown} ({n} run(s); NOT passed: "
              f"{', '.join(result.failed)})")
    return result.exit_code


def register(sub) -> None:
    p = sub.add_parser("report", help="Markdown + PNG report from run folders (exit 0/1/2/3)",
                       description="Write report.md, report.json and PNG plots (rates, phase "
                                   "plane, residuals, firing chart) from hil run folders.")
    p.add_argument("runs", nargs="+", metavar="DIR",
                   help="run folder (hil run --out), or a folder of run folders")
    p.add_argument("--out", metavar="REPORT_DIR",
                   help="report folder (default runs/report)")
    p.add_argument("--no-plots", action="store_true", help="table only (fast)")
    p.add_argument("--from-lcm-log", action="store_true",
                   help="per-tick data from each run's run.lcmlog (hil run --lcm-log), played "
                        "by lcm-logplayer in a private network namespace, instead of its JSON "
                        "lines (the table still comes from summary.json)")
    p.add_argument("--speed", type=number(gt=0, le=10000), metavar="X",
                   help="with --from-lcm-log: lcm-logplayer's speed multiplier (default: paced "
                        "to about 300 messages per second)")
    p.add_argument("--lcm-url", metavar="URL",
                   help="with --from-lcm-log: the LCM provider to play on")
    p.set_defaults(func=_cmd)
