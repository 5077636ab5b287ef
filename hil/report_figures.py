"""The report's figures (``hil report``): rates, phase plane, residuals and firing chart of one
run, PNGs drawn with matplotlib. How to read each is in ``hil.report``'s module doc.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hil.report_load import AXES, Run, answer_to, fault_text, names_of, thruster_text

DPI = 100
FIG_W_IN = 9.0
FIG_H_IN = 4.0
FAULT_COLOR = "tab:red"
DETECT_COLOR = "tab:green"
FALSE_ALARM_COLOR = "darkorange"
TRUTH_COLOR = "tab:blue"
MEAS_COLOR = "0.35"
# Thruster colours on residual plots: no red, green or orange (taken by fault/detection lines).
THRUSTER_COLORS = ("tab:blue", "tab:purple", "tab:brown", "tab:cyan", "tab:olive", "tab:pink",
                   "tab:gray", "navy")
ZOOM_MARGIN_S = 20.0         # rates, residuals and firing chart: fault - 20 s .. detection + 20 s
PHASE_MARGIN_S = 5.0         # phase-plane zoom: fault - 5 s .. detection + 5 s
NO_DETECTION_AFTER_S = 40.0  # window end after a fault that was never detected
ZOOM_IF_FRACTION = 0.6       # add a zoom panel when the window is shorter than this share of run
MAX_RESIDUAL_THRUSTERS = 5
LEGEND_CHARS_PER_ROW = 140
FIRING_SHOW_ALL_UP_TO = 8     # more thrusters than this: show only those commanded


# =============================================================================== plots: helpers


def fmt_s(x: float | None) -> str:
    """Seconds for the report: one decimal when the value sits on it (0.2 s ticks), else two."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.1f}" if abs(x * 10 - round(x * 10)) < 1e-6 else f"{x:.2f}"


def fmt_num(x: Any, fmt: str = ".2f") -> str:
    return format(x, fmt) if isinstance(x, int | float) else "-"


def _channel(run: Run, thruster: str, t_fault: float) -> int:
    """Body axis of the thruster's largest angular acceleration; else the largest rate change."""
    ar = run.arrays
    if ar is not None and thruster in ar.names:
        return int(np.argmax(np.abs(ar.mu_B_rad_s2[ar.names.index(thruster)])))
    t, w = run.plant.get("t"), run.plant.get("omega")
    if t is None or len(t) == 0:
        return 0
    k0 = int(np.searchsorted(t, t_fault))
    seg = w[k0:k0 + max(1, int(np.searchsorted(t, t_fault + 10.0)) - k0)]
    if len(seg) == 0 or np.all(np.isnan(seg)):
        return 0
    return int(np.nanargmax(np.nanmax(np.abs(seg - seg[0]), axis=0)))


def _span(run: Run) -> tuple[float, float]:
    ts = [a for a in (run.plant.get("t"), run.flight.get("t")) if a is not None and len(a)]
    if not ts:
        return 0.0, 1.0
    return float(min(a[0] for a in ts)), float(max(a[-1] for a in ts))


def fault_window(run: Run) -> tuple[float, float] | None:
    """Zoom window around the thruster faults: first fault - m .. its answer + m, with the
    margin m = 5 latencies, between 2 s and 20 s (a one-tick detection gets a window where
    its ticks can be told apart)."""
    faults = run.thruster_faults
    if not faults:
        return None
    t0, t1 = _span(run)
    t_f = min(float(f["t_s"]) for f in faults)
    ends = []
    for f in faults:
        d = answer_to(run, f)
        ends.append(float(d["t_s"]) if d else float(f["t_s"]) + NO_DETECTION_AFTER_S)
    margin = min(ZOOM_MARGIN_S, max(2.0, 5.0 * (max(ends) - t_f)))
    lo = max(t0, t_f - margin)
    hi = min(t1, max(ends) + margin)
    return (lo, hi) if hi > lo else (t0, t1)


def _needs_zoom(run: Run, win: tuple[float, float] | None) -> bool:
    if win is None:
        return False
    t0, t1 = _span(run)
    return (win[1] - win[0]) < ZOOM_IF_FRACTION * (t1 - t0)


