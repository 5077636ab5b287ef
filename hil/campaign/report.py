"""``DIR/campaign.json`` and ``DIR/report.md`` with PNG plots, from the rows of a campaign.

``campaign.json``: the statistics of ``hil.campaign.statistics.campaign_statistics`` (rates
with Clopper-Pearson intervals per vehicle and fault class, latencies, unobservable runs,
confusion counts, failures), the worst runs with the command that reproduces each, and the
campaign's identity. ``report.md`` says the same for a person, with ``latency.png`` (latency
histogram per fault class), ``confusion.png`` (injected against named thruster, groups and
"none" as their own columns) and ``rates.png`` (rates with their intervals).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hil.campaign.statistics import FAILED, campaign_statistics, worst_runs


def _goal_table(classes: list[str], vs: dict, key: str, lat: str, head: str,
                col: str) -> list[str]:
    """The goal population's table (``key``: ``commanded_goal`` or ``closed_goal``) over the
    fault ``classes`` that have it, with ``head`` (``{n}``: its minimum ticks) above it."""
    if not classes:
        return []
    L = [head.format(n=vs[classes[0]][key]["min_ticks"]), "",
         f"| fault class | detection rate [95 % CI] | latency from the first {col} s "
         "p50 / p90 / max |", "|---|---|---|"]
    for k in classes:
        g = vs[k][key]
        L.append(f"| {k} | {_fmt_rate(g['detection'])} | {_fmt_lat(g[lat])} |")
    return L + [""]


def reproduce_command(campaign_file: str, row: dict[str, Any]) -> str:
    return (f"hil campaign expand {campaign_file} --run {row['run']} --out runs/repro && "
            f"hil run runs/repro/{row['name']}.yaml")


def _fmt_rate(r: dict[str, Any] | None) -> str:
    if not r or r["n"] == 0:
        return "- (no runs)"
    lo, hi = r["ci95"]
    return f"{r['k']}/{r['n']} = {100 * r['rate']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]"


def _fmt_lat(lat: dict[str, Any]) -> str:
    if not lat["n"]:
        return "-"
    return f"{lat['p50']:.2f} / {lat['p90']:.2f} / {lat['max']:.2f} (n={lat['n']})"


def _plots(rows: list[dict[str, Any]], stats: dict[str, Any], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    made = []
    lat: dict[str, list[float]] = {}
    for r in rows:
        if r["verdict"] == "detected":
            lat.setdefault(f"{r['vehicle']} {r['fault_class']}", []).append(r["latency_s"])
    if lat:
        fig, ax = plt.subplots(figsize=(7, 4))
        allv = [v for vs in lat.values() for v in vs]
        bins = np.linspace(0.0, max(allv) * 1.05 + 1e-9, 30)
        for k, vs in sorted(lat.items()):
            ax.hist(vs, bins=bins, alpha=0.6, label=f"{k} (n={len(vs)})")
        ax.set_xlabel("detection latency (s): fault time to the first correct detection")
        ax.set_ylabel("runs")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / "latency.png", dpi=110)
        plt.close(fig)
        made.append("latency.png")
    faults = [r for r in rows if r["fault"] is not None
              and r["verdict"] not in (*FAILED, "unobservable")]
    if faults:
        inj = sorted({str(r["fault"].get("thruster")) for r in faults},
                     key=lambda s: (len(s), s))
        named = []
        for r in faults:
            who = (r["named"] or "none").rsplit(" ", 1)[0] if r["named"] else "none"
            named.append(who)
        cols = sorted({n for n in named if n not in inj and n != "none"}, key=lambda s: (len(s), s))
        cols = inj + cols + ["none"]
        m = np.zeros((len(inj), len(cols)), dtype=int)
        for r, who in zip(faults, named, strict=True):
            m[inj.index(str(r["fault"].get("thruster"))), cols.index(who)] += 1
        fig, ax = plt.subplots(figsize=(max(5, 0.3 * len(cols) + 3), max(4, 0.3 * len(inj) + 2)))
        ax.imshow(m, cmap="Blues", aspect="auto")
        ax.set_xticks(range(len(cols)), cols, rotation=90, fontsize=7)
        ax.set_yticks(range(len(inj)), inj, fontsize=7)
        for i in range(m.shape[0]):
            for j in range(m.shape[1]):
                if m[i, j]:
                    ax.text(j, i, str(m[i, j]), ha="center", va="center", fontsize=6)
        ax.set_xlabel("named by the first detection after the fault (groups apart; none)")
        ax.set_ylabel("injected thruster")
        ax.set_title("isolation: injected vs named thruster (all fault kinds; unobservable runs "
                     "apart)", fontsize=9)
        fig.tight_layout()
        fig.savefig(out / "confusion.png", dpi=110)
        plt.close(fig)
        made.append("confusion.png")
    bars = []
    for veh, vs in stats["by_vehicle"].items():
        for cls, st in vs.items():
            r = st.get("false_alarm") if cls == "none" else st.get("missed_detection")
            if r and r["n"] and cls != "all_faults":
                what = "false alarm" if cls == "none" else f"missed {cls}"
                bars.append((f"{veh}: {what}", r))
    if bars:
        fig, ax = plt.subplots(figsize=(7, 0.5 * len(bars) + 1.5))
        y = np.arange(len(bars))
        p = np.array([b[1]["rate"] for b in bars])
        lo = np.array([b[1]["ci95"][0] for b in bars])
        hi = np.array([b[1]["ci95"][1] for b in bars])
        ax.barh(y, p, xerr=[p - lo, hi - p], capsize=4, color="tab:orange")
        ax.set_yticks(y, [b[0] for b in bars], fontsize=8)
        ax.set_xlim(0, 1)
        ax.set_xlabel("rate, with the exact (Clopper-Pearson) 95 % interval")
        ax.grid(alpha=0.3, axis="x")
        fig.tight_layout()
        fig.savefig(out / "rates.png", dpi=110)
        plt.close(fig)
        made.append("rates.png")
    return made


def write_report(rows: list[dict[str, Any]], out: Path, *, campaign: str, campaign_file: str,
                 runs_planned: int, fingerprint: str, extra: dict[str, Any] | None = None
                 ) -> dict[str, Any]:
    """Write ``campaign.json``, ``report.md`` and the PNGs into ``out``; return the JSON."""
    out.mkdir(parents=True, exist_ok=True)
    rows = sorted(rows, key=lambda r: r["run"])
    stats = campaign_statistics(rows)
    worst = [{"run": r["run"], "name": r["name"], "verdict": r["verdict"],
              "fault": r["fault"], "named": r["named"], "latency_s": r["latency_s"],
              "first_detection": r["detections"][0] if r["detections"] else None,
              "why": r["error"] or r["reason"],
              "max_attitude_error_deg": r["max_attitude_error_deg"],
              "reproduce": reproduce_command(campaign_file, r)} for r in worst_runs(rows)]
    doc = {"campaign": campaign, "file": campaign_file, "fingerprint": fingerprint,
           "runs_planned": runs_planned, "rows": len(rows),
           "wall_s_sum": round(sum(r.get("wall_s") or 0.0 for r in rows), 1),
           "cpu_s_sum": round(sum(r.get("cpu_s") or 0.0 for r in rows), 1),
           **stats, "worst_runs": worst, **(extra or {})}
    (out / "campaign.json").write_text(json.dumps(doc, indent=2) + "\n")
    pngs = _plots(rows, stats, out)

    L = [f"# Campaign {campaign}", "",
         f"`{campaign_file}`: {len(rows)} of {runs_planned} runs have a row "
         f"(fingerprint `{fingerprint}`).", ""]
    if len(rows) < runs_planned:
        L += [f"**Incomplete campaign:** {runs_planned - len(rows)} runs have no row yet; "
              f"run the same command again to compute them.", ""]
    L += ["Rates are exact binomial (Clopper-Pearson) 95 % intervals. Failed runs (error, "
          "incomplete summary) are in no rate; unobservable runs (a thruster that fails to "
          "fire or is degraded never commanded after the fault, or a stuck-on one commanded "
          "on for the whole of every tick after it) are in no missed-detection rate.", ""]
    for veh, vs in stats["by_vehicle"].items():
        L += [f"## {veh}", ""]
        if "none" in vs:
            st = vs["none"]
            att = st.get("max_attitude_error_deg") or {"n": 0}
            L += ["| fault-free runs | completed | false-alarm rate [95 % CI] | first false "
                  "alarm at (s) p50 / p90 / max | largest attitude error of a run (deg) p50 / "
                  "p90 / max |", "|---|---|---|---|---|",
                  f"| {st['runs']} | {st['completed']} | {_fmt_rate(st['false_alarm'])} | "
                  f"{_fmt_lat(st['first_false_alarm_s'])} | {_fmt_lat(att)} |", ""]
        fcls = [k for k in vs if k not in ("none", "all_faults")]
        if fcls:
            L += ["| fault class | runs | unobservable | observable | missed-detection rate "
                  "[95 % CI] | detected exact / group | of those, a wrong one named first | "
                  "misidentified | latency s p50 / p90 / max | runs with a false alarm before "
                  "the fault |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
            for k in fcls + (["all_faults"] if "all_faults" in vs else []):
                st = vs[k]
                if k == "all_faults":
                    L.append(f"| **all** | {st['runs']} | | {st['observable']} | "
                             f"{_fmt_rate(st['missed_detection'])} | | | | "
                             f"{_fmt_lat(st['latency_s'])} | |")
                    continue
                L.append(f"| {k} | {st['runs']} | {st['unobservable']} | {st['observable']} | "
                         f"{_fmt_rate(st['missed_detection'])} | {st['detected_exact']} / "
                         f"{st['detected_group']} | {st['wrong_first']} | "
                         f"{st['misidentified']} | "
                         f"{_fmt_lat(st['latency_s'])} | "
                         f"{_fmt_rate(st['false_alarm_before_fault'])} |")
            L.append("")
            if "fraction_error" in vs.get("degraded", {}):
                fe = vs["degraded"]["fraction_error"]
                L += [f"Degraded: thrust fraction named within {fe['tolerance']} of the injected "
                      f"one in {_fmt_rate(fe['within_tolerance'])} of the observable runs; "
                      f"|error| p50 / p90 / max {_fmt_lat(fe)}, mean signed error "
                      f"{fe['mean_signed']}.", ""]
            for key, lat, head, col in (
                    ("commanded_goal", "latency_from_command_s",
                     "Faults seen only when their thruster fires, runs whose thruster was "
                     "commanded on {n} ticks or more after the fault, or detected before its "
                     "{n}th command (the FDIR goal's population; the response ends the "
                     "thruster's commands):", "command"),
                    ("closed_goal", "latency_from_closed_s",
                     "Stuck on, seen only while its valve is meant to be closed: runs whose "
                     "thruster was commanded closed for part or all of {n} ticks or more "
                     "after the fault, or detected sooner:", "closed time")):
                L += _goal_table([k for k in fcls if key in vs[k]], vs, key, lat, head, col)
            conf = stats["confusion"].get(veh, {}).get("by_kind", [])
            if conf:
                L += ["Isolation by kind (injected kind, what the first detection after the "
                      "fault named):", "", "| injected | named | runs |", "|---|---|---|"]
                L += [f"| {c['injected']} | {c['named']} | {c['runs']} |" for c in conf]
                L.append("")
        pulsed = [k for k in vs if "pulse_tests" in vs[k]]
        if pulsed:
            L += ["Test pulses (a suspected thruster fired alone between quiet ticks; the "
                  "controller waits on the test's ticks):", "",
                  "| runs of | runs with a test | tests | healthy / named / no verdict | "
                  "ticks waited per run p50 / p90 / max |", "|---|---|---|---|---|"]
            for k in pulsed:
                pt = vs[k]["pulse_tests"]
                L.append(f"| {k} | {pt['runs_with_tests']} of {vs[k]['completed']} | "
                         f"{pt['started']} | {pt['healthy']} / {pt['named']} / {pt['void']} | "
                         f"{_fmt_lat(pt['wait_ticks_per_run'])} |")
            L.append("")
    if stats["failures"]:
        L += ["## Failed runs", "", "| run | verdict | why |", "|---|---|---|"]
        L += [f"| {f['run']} | {f['verdict']} | {str(f['why']).replace('|', '/')} |"
              for f in stats["failures"][:50]]
        L.append("")
    L += ["## Worst runs", "", "Failures first, then false alarms (earliest first), missed and "
          "misidentified faults, the longest latencies. Each line reproduces the run on its own "
          "over the bus (`hil run`); the in-process result is the campaign's row.", "",
          "| run | verdict | fault | named / first detection | latency s | reproduce |",
          "|---|---|---|---|---|---|"]
    for w in worst:
        f = w["fault"]
        fs = f"{f['kind']} {f.get('thruster')} at {f['t_s']:.1f} s" if f else "none"
        d = w["first_detection"]
        named = w["named"] or (f"{d['type']} {d['thruster']} at {d['t_s']:.1f} s" if d else "-")
        lat = f"{w['latency_s']:.2f}" if w["latency_s"] is not None else "-"
        L.append(f"| {w['run']} | {w['verdict']} | {fs} | {named} | {lat} | "
                 f"`{w['reproduce']}` |")
    L.append("")
    for p in pngs:
        L += [f"![{p}]({p})", ""]
    (out / "report.md").write_text("\n".join(L))
    return doc
