"""``hil campaign``: Monte Carlo campaigns (docs/design.md section 11).

Usage:

    hil campaign FILE [--workers N | --scheduler tcp://HOST:8786] [--out DIR] [--bus [can|lcm]]
    hil campaign expand FILE --run K[,K...] [--out DIR]
    hil campaign sweep FILE [FILE ...] [--thresholds T,T,...] [--forgetting W,W,...]
                       [--workers N | --scheduler ADDRESS] [--out DIR]
    hil campaign report DIR

Exit codes: 0 every run has a row and none failed (and, with ``--bus``, the bus agreed);
1 some runs failed (error, incomplete summary) or the bus disagreed; 2 a usage or
configuration error; 130 interrupted (the finished runs are kept: the same command resumes).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from hil.campaign.file import Bare, CampaignError
from hil.campaign.load import load_campaign

ACTIONS = ("expand", "sweep", "report")
# Which options each action takes (an option given to an action that does not use it is an
# error, never ignored).
OPTIONS = {
    "run": {"workers", "scheduler", "out", "bus", "no_progress"},
    "expand": {"run", "out"},
    "sweep": {"workers", "scheduler", "out", "thresholds", "forgetting", "no_progress"},
    "report": set(),
}
_FLAGS = {"workers": "--workers", "scheduler": "--scheduler", "out": "--out", "bus": "--bus",
          "no_progress": "--no-progress", "run": "--run", "thresholds": "--thresholds",
          "forgetting": "--forgetting"}


def _floats(text: str, opt: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CampaignError("hil campaign", opt, "numbers separated by commas", text) from None
    if not vals:
        raise CampaignError("hil campaign", opt, "at least one number", text)
    return vals


def _default_out(name: str, sub: str = "") -> Path:
    return Path("runs") / "campaigns" / (name + sub)


def _finish_report(c, out: Path) -> dict[str, Any]:
    from hil.campaign.engine import read_rows
    from hil.campaign.report import write_report

    rows = read_rows(out / "runs.jsonl")
    rows = [r for r in rows if r["run"] < c.runs]
    return write_report(rows, out, campaign=c.name, campaign_file=str(c.path),
                        runs_planned=c.runs, fingerprint=c.fingerprint())


def _print_summary(doc: dict[str, Any]) -> None:
    from hil.campaign.report import _fmt_lat, _fmt_rate

    for veh, vs in doc["by_vehicle"].items():
        for cls, st in vs.items():
            if cls == "none":
                print(f"  {veh} fault-free: false alarms {_fmt_rate(st['false_alarm'])}")
            elif cls == "all_faults":
                print(f"  {veh} all faults: missed {_fmt_rate(st['missed_detection'])}, "
                      f"latency p50/p90/max {_fmt_lat(st['latency_s'])}")
            else:
                wrong = st["wrong_first"]
                print(f"  {veh} {cls}: missed {_fmt_rate(st['missed_detection'])}, "
                      f"unobservable {st['unobservable']}, latency p50/p90/max "
                      f"{_fmt_lat(st['latency_s'])}"
                      + (f", {wrong} detected after a wrong one named first" if wrong else ""))
                if "fraction_error" in st:
                    fe = st["fraction_error"]
                    print(f"    thrust fraction within {fe['tolerance']}: "
                          f"{_fmt_rate(fe['within_tolerance'])}, |error| p50/p90/max "
                          f"{_fmt_lat(fe)}, mean signed {fe['mean_signed']}")
                for key, what, lat in (
                        ("commanded_goal", ("commanded on", "first command"),
                         "latency_from_command_s"),
                        ("closed_goal", ("commanded closed", "first closed time"),
                         "latency_from_closed_s")):
                    if key in st:
                        g = st[key]
                        print(f"    {what[0]} {g['min_ticks']}+ ticks after the fault (or "
                              f"detected sooner: {g.get('detected_sooner', 0)}): detected "
                              f"{_fmt_rate(g['detection'])}, from the {what[1]} p50/p90/max "
                              f"{_fmt_lat(g[lat])}")
    if doc["failures"]:
        print(f"  failed runs: {len(doc['failures'])} (see report.md)")


def _cmd_run(args) -> int:
    from hil.campaign.engine import run_campaign

    c = load_campaign(args.target)
    out = Path(args.out) if args.out else _default_out(c.name)
    o = run_campaign(c, out, workers=args.workers, scheduler=args.scheduler,
                     progress=not args.no_progress)
    doc = _finish_report(c, out)
    print(f"campaign {c.name}: {doc['rows']}/{c.runs} runs have a row ({o.computed} computed "
          f"now in {o.wall_s:.1f} s on {o.where}); report in {out / 'report.md'}")
    _print_summary(doc)
    if o.lost:
        print(f"  {o.lost} task(s) lost with their worker: run the same command to compute "
              f"them", file=sys.stderr)
    if o.interrupted:
        print(f"interrupted: {doc['rows']} of {c.runs} runs kept in {out / 'runs.jsonl'}; the "
              f"same command resumes", file=sys.stderr)
        return 130
    rc = 1 if doc["failures"] or doc["rows"] < c.runs else 0
    if args.bus:
        rc = max(rc, _bus_check(c, out, args.bus))
    return rc


def bus_sample(c, k: int | None = None) -> list[int]:
    """The runs ``--bus`` checks: ``bus_sample`` of them, drawn from the master seed."""
    from hil.campaign.dispersions import stream

    n = min(k or c.model.bus_sample, c.runs)
    rng = stream(c.seed, c.runs, "bus_sample")
    return sorted(int(x) for x in rng.choice(c.runs, size=n, replace=False))


def compare(row: dict[str, Any], bus: dict[str, Any], n_ticks: int) -> list[str]:
    """How a run over the bus differs from its in-process row (empty: they agree)."""
    diffs = []
    a = [(d["thruster"], d["type"], d["t_s"]) for d in row["detections"]]
    b = [(d["thruster"], d["type"], d["t_s"]) for d in bus.get("detections", [])]
    if a != b:
        diffs.append(f"detections: in-process {a}, bus {b}")
    if len(bus.get("false_alarms", [])) != row["false_alarms"]:
        diffs.append(f"false alarms: in-process {row['false_alarms']}, bus "
                     f"{len(bus.get('false_alarms', []))}")
    if bus.get("ticks") != n_ticks:
        diffs.append(f"ticks: expected {n_ticks}, bus {bus.get('ticks')}")
    return diffs


def _bus_check(c, out: Path, bus: str | bool = True) -> int:
    """Run the sample over the real bus (``hil run``, lockstep: ``bus`` can (vcan0) or lcm,
    True for the base scenario's ``bus:``, else can) and compare."""
    from hil.campaign.engine import read_rows
    from hil.campaign.expansion import expand_run, write_run

    rows = {r["run"]: r for r in read_rows(out / "runs.jsonl")}
    results, bad = [], 0
    for k in bus_sample(c):
        spec = expand_run(c, k)
        d = out / "bus" / spec.name
        path = write_run(spec, d)
        cmd = [sys.executable, "-m", "hil.cli", "run", str(path), "--out", str(d / "run")]
        if bus in ("can", "lcm"):  # else the run's own bus: (the base scenario's), or can
            cmd += ["--bus", bus]
        print(f"bus: run {k}: {' '.join(cmd[1:])}", flush=True)
        p = subprocess.run(cmd, capture_output=True, text=True)
        summ = d / "run" / "summary.json"
        if p.returncode not in (0, 1) or not summ.exists():
            tail = (p.stdout + p.stderr).strip().splitlines()[-3:]
            results.append({"run": k, "agree": False, "why": f"hil run exited {p.returncode}: "
                            f"{' / '.join(tail)}"})
            bad += 1
            continue
        summ_bus = json.loads(summ.read_text())
        diffs = compare(rows[k], summ_bus, spec.n_ticks) if k in rows else ["no in-process row"]
        results.append({"run": k, "agree": not diffs, "diffs": diffs,
                        "where": summ_bus.get("where"), "bus_kind": summ_bus.get("bus_kind"),
                        "fuel_kg": {"in_process": rows.get(k, {}).get("fuel_kg"),
                                    "bus": summ_bus.get("fuel_kg")}})
        bad += bool(diffs)
        print(f"bus: run {k}: {'agrees' if not diffs else 'DIFFERS: ' + '; '.join(diffs)}")
    (out / "bus.json").write_text(json.dumps(results, indent=2) + "\n")
    print(f"bus: {len(results) - bad}/{len(results)} sampled runs agree with the in-process "
          f"result ({out / 'bus.json'})")
    return 1 if bad else 0


def _cmd_expand(args) -> int:
    from hil.campaign.expansion import expand_run, write_run

    c = load_campaign(args.target)
    if args.run is None:
        raise CampaignError("hil campaign expand", "--run", "run indices K[,K...]",
                            Bare("nothing"))
    try:
        ks = [int(x) for x in args.run.split(",") if x.strip()]
    except ValueError:
        raise CampaignError("hil campaign expand", "--run", "integers separated by commas",
                            args.run) from None
    for k in ks:
        if not 0 <= k < c.runs:
            raise CampaignError("hil campaign expand", "--run", f"0 <= K < {c.runs}", k)
    out = Path(args.out) if args.out else _default_out(c.name, "-expanded")
    for k in ks:
        print(write_run(expand_run(c, k), out))
    return 0


def _cmd_sweep(args) -> int:
    from hil.campaign.sweep import run_sweep

    cs = [load_campaign(f) for f in [args.target, *args.more]]
    out = Path(args.out) if args.out else _default_out(cs[0].name, "-sweep")
    doc = run_sweep(cs, out, thresholds=_floats(args.thresholds, "--thresholds")
                    if args.thresholds else None,
                    forgetting=_floats(args.forgetting, "--forgetting")
                    if args.forgetting else None,
                    workers=args.workers, scheduler=args.scheduler,
                    progress=not args.no_progress)
    print(f"sweep over {doc['replayed_runs']} replayed runs of {doc['vehicle']} "
          f"(configured: {doc['configured']}):")
    print("  thr_on thr_off  w_on  w_off | false alarms        | detected     | latency "
          "p50/p90 s")
    for p in doc["points"]:
        fa = (f"{p['false_alarm_runs']}/{p['fault_free_runs']}" if p["fault_free_runs"]
              else f"{p['false_alarm_before_fault_runs']}/{p['fault_runs']} pre")
        det = f"{p['detected']}/{p['fault_runs']}" if p["fault_runs"] else "-"
        lat = (f"{p['latency_p50_s']:.2f}/{p['latency_p90_s']:.2f}"
               if p["latency_p50_s"] is not None else "-")
        print(f"  {p['threshold_on']:6g} {p['threshold_off']:7g} {p['forgetting_on']:5g} "
              f"{p['forgetting_off']:6g} | {fa:19s} | {det:12s} | {lat}")
    print(f"  written: {out / 'sweep.json'}, {out / 'sweep.png'}")
    return 0


def _cmd_report(args) -> int:
    folder = Path(args.target)
    meta = folder / "meta.json"
    if not meta.exists():
        raise CampaignError(str(folder), "meta.json", "a campaign results folder",
                            Bare("no meta.json"))
    src = folder / "campaign.yaml"
    c = load_campaign(src)
    doc = _finish_report(c, folder)
    print(f"report: {folder / 'report.md'} ({doc['rows']} rows)")
    _print_summary(doc)
    return 0


def _dispatch(args) -> int:
    try:
        return _route(args)
    except CampaignError as exc:
        if getattr(args, "debug", False):
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _route(args) -> int:
    action = args.target if args.target in ACTIONS else "run"
    if action != "run":
        if not args.more:
            raise CampaignError(f"hil campaign {action}", "FILE" if action != "report" else
                                "DIR", "a path", Bare("nothing"))
        args.target, args.more = args.more[0], args.more[1:]
    if args.more and action != "sweep":
        raise CampaignError(f"hil campaign {action}", "arguments", "one FILE", args.more)
    for key, flag in _FLAGS.items():
        val = getattr(args, key)
        if val not in (None, False) and key not in OPTIONS[action]:
            raise CampaignError(f"hil campaign {action}", flag, "no such option for this "
                                "action", val)
    return {"run": _cmd_run, "expand": _cmd_expand, "sweep": _cmd_sweep,
            "report": _cmd_report}[action](args)


def register(sub) -> None:
    doc = __doc__.split("\n\n")
    p = sub.add_parser(
        "campaign", help="Monte Carlo campaigns on Dask: false-alarm and missed-detection rates",
        description="Run a campaign file's runs as tasks on Dask distributed (an embedded "
        "LocalCluster, one single-threaded worker process per core, or an existing cluster "
        "with --scheduler), write one row per run as it arrives (the same command resumes), "
        "then DIR/campaign.json and DIR/report.md with plots.",
        epilog="\n\n".join(doc[1:]), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("target", metavar="FILE|expand|sweep|report",
                   help="a campaign file, or an action followed by its FILE(s) / DIR")
    p.add_argument("more", nargs="*", metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the embedded LocalCluster (default: one per "
                        "core); 1 runs every run in this process")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://HOST:8786")
    p.add_argument("--out", metavar="DIR",
                   help="results folder (default runs/campaigns/<name>); expand: where the "
                        "scenario files go")
    p.add_argument("--bus", nargs="?", const=True, choices=("can", "lcm"),
                   help="also run a sample of the runs over the real bus (hil run, lockstep) "
                        "and check that they agree with the in-process rows: can (vcan0), lcm "
                        "(a private network namespace), or, given alone, the base scenario's "
                        "bus: (else can)")
    p.add_argument("--no-progress", action="store_true", help="no progress output")
    p.add_argument("--run", metavar="K[,K...]", help="expand: the run indices to write")
    p.add_argument("--thresholds", metavar="T,T,...",
                   help="sweep: detector thresholds (on and off) to replay")
    p.add_argument("--forgetting", metavar="W,W,...",
                   help="sweep: forgetting factors (on and off) to replay")
    p.set_defaults(func=_dispatch)