def _markers(ax, run: Run, labels: bool = True) -> list:
    """Vertical fault (red), detection (green) and false-alarm (orange) lines; legend handles."""
    handles = []
    for f in run.summary.get("faults") or []:
        if f.get("t_s") is None:
            continue
        h = ax.axvline(float(f["t_s"]), color=FAULT_COLOR, lw=1.3, zorder=1.5,
                       label=f"fault: {fault_text(f)} at {fmt_s(float(f['t_s']))} s")
        handles.append(h)
    for d in run.detections:
        if d.get("t_s") is None:
            continue
        ok = bool(d.get("correct"))
        what = "detection" if ok else "false alarm"
        h = ax.axvline(float(d["t_s"]), color=DETECT_COLOR if ok else FALSE_ALARM_COLOR,
                       lw=1.3, ls="-" if ok else "-.", zorder=1.5,
                       label=f"{what}: {d.get('type')} {thruster_text(d.get('thruster'))} "
                             f"at {fmt_s(float(d['t_s']))} s")
        handles.append(h)
    return handles if labels else []


def _new_figure(rows: int = 1, cols: int = 1, height: float = FIG_H_IN, **kw):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(FIG_W_IN, height), dpi=DPI, layout="constrained")
    axs = fig.subplots(rows, cols, squeeze=False, **kw)
    return fig, axs


def _legend_below(fig, handles: list, ncol: int = 4) -> None:
    """One legend under the axes (never over the data), as many columns as fit the width."""
    seen: dict[str, Any] = {}
    for h in handles:
        seen.setdefault(h.get_label(), h)
    if not seen:
        return
    labels = list(seen)
    # About 145 characters of 8 pt text fit across 9 in; a column costs ~8 more for its handle.
    # Columns as matplotlib fills them: the first len % c columns get one label more.
    cols = 1
    for c in range(min(ncol, len(labels)), 0, -1):
        rows, big = divmod(len(labels), c)
        width, k = 0, 0
        for j in range(c):
            n = rows + (1 if j < big else 0)
            width += max(len(x) for x in labels[k:k + n]) + 8
            k += n
        if width <= LEGEND_CHARS_PER_ROW:
            cols = c
            break
    fig.legend(list(seen.values()), labels, loc="outside lower center", ncol=cols, fontsize=8,
               frameon=False)


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path


def _in(t: np.ndarray, win: tuple[float, float]) -> np.ndarray:
    return (t >= win[0] - 1e-9) & (t <= win[1] + 1e-9)


def _subtitle(run: Run) -> str:
    return f"{run.name} ({run.summary.get('vehicle', '?')})"


# =============================================================================== plots


