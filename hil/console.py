"""`hil console`: the operator's live view of a running system, with the fault panel.

It attaches to a run folder (``--run``, default ``runs/up``: the ``--out`` of ``hil up``) and
reads the per-tick JSON lines the plant and flight write there as they grow
(``hil.follow``), so it works the same inside and outside user-mode Linux and never touches
the bus or the processes. Each tick it shows:

* attitude error (flight) and rate (truth, relative to the orbit frame) per channel against
  the controller's dead zones, and the channel's place in the phase plane (inside the dead
  zone, or which way out);
* the detector's residual evidence ``rho_on`` / ``rho_off`` of the thrusters nearest their
  thresholds, as bars against the thresholds;
* the thruster grid: commanded this tick (``flight/on_ms``), actual thrust (``truth/thrust_n``),
  failed (an active plant fault or a detection), manifold closed or dropped (the FDIR);
* the FDIR state, its detections and responses; timing (compute, release jitter, overruns,
  sensor-to-actuator or SYNC-to-command); the event log of both processes.

The fault panel (key ``f``) sends through the same path as ``hil fault``
(``hil.panel.build_command`` and ``hil.panel.deliver``: the run folder's panel bridge when
there is one, else the bus) and shows the same acknowledgement lines.

The view model (``ConsoleModel``) is plain Python fed with records, rendered as text; the
Textual app (``ConsoleApp``) only lays it out (it fits 80x24) and polls the folder.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import Any

from hil.follow import RunFollower

AXES = (("x", "roll"), ("y", "yaw"), ("z", "pitch"))
TOP_RESIDUALS = 4
BAR = 16
EVENT_LINES = 200


def _bar(frac: float, width: int = BAR) -> str:
    """A bar of ``frac`` (0..1, clipped; past 1 marked) in ``width`` cells."""
    f = max(0.0, min(frac, 1.0))
    full = int(round(f * width))
    return "█" * full + "·" * (width - full) + ("!" if frac >= 1.0 else " ")


class ConsoleModel:
    """What the console shows, from the records of one run (fed as they come)."""

    def __init__(self) -> None:
        self.plant: dict[str, Any] = {}
        self.flight: dict[str, Any] = {}
        self.config: dict[str, Any] = {}
        self.flight_config: dict[str, Any] = {}
        self.faults: list[dict] = []
        self.detections: list[dict] = []
        self.actions: list[dict] = []
        self.events: deque[str] = deque(maxlen=EVENT_LINES)
        self.ticks = 0
        self.max_compute_ms = 0.0
        self.events_total = 0  # every event fed (the deque keeps the last EVENT_LINES)
        self.dead_zone: tuple[float | None, float | None] = (None, None)

    # --- feeding -------------------------------------------------------------------------

    def feed(self, plant: list[dict], flight: list[dict]) -> bool:
        """Take new records; True when anything changed."""
        from hil.summary import apply_clear

        for r in plant:
            if r.get("final"):
                continue
            if "config" in r:
                self.config = r["config"]
                self.dead_zone = _dead_zone(self.config)
            self.faults.extend(dict(f) for f in r.get("faults_injected", []))
            for c in r.get("faults_cleared", []):
                apply_clear(self.faults, c)
            for e in r.get("events", []):
                self.events.append(f"{r['t_s']:7.1f} plant  {e}")
                self.events_total += 1
            self.plant = r
            self.ticks = max(self.ticks, int(r.get("tick", 0)) + 1)
        for r in flight:
            if "config" in r:
                self.flight_config = r["config"]
            if r.get("detection"):
                self.detections.append(r["detection"])
            self.actions.extend(r.get("fdir_actions", []))
            for e in r.get("events", []):
                self.events.append(f"{r['t_s']:7.1f} flight {e}")
                self.events_total += 1
            if r.get("compute_s") is not None:
                self.max_compute_ms = max(self.max_compute_ms, r["compute_s"] * 1e3)
            self.flight = r
        return bool(plant or flight)

    # --- derived -------------------------------------------------------------------------

    def _series(self, rec: dict, name: str) -> dict[str, float]:
        return (rec.get("series") or {}).get(name) or {}

    def active_faults(self) -> list[dict]:
        now = self.plant.get("t_s")
        if now is None:
            return []
        return [f for f in self.faults if f.get("clear_t_s") is None or f["clear_t_s"] > now]

    def deadbands(self) -> tuple[float | None, float | None]:
        """(angle dead band deg, rate dead band deg/s) of the vehicle's controller."""
        return self.dead_zone

    # --- panels (plain text, fixed widths: they fit 80x24) --------------------------------

    def header(self) -> str:
        c = self.config
        t = self.plant.get("t_s")
        mode = c.get("mode") or "-"
        return (f"{c.get('scenario', '?')}  vehicle {c.get('vehicle', '?')}  {mode}  "
                f"tick {self.ticks}  t {'-' if t is None else f'{t:.1f}'} s")

    def attitude(self) -> str:
        att = self._series(self.flight, "flight/attitude_error_deg")
        rate = self._series(self.plant, "truth/omega_deg_s")
        dz_a, dz_r = self.deadbands()
        lines = [f"ATT deg dz {dz_a if dz_a is not None else '-'}  "
                 f"rate deg/s dz {dz_r if dz_r is not None else '-'}"]
        for k, name in AXES:
            a, w = att.get(k), rate.get(k)
            if a is None or w is None:
                lines.append(f"{k} {name:5s}      -         -")
                continue
            lines.append(f"{k} {name:5s} {a:+8.3f} {w:+9.4f}  {phase_place(a, w, dz_a, dz_r)}")
        return "\n".join(lines)

    def residuals(self) -> str:
        on = self._series(self.flight, "flight/rho_on")
        off = self._series(self.flight, "flight/rho_off")
        th = self._series(self.flight, "flight/thresholds")
        t_on, t_off = abs(th.get("on", 0.0)) or None, th.get("off") or None
        lines = [f"RESIDUALS rho/thr (on {t_on or '-'}, off {t_off or '-'})"]
        if not on or t_on is None or t_off is None:
            return "\n".join(lines + ["  -"])
        # The evidence for "stuck on" grows negative (rho_on <= -thr_on), "fails" positive.
        score = {n: max(max(0.0, -on[n]) / t_on, max(0.0, off.get(n, 0.0)) / t_off) for n in on}
        for n in sorted(score, key=lambda k: -score[k])[:TOP_RESIDUALS]:
            r_on, r_off = on[n], off.get(n, 0.0)
            kind, frac = ("on ", -r_on / t_on) if -r_on / t_on >= r_off / t_off \
                else ("off", r_off / t_off)
            frac = frac if frac > 0 else 0.0
            lines.append(f"{n[-8:]:>8s} {kind} {_bar(frac)} {frac:4.2f}")
        return "\n".join(lines)

    def thrusters(self, width: int = 38) -> str:
        names = self.config.get("thrusters") or list(self._series(self.flight, "flight/on_ms"))
        cell = max((len(n) for n in names), default=2) + 2
        per_row = max(1, width // cell)
        on_ms = self._series(self.flight, "flight/on_ms")
        thrust = self._series(self.plant, "truth/thrust_n")
        faulty = {f.get("thruster") for f in self.active_faults()}
        detected = set()
        for d in self.detections:
            t = d.get("thruster")
            detected.update(t if isinstance(t, list) else [t])
        fdir = self.flight.get("fdir") or {}
        off = set(fdir.get("unavailable") or [])
        lines = ["THRUSTERS #fire c cmd *thrust F fault",
                 "          D detected x off . idle"]
        row = []
        for n in names:
            cmd, thr = on_ms.get(n, 0) > 0, thrust.get(n, 0) > 0
            state = ("x" if n in off else "D" if n in detected else "F" if n in faulty
                     else "#" if cmd and thr else "c" if cmd else "*" if thr else ".")
            row.append(f"{n:>{cell - 1}s}{state}")
            if len(row) == per_row:
                lines.append("".join(row))
                row = []
        if row:
            lines.append("".join(row))
        return "\n".join(lines)

    def fdir(self) -> str:
        f = self.flight.get("fdir") or {}
        closed = ", ".join(f.get("closed_manifolds") or []) or "none"
        lines = [f"FDIR {f.get('state', '-')}  closed: {closed}  "
                 f"safe: {'YES' if self.flight.get('safe') else 'no'}"]
        for d in self.detections[-2:]:
            thr = d.get("thruster")
            thr = thr if isinstance(thr, str) or thr is None else "one of " + ",".join(thr)
            lines.append(f" detected {d.get('type')} {thr or ''} {d.get('t_s', 0):.1f} s")
        for a in self.actions[-2:]:
            what = a.get("manifold") or a.get("thruster")
            lines.append(f" response {a.get('action')} {what} {a.get('t_s', 0):.1f} s")
        active = self.active_faults()
        lines.append(" faults active: " + (", ".join(
            f"{f['type']} {f['thruster']}" for f in active) if active else "none"))
        return "\n".join(lines)

    def timing(self) -> str:
        fr, pr = self.flight, self.plant
        c = fr.get("compute_s")
        j = fr.get("jitter_s")
        s2a = pr.get("s2a_s")
        if isinstance(s2a, list):
            s2a = max(s2a) if s2a else None
        link = (f"sensor-to-actuator {s2a * 1e3:.1f} ms" if isinstance(s2a, float)
                else f"SYNC-to-THR_CMD {pr['sync_to_cmd_s'] * 1e3:.1f} ms"
                if pr.get("sync_to_cmd_s") is not None else "")
        return (f"TIMING compute {'-' if c is None else f'{c * 1e3:.2f}'} ms "
                f"(max {self.max_compute_ms:.1f})\n jitter "
                f"{'-' if j is None else f'{j * 1e3:.2f}'} ms  overruns "
                f"{fr.get('overruns', '-')}\n {link}")

    def event_lines(self, n: int) -> list[str]:
        return list(self.events)[-n:]


def phase_place(angle: float, rate: float, dz_angle: float | None,
                dz_rate: float | None) -> str:
    """Where a channel's point (angle error, rate) is in the phase plane against the dead
    zone box: ``in`` or the sides it is out on (``a+``: angle above, ``r-``: rate below)."""
    if dz_angle is None or dz_rate is None:
        return ""
    out = []
    if abs(angle) > dz_angle:
        out.append("a+" if angle > 0 else "a-")
    if abs(rate) > dz_rate:
        out.append("r+" if rate > 0 else "r-")
    return "in" if not out else "out " + " ".join(out)


def _dead_zone(config: dict) -> tuple[float | None, float | None]:
    """The controller's dead zones of the vehicle a run's first record names."""
    from hil.config import load_vehicle
    from hil.errors import HilError

    vfile = config.get("vehicle_file")
    try:
        v = load_vehicle(vfile if vfile and Path(vfile).exists() else config.get("vehicle"))
    except (HilError, OSError, TypeError):
        return None, None
    c = v.flight.controller
    return c.angle_deadband_deg, c.rate_deadband_deg_s


def attach(run: Path) -> tuple[ConsoleModel, RunFollower]:
    follow = RunFollower(run)
    model = ConsoleModel()
    model.feed(*follow.read())
    return model, follow


# --- the Textual app ----------------------------------------------------------------------

def _app_classes():
    """Built on first use: importing Textual costs a few hundred ms, only the console needs it."""
    from rich.text import Text
    from textual.app import App, ComposeResult
    from textual.binding import Binding
    from textual.containers import Horizontal, Vertical
    from textual.screen import ModalScreen
    from textual.widgets import Button, Footer, Input, Log, Select, Static

    class FaultPanel(ModalScreen):
        """Inject, clear or list faults through the path of `hil fault`."""

        DEFAULT_CSS = """
        FaultPanel { align: center middle; }
        #panel { width: 64; height: auto; border: round $accent; padding: 0 1;
                 background: $surface; }
        #panel Input, #panel Select { width: 1fr; }
        #row1, #row2, #buttons { height: auto; }
        #result { height: auto; min-height: 2; }
        """
        BINDINGS = [Binding("escape", "close", "close")]

        def __init__(self, app_ref) -> None:
            super().__init__()
            self.console = app_ref

        def compose(self) -> ComposeResult:
            from hil.panel import TYPES

            with Vertical(id="panel"):
                yield Static("FAULT PANEL (same path as hil fault)")
                with Horizontal(id="row1"):
                    yield Input(placeholder="thruster", id="thruster")
                    yield Select([(t, t) for t in TYPES], value=TYPES[0], id="type",
                                 allow_blank=False)
                with Horizontal(id="row2"):
                    yield Input(placeholder="fraction 0..1", id="fraction")
                    yield Input(placeholder="at [s] (now)", id="at")
                with Horizontal(id="buttons"):
                    yield Button("Inject", id="inject", variant="error")
                    yield Button("Clear", id="clear")
                    yield Button("List", id="list")
                    yield Button("Close", id="close")
                yield Static("", id="result")

        def action_close(self) -> None:
            self.dismiss()

        def _num(self, wid: str) -> float | None:
            text = self.query_one(f"#{wid}", Input).value.strip()
            return float(text) if text else None

        def on_button_pressed(self, event: Button.Pressed) -> None:
            bid = event.button.id
            if bid == "close":
                self.dismiss()
                return
            if bid == "list":
                self.query_one("#result", Static).update(self.console.list_text())
                return
            thruster = self.query_one("#thruster", Input).value.strip() or None
            kind = self.query_one("#type", Select).value if bid == "inject" else None
            try:
                fraction, at = self._num("fraction"), self._num("at")
            except ValueError as exc:
                self.query_one("#result", Static).update(f"error: fault: {exc}")
                return
            self.query_one("#result", Static).update(f"{bid}: waiting for FAULT_ACK ...")
            self.console.send_fault(bid, thruster, kind, fraction, at,
                                    lambda text: self.app.call_from_thread(
                                        self.query_one("#result", Static).update, text))

    class ConsoleApp(App):
        """The live console (see the module doc)."""

        CSS = """
        Screen { layout: vertical; }
        #head { height: 1; background: $primary; color: $text; }
        #cols { height: auto; }
        #left, #right { width: 1fr; height: auto; }
        .pane { height: auto; padding: 0 1; }
        #log { height: 1fr; min-height: 3; border-top: solid $primary; }
        """
        BINDINGS = [Binding("f", "faults", "fault panel"), Binding("q", "quit", "quit")]

        def __init__(self, run: Path, interface: str = "socketcan", channel: str = "vcan0",
                     vehicle: str | None = None, period_s: float = 0.1,
                     timeout_s: float = 5.0, title_note: str = "") -> None:
            super().__init__()
            self.title_note = title_note
            self.run_dir, self.period_s = Path(run), period_s
            self.interface, self.channel, self.vehicle = interface, channel, vehicle
            self.timeout_s = timeout_s
            self.model, self.follow = attach(self.run_dir)
            self.render_ms: deque[float] = deque(maxlen=500)  # refresh cost per update
            self.shown_events = 0
            self.acks: list[str] = []

        def compose(self) -> ComposeResult:
            yield Static(id="head")
            with Horizontal(id="cols"):
                with Vertical(id="left"):
                    yield Static(id="attitude", classes="pane")
                    yield Static(id="residuals", classes="pane")
                    yield Static(id="fdir", classes="pane")
                with Vertical(id="right"):
                    yield Static(id="thrusters", classes="pane")
                    yield Static(id="timing", classes="pane")
            yield Log(id="log", max_lines=EVENT_LINES)
            yield Footer()

        def on_mount(self) -> None:
            self.title = f"hil console {self.run_dir}"
            self.sub_title = self.title_note
            self.refresh_view(force=True)
            self.set_interval(self.period_s, self.refresh_view)

        def refresh_view(self, force: bool = False) -> None:
            from textual.css.query import NoMatches

            try:
                self._refresh_view(force)
            except NoMatches:  # a timer tick while the app closes: the panes are gone
                pass

        def _refresh_view(self, force: bool) -> None:
            t0 = time.perf_counter()
            changed = self.model.feed(*self.follow.read())
            if not (changed or force):
                return
            m = self.model
            for wid, text in (("head", m.header()), ("attitude", m.attitude()),
                              ("fdir", m.fdir()), ("residuals", m.residuals()),
                              ("thrusters", m.thrusters()), ("timing", m.timing())):
                # Text, not markup: names and bars keep their spaces and brackets.
                self.query_one(f"#{wid}", Static).update(Text(text, no_wrap=True,
                                                              overflow="ellipsis"))
            new = min(m.events_total - self.shown_events, len(m.events))
            if new > 0:
                self.query_one("#log", Log).write_lines(list(m.events)[-new:])
            self.shown_events = m.events_total
            self.render_ms.append((time.perf_counter() - t0) * 1e3)

        def action_faults(self) -> None:
            self.push_screen(FaultPanel(self))

        def list_text(self) -> str:
            from hil.panel import fault_table

            active = self.model.active_faults()
            names = ", ".join(self.model.config.get("thrusters") or [])
            return (f"thrusters {names}\n" + ("\n".join(fault_table(active)) if active
                                               else "no fault active"))

        def send_fault(self, action, thruster, kind, fraction, at, done) -> None:
            """Build and send in a worker thread; ``done(text)`` gets the panel's line."""
            def work() -> None:
                text = fault_request(self.run_dir, action, thruster, kind, fraction, at,
                                     self.vehicle, self.interface, self.channel,
                                     self.timeout_s)
                self.acks.append(text)
                self.call_from_thread(self.query_one("#log", Log).write_line, f"panel: {text}")
                done(text)

            self.run_worker(work, thread=True, exclusive=False)

    return ConsoleApp, FaultPanel


def fault_request(run: Path, action: str, thruster: str | None, kind: str | None,
                  fraction: float | None, at: float | None, vehicle: str | None,
                  interface: str, channel: str, timeout_s: float) -> str:
    """One panel request as `hil fault` makes it; the line `hil fault` would print."""
    from hil.errors import HilError
    from hil.panel import _request_id, ack_line, build_command, deliver, resolve_vehicle

    try:
        v, _ = resolve_vehicle(vehicle, Path(run))
        cmd = build_command(v, action, thruster, kind, fraction, at, None, _request_id())
        ack = deliver(cmd, Path(run), "auto", interface, channel, timeout_s)
    except HilError as exc:
        return f"error: {exc}"
    return ack_line(ack, action, kind, thruster, v.name)


def _cmd(args) -> int:
    from hil.errors import UsageError

    run = Path(args.run)
    if not run.is_dir():
        raise UsageError(f"hil console: --run: expected the run folder of a running system "
                         f"(the --out of hil up), got {run}: no such folder")
    ConsoleApp, _ = _app_classes()
    app = ConsoleApp(run, args.interface, args.channel, args.vehicle)
    app.run()
    if app.render_ms:
        ms = sorted(app.render_ms)
        print(f"hil console: refresh cost per update p50 {ms[len(ms) // 2]:.2f} ms, max "
              f"{ms[-1]:.2f} ms over {len(ms)} updates (this process)")
    return 0


def register(sub) -> None:
    import argparse

    summary = "live console of a running system (hil up): attitude, residuals, thrusters, " \
              "FDIR, timing, events, and the fault panel"
    p = sub.add_parser("console", help=summary, description=summary,
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog="""examples:
  hil up --out runs/up &                 (or in another terminal)
  hil console                            attach to runs/up; f: fault panel, q: quit
  hil console --run runs/other

It reads the run folder as it grows, inside or outside user-mode Linux; it fits 80x24.""")
    p.add_argument("--run", default="runs/up", help="run folder (the --out of hil up)")
    p.add_argument("--vehicle", help="vehicle to check thruster names against (default: the "
                                     "one the plant flies)")
    p.add_argument("--interface", default="socketcan",
                   help="bus for the fault panel when the run has no panel bridge")
    p.add_argument("--channel", default="vcan0")
    p.set_defaults(func=_cmd)
