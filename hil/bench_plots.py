"""`hil bench`'s plots: histograms of release jitter, sensor-to-actuator latency and bus
latency, and the compute time per flight stage over time (PNG).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_plots(report: dict, out: Path) -> list[str]:
    """PNG histograms of jitter and latencies, and compute time per stage over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    where = report.get("host", {}).get("kernel", "")
    made: list[str] = []
    rt = (report.get("realtime") or {}).get("_series")
    bus = (report.get("bus") or {}).get("_series")
    if rt and rt["jitter_ms"]:
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.hist(rt["jitter_ms"], bins=60, color="tab:blue")
        ax.set_yscale("log")
        ax.set_xlabel("release jitter: wake-up minus scheduled release [ms]")
        ax.set_ylabel("ticks")
        ax.set_title(f"flight tick release jitter ({where})")
        fig.tight_layout()
        fig.savefig(out / "jitter_hist.png", dpi=110)
        plt.close(fig)
        made.append("jitter_hist.png")
    panels = []
    if rt and rt["s2a_ms"]:
        panels.append(("sensor-to-actuator: gyro sample to THR_CMD applied [ms]", rt["s2a_ms"]))
    if bus:
        panels.append(("bus one way A->B [ms]", bus["one_way_ms"]))
        panels.append(("bus round trip [ms]", bus["round_trip_ms"]))
    if panels:
        fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.6 * len(panels)))
        for ax, (label, vals) in zip(np.atleast_1d(axes), panels, strict=True):
            ax.hist(vals, bins=60, color="tab:orange")
            ax.set_yscale("log")
            ax.set_xlabel(label)
            ax.set_ylabel("count")
        fig.suptitle(f"latency ({where})")
        fig.tight_layout()
        fig.savefig(out / "latency_hist.png", dpi=110)
        plt.close(fig)
        made.append("latency_hist.png")
    if rt and rt["stage_ms"]:
        fig, ax = plt.subplots(figsize=(9, 4.5))
        t = rt["tick"]
        for k, vals in rt["stage_ms"].items():
            ax.plot(t, vals, lw=0.8, label=k)
        ax.set_yscale("log")
        ax.set_xlabel("flight tick")
        ax.set_ylabel("compute time [ms]")
        ax.set_title(f"flight compute per stage ({where})")
        ax.legend(fontsize=7, ncol=4)
        fig.tight_layout()
        fig.savefig(out / "compute_stages.png", dpi=110)
        plt.close(fig)
        made.append("compute_stages.png")
    return made