def plot_rates(run: Run, path: Path) -> Path | None:
    """True and measured rate of the faulted channel (seed 000 figs. 9, 13); no fault: all."""
    tp, w = run.plant.get("t"), run.plant.get("omega")
    tf, wm = run.flight.get("t"), run.flight.get("meas")
    if (tp is None or not len(tp)) and (tf is None or not len(tf)):
        return None
    faults = run.thruster_faults
    orbit = run.vehicle is not None and run.vehicle.orbit.rate_rad_s > 0
    true_lbl = "true (plant, rel. orbit frame)" if orbit else "true (plant)"
    integrating = run.vehicle is not None and run.vehicle.gyro.kind == "integrating"
    meas_lbl = "measured (" + ("integrating gyro: mean rate over the tick" if integrating
                               else "gyro") + (", inertial)" if orbit else ")")
    if not faults:
        return _plot_rates_nofault(run, path, true_lbl)
    f0 = faults[0]
    ch = _channel(run, f0["thruster"], float(f0["t_s"]))
    win = fault_window(run)
    zoom = _needs_zoom(run, win)
    fig, axs = (_new_figure(1, 2, width_ratios=[1, 1.6]) if zoom else _new_figure(1, 1))
    panels = [(axs[0][0], None)] + ([(axs[0][1], win)] if zoom else [])
    handles: list = []
    for ax, wnd in panels:
        if len(tp):
            m = _in(tp, wnd) if wnd else slice(None)
            handles.append(ax.plot(tp[m], w[m, ch], color=TRUTH_COLOR, lw=1.6,
                                   label=true_lbl)[0])
        if len(tf) and (wnd or not zoom):  # thousands of dots would bury the whole-run line
            m = _in(tf, wnd) if wnd else slice(None)
            n_dots = np.count_nonzero(m) if wnd else len(tf)
            ms = 2.5 if n_dots < 400 else 1.0  # dots, not a line: it would hide under the truth
            handles.append(ax.plot(tf[m], wm[m, ch], ".", color=MEAS_COLOR, ms=ms,
                                   label=f"{meas_lbl}, one dot per tick")[0])
        handles += _markers(ax, run)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"rate ω_{AXES[ch]} [deg/s]")
        ax.grid(alpha=0.3)
        if wnd:
            ax.set_xlim(*wnd)
            ax.set_title(f"zoom {fmt_s(wnd[0])}-{fmt_s(wnd[1])} s", fontsize=9)
        elif zoom:
            ax.axvspan(*win, color="0.85", zorder=0)
            ax.set_title("whole run (grey: zoomed window)", fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: rate of channel {AXES[ch]} "
                 f"(largest torque axis of {f0['thruster']})", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


def _dead_zone_deg_s(run: Run) -> float | None:
    if run.vehicle is None:
        return None
    c = run.vehicle.flight.controller
    return float(c.rate_deadband_deg_s) if c.law == "phase_plane" else None


def _plot_rates_nofault(run: Run, path: Path, true_lbl: str) -> Path:
    tp, w, att = run.plant.get("t"), run.plant.get("omega"), run.plant.get("att")
    fig, axs = _new_figure(1, 2)
    handles: list = []
    colors = ("tab:blue", "tab:purple", "tab:brown")
    ax_w, ax_a = axs[0]
    for i, a in enumerate(AXES):
        if len(tp):
            handles.append(ax_w.plot(tp, w[:, i], color=colors[i], lw=1.2, label=f"axis {a}")[0])
            ax_a.plot(tp, att[:, i], color=colors[i], lw=1.2)
    dz = _dead_zone_deg_s(run)
    if dz is not None:
        for sgn in (1, -1):
            h = ax_w.axhline(sgn * dz, color="k", ls=":", lw=1.0,
                             label=f"controller rate dead zone ±{dz:g} deg/s")
        handles.append(h)
    for ax in (ax_w, ax_a):
        handles += _markers(ax, run)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    ax_w.set_ylabel("rate ω [deg/s]")
    ax_a.set_ylabel("attitude error ν [deg]")
    ax_w.set_title(f"rate ω, {true_lbl}", fontsize=9)
    ax_a.set_title("attitude error ν, true (plant)", fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: no thruster fault, rates and attitude errors", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


def _band(run: Run, ch: int, nu_max_deg: float):
    """Controller dead zone on the channel's phase plane: (nu_deg, lo_deg_s, hi_deg_s, label)."""
    if run.vehicle is None or run.arrays is None:
        return None
    try:
        from flight.controller import Controller

        ctl = Controller(run.vehicle, run.arrays)
    except Exception:  # noqa: BLE001 - the band is a reading aid; the plot stands without it
        return None
    c = ctl.cfg
    if c.law == "s_law":
        nu = np.linspace(-nu_max_deg, nu_max_deg, 201)
        half = math.degrees(ctl.s_dz) / c.s_gain_s
        return (nu, -nu / c.s_gain_s - half, -nu / c.s_gain_s + half,
                f"dead zone |ν + {c.s_gain_s:g} s·ω| ≤ {c.s_deadband_deg:g} deg")
    lim = min(nu_max_deg, c.large_angle_deg)
    nu = np.linspace(-lim, lim, 401)
    eps = float(ctl.eps_B_rad_s2[ch])
    e_ref = []
    for x in np.radians(nu):
        if abs(x) > ctl.curve_rad:
            e_ref.append(-math.copysign(min(math.sqrt(2.0 * eps * abs(x)), ctl.w_max), x))
        else:
            e_ref.append(ctl.centre_line(float(x), eps))
    e = np.degrees(np.array(e_ref))
    dz = c.rate_deadband_deg_s
    return nu, e - dz, e + dz, f"controller dead zone (±{dz:g} deg/s about the switching line)"


def _phase_panel(ax, run: Run, ch: int, win: tuple[float, float] | None, t_fault: float | None,
                 dets: list[dict]) -> list:
    t, att, w = run.plant["t"], run.plant["att"][:, ch], run.plant["omega"][:, ch]
    m = _in(t, win) if win else np.ones(len(t), bool)
    t, x, y = t[m], att[m], w[m]
    handles = []
    if len(t) == 0:
        return handles
    xmax = float(np.nanmax(np.abs(x))) if np.any(np.isfinite(x)) else 1.0
    ymax = float(np.nanmax(np.abs(y))) if np.any(np.isfinite(y)) else 0.2
    band = _band(run, ch, max(xmax * 1.2, 1.0))
    if band is not None:
        nu, lo, hi, lbl = band
        handles.append(ax.fill_between(nu, lo, hi, color="0.8", alpha=0.6, lw=0, label=lbl))
    if t_fault is None:
        handles.append(ax.plot(x, y, color=TRUTH_COLOR, lw=1.2, label="true state")[0])
    else:
        k = int(np.searchsorted(t, t_fault))
        handles.append(ax.plot(x[:k + 1], y[:k + 1], color=TRUTH_COLOR, lw=1.2,
                               label="true state before the fault")[0])
        handles.append(ax.plot(x[k:], y[k:], color=FAULT_COLOR, lw=1.2,
                               label="true state after the fault (seed 000 fig. 8)")[0])
        if t[0] <= t_fault <= t[-1]:
            handles.append(ax.plot(np.interp(t_fault, t, x), np.interp(t_fault, t, y), "o",
                                   ms=8, mfc="none", mec=FAULT_COLOR, mew=2,
                                   label="state at the fault")[0])
    for d in dets:
        td = float(d["t_s"])
        if t[0] <= td <= t[-1]:
            ok = bool(d.get("correct"))
            handles.append(ax.plot(np.interp(td, t, x), np.interp(td, t, y), "*", ms=13,
                                   color=DETECT_COLOR if ok else FALSE_ALARM_COLOR, mec="k",
                                   mew=0.5, label="state at detection" if ok
                                   else "state at false alarm")[0])
    handles.append(ax.plot(x[0], y[0], "s", color="k", ms=5, label="first state shown")[0])
    ax.axhline(0, color="k", lw=0.5)
    ax.axvline(0, color="k", lw=0.5)
    pad_x, pad_y = 0.08 * max(xmax, 0.1), 0.12 * max(ymax, 0.05)
    ax.set_xlim(np.nanmin(x) - pad_x, np.nanmax(x) + pad_x)
    ax.set_ylim(np.nanmin(y) - pad_y, np.nanmax(y) + pad_y)
    ax.set_xlabel(f"attitude error ν_{AXES[ch]} [deg]")
    ax.set_ylabel(f"rate error ω_{AXES[ch]} [deg/s]")
    ax.grid(alpha=0.3)
    return handles


def plot_phase(run: Run, path: Path) -> Path | None:
    """Phase plane of the faulted channel (seed 000 figs. 7-8, 12; seed 004 fig. 2)."""
    if not len(run.plant.get("t", [])):
        return None
    faults = run.thruster_faults
    if not faults:
        fig, axs = _new_figure(1, 3)
        handles: list = []
        for ch in range(3):
            handles += _phase_panel(axs[0][ch], run, ch, None, None, run.detections)
            axs[0][ch].set_title(f"channel {AXES[ch]}", fontsize=9)
        fig.suptitle(f"{_subtitle(run)}: phase planes, no thruster fault", fontsize=11)
        _legend_below(fig, handles)
        return _save(fig, path)
    f0 = faults[0]
    t_f = float(f0["t_s"])
    ch = _channel(run, f0["thruster"], t_f)
    d = answer_to(run, f0)
    t0, t1 = _span(run)
    zwin = (max(t0, t_f - PHASE_MARGIN_S),
            min(t1, (float(d["t_s"]) if d else t_f + NO_DETECTION_AFTER_S) + PHASE_MARGIN_S))
    fig, axs = _new_figure(1, 2)
    handles = _phase_panel(axs[0][0], run, ch, None, t_f, run.detections)
    axs[0][0].set_title("whole run", fontsize=9)
    handles += _phase_panel(axs[0][1], run, ch, zwin, t_f, run.detections)
    axs[0][1].set_title(f"zoom {fmt_s(zwin[0])}-{fmt_s(zwin[1])} s", fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: phase plane of channel {AXES[ch]} "
                 f"({fault_text(f0)} at {fmt_s(t_f)} s)", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


def _residual_thrusters(run: Run, win: tuple[float, float] | None) -> list[str]:
    """Faulted, detected, then the others closest to their thresholds (max |rho| / thr)."""
    tf = run.flight["t"]
    m = _in(tf, win) if win else np.ones(len(tf), bool)
    rho_on, rho_off = run.flight["rho_on"], run.flight["rho_off"]
    names = list(dict.fromkeys([*rho_off, *rho_on]))
    first: list[str] = []
    for f in run.thruster_faults:
        first.append(f["thruster"])
    for d in run.detections:
        if win is None or win[0] <= float(d["t_s"]) <= win[1]:
            first.extend(names_of(d.get("thruster"))[:2])
    first = [n for n in dict.fromkeys(first) if n in names]
    thr = run.flight["thr"]
    t_off = float(np.nanmax(np.abs(thr["off"]))) if "off" in thr and len(thr["off"]) else 1.0
    t_on = float(np.nanmax(np.abs(thr["on"]))) if "on" in thr and len(thr["on"]) else 1.0

    def score(n: str) -> float:
        a = np.abs(rho_off.get(n, np.zeros(len(tf)))[m]) / (t_off or 1.0)
        b = np.abs(rho_on.get(n, np.zeros(len(tf)))[m]) / (t_on or 1.0)
        v = np.concatenate([a, b])
        return float(np.nanmax(v)) if v.size and np.any(np.isfinite(v)) else 0.0

    others = sorted((n for n in names if n not in first), key=score, reverse=True)
    others = [n for n in others if score(n) > 0.0]
    return (first + others)[:max(MAX_RESIDUAL_THRUSTERS, len(first))]


def plot_residuals(run: Run, path: Path) -> Path | None:
    """rho_off above, rho_on below, thresholds dashed (seed 000 figs. 10-11; seed 003 fig. 5b)."""
    tf = run.flight.get("t")
    if tf is None or not len(tf) or not (run.flight["rho_off"] or run.flight["rho_on"]):
        return None
    win = fault_window(run)
    shown = _residual_thrusters(run, win)
    m = _in(tf, win) if win else np.ones(len(tf), bool)
    t = tf[m]
    fig, axs = _new_figure(2, 1, height=5.0, sharex=True)
    ax_off, ax_on = axs[0][0], axs[1][0]
    faulted = {f["thruster"] for f in run.thruster_faults}
    handles: list = []
    for k, n in enumerate(shown):
        c = THRUSTER_COLORS[k % len(THRUSTER_COLORS)]
        lw = 2.0 if n in faulted else 1.2
        z = 5 if n in faulted else 2  # the faulted thruster on top of the others
        mk = "o" if n in faulted else None
        lbl = f"thruster {n} (faulted)" if n in faulted else f"thruster {n}"
        if n in run.flight["rho_off"]:
            handles.append(ax_off.plot(t, run.flight["rho_off"][n][m], color=c, lw=lw,
                                       label=lbl, zorder=z, marker=mk, ms=3)[0])
        if n in run.flight["rho_on"]:
            handles.append(ax_on.plot(t, run.flight["rho_on"][n][m], color=c, lw=lw,
                                      label=lbl, zorder=z, marker=mk, ms=3)[0])
    thr = run.flight["thr"]
    last = {k: v[m][np.isfinite(v[m])] for k, v in thr.items()}
    thr_lbl = "thresholds" + (
        f" (ρ_off > {last['off'][-1]:+g}, ρ_on < {last['on'][-1]:+g})"
        if all(k in last and last[k].size for k in ("off", "on")) else "")
    for ax, key in ((ax_off, "off"), (ax_on, "on")):
        if key in thr:
            handles.append(ax.step(t, thr[key][m], where="post", color="k", ls="--", lw=1.2,
                                   label=thr_lbl)[0])
        handles += _markers(ax, run)
        ax.grid(alpha=0.3)
        ax.axhline(0, color="k", lw=0.5)
    for d in run.detections:
        n = names_of(d.get("thruster"))
        series = run.flight["rho_off" if d.get("type") == "stuck_on" else "rho_on"]
        ax = ax_off if d.get("type") == "stuck_on" else ax_on
        if n and n[0] in series and len(t) and t[0] <= float(d["t_s"]) <= t[-1]:
            ax.plot(float(d["t_s"]), np.interp(float(d["t_s"]), t, series[n[0]][m]), "*",
                    ms=12, color=DETECT_COLOR if d.get("correct") else FALSE_ALARM_COLOR,
                    mec="k", mew=0.5)
    ax_off.set_ylabel("ρ_off (stuck on) [-]")
    ax_on.set_ylabel("ρ_on (fails to fire) [-]")
    ax_on.set_xlabel("time [s]")
    if win:
        ax_on.set_xlim(*win)
    where = f", {fmt_s(win[0])}-{fmt_s(win[1])} s" if win and _needs_zoom(run, win) else ""
    fig.suptitle(f"{_subtitle(run)}: integral residuals{where}", fontsize=11)
    _legend_below(fig, handles, ncol=4)
    return _save(fig, path)


def plot_firing(run: Run, path: Path) -> Path | None:
    """Commanded on-time per thruster per tick in 10 ms quanta (seed 004 figs. 6, 9, 12)."""
    tf = run.flight.get("t")
    on = run.flight.get("on_ms") or {}
    if tf is None or not len(tf) or not on:
        return None
    import matplotlib
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.patches import Patch, Rectangle

    quantum_ms = run.vehicle.timing.pwm_quantum_ms if run.vehicle is not None else 10.0
    tick_s = run.vehicle.timing.tick_s if run.vehicle is not None else (
        float(np.median(np.diff(tf))) if len(tf) > 1 else 0.2)
    n_q = max(1, int(round(tick_s * 1000.0 / quantum_ms)))
    win = fault_window(run)
    m = _in(tf, win) if win else np.ones(len(tf), bool)
    t = tf[m]
    if not len(t):
        return None
    faulted = [f["thruster"] for f in run.thruster_faults]
    if len(on) <= FIRING_SHOW_ALL_UP_TO:
        names = list(on)
    else:  # 30 thrusters: only those commanded in the window (and the faulted ones)
        names = [n for n in on if np.nansum(on[n][m]) > 0 or n in faulted]
    order = run.arrays.names if run.arrays is not None else tuple(on)
    names.sort(key=lambda n: order.index(n) if n in order else len(order))
    if not names:
        names = list(on)[:1]
    q = np.array([np.nan_to_num(on[n][m]) / quantum_ms for n in names])
    edges_t = np.append(t, t[-1] + tick_s)
    edges_y = np.arange(len(names) + 1) - 0.5
    # 0 is white; 1..n_q quanta from light to dark, starting dark enough to see a 30 ms pulse.
    ramp = matplotlib.colormaps["viridis_r"](np.linspace(0.15, 1.0, n_q))
    cmap = ListedColormap(np.vstack([[1.0, 1.0, 1.0, 1.0], ramp]))
    norm = BoundaryNorm(np.arange(n_q + 2) - 0.5, cmap.N)
    height = min(8.0, max(FIG_H_IN, 1.8 + 0.22 * len(names)))
    fig, axs = _new_figure(1, 1, height=height)
    ax = axs[0][0]
    mesh = ax.pcolormesh(edges_t, edges_y, q, cmap=cmap, norm=norm, shading="flat")
    ax.set_yticks(range(len(names)), names, fontsize=8 if len(names) > 12 else 9)
    for lbl in ax.get_yticklabels():
        if lbl.get_text() in faulted:
            lbl.set_color(FAULT_COLOR)
            lbl.set_fontweight("bold")
    ax.set_ylim(len(names) - 0.5, -0.5)  # first thruster on top
    handles = _markers(ax, run)
    for f in run.thruster_faults:
        if f["thruster"] not in names:
            continue
        row = names.index(f["thruster"])
        t_end = f.get("clear_t_s") or edges_t[-1]
        ax.add_patch(Rectangle((float(f["t_s"]), row - 0.45), float(t_end) - float(f["t_s"]),
                               0.9, fill=False, hatch="///", edgecolor=FAULT_COLOR, lw=0.0))
    if faulted:
        handles.append(Patch(fill=False, hatch="///", edgecolor=FAULT_COLOR, lw=0.0,
                             label="faulted: real thrust differs from the command"))
    ax.set_xlim(edges_t[0], edges_t[-1])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("thruster")
    cb = fig.colorbar(mesh, ax=ax, ticks=range(0, n_q + 1, max(1, n_q // 4)), pad=0.01)
    cb.set_label(f"on-time [{quantum_ms:g} ms quanta], {n_q} = whole tick", fontsize=8)
    hidden = len(on) - len(names)
    sub = f"{fmt_s(edges_t[0])}-{fmt_s(edges_t[-1])} s"
    if hidden > 0:
        sub += f"; {hidden} thrusters not commanded in this window are not shown"
    ax.set_title(sub, fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: commanded on-time per tick (THR_CMD)", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


PLOTS: tuple[tuple[str, Callable[[Run, Path], Path | None], str], ...] = (
    ("rates", plot_rates, "rate against time"),
    ("phase", plot_phase, "phase plane"),
    ("residuals", plot_residuals, "integral residuals and thresholds"),
    ("firing", plot_firing, "thruster firing chart"),
)

