"""`hil run` and `hil up`: start the plant and flight processes on the bus, record, judge.

``hil run SCENARIO.yaml [--mode lockstep|realtime] [--out DIR]`` runs a scenario to its end
and writes ``DIR/summary.json``, ``DIR/bus.log`` (candump format: every frame on the bus,
replayable with ``canplayer`` or ``python -m can.player``), ``DIR/run.rrd`` (rerun: truth and
the flight's view on one timeline, built from the JSON lines after the run),
``DIR/plant.jsonl`` / ``DIR/flight.jsonl`` (per tick) and the processes' logs. Exit 0 when
the scenario's expectations hold, 1 when not, 2 on a usage or configuration error, 3 when the
run itself failed (a process died or stopped early, ticks were lost: ``hil.verdict``),
whatever its expectations say.

``hil up [--vehicle V | --scenario S] [--mode realtime|lockstep] [--viewer]`` brings the
system up until Ctrl-C (or ``--duration``); faults are injected with ``hil fault``.

Where the bus is socketcan and the kernel has no CAN, the whole command re-runs itself inside
user-mode Linux (``hil.uml``), which sees the same files: the outputs land on the host's disk.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from hil.argtypes import number
from hil.config import MAX_DURATION_S, REPO_ROOT, load_scenario
from hil.errors import BusError, UsageError
from hil.lcm_replay import LOG_NAME
from hil.panel_bridge import control_dir, request_stop, stop_path
from hil.recorder import RrdRecorder, build_rrd, merge_by_tick, read_jsonl
from hil.secoc_key import KEY_FILE, new_key_file
from hil.summary import summarise
from hil.timing import timing_summary
from hil.verdict import EXIT_CODES, EXIT_RUN_FAILED

INSIDE_UML_ENV = "HIL_INSIDE_UML"


def _vcan_ready(channel: str) -> bool:
    from hil.vcan import ensure_vcan, vcan_present

    if vcan_present(channel):
        return True
    try:
        ensure_vcan(channel)
    except Exception:  # noqa: BLE001 - any failure means: not natively
        return False
    return vcan_present(channel)


def maybe_in_uml(args, argv: list[str], out: Path | None = None) -> int | None:
    """Re-run this command inside user-mode Linux when socketcan has no vcan here.

    ``out``: the run folder; Ctrl-C or SIGTERM here then asks the supervisor inside to stop
    through it (``hil.panel_bridge.request_stop``) and waits for it to write its result, as
    natively; a second Ctrl-C, or no end within ``STOP_GRACE_S``, stops UML at once."""
    if args.interface != "socketcan" or os.environ.get(INSIDE_UML_ENV):
        return None
    if _vcan_ready(args.channel):
        return None
    from hil.uml import run_in_uml

    print("hil: this kernel has no CAN; running inside user-mode Linux (real vcan0 there)",
          flush=True)
    env = dict(os.environ, **{INSIDE_UML_ENV: "1"})
    on_interrupt = None
    if out is not None:
        def on_interrupt(why: str) -> None:
            print(f"hil: {why}; asking the run inside user-mode Linux to stop and write its "
                  f"result", file=sys.stderr, flush=True)
            request_stop(out, why)
    with stop_on_signals():
        return run_in_uml([sys.executable, "-m", "hil.cli", *argv], env=env, cwd=os.getcwd(),
                          on_interrupt=on_interrupt, interrupt_grace_s=STOP_GRACE_S)


STOP_GRACE_S = 30.0  # how long an interrupted run inside UML gets to write its result


class _Tail:
    """Follow a JSON lines file as it grows (only whole lines)."""

    def __init__(self, path: Path) -> None:
        self.path, self.pos, self.buf = path, 0, ""

    def read(self) -> list[dict]:
        if not self.path.exists():
            return []
        with self.path.open(encoding="utf-8") as f:
            f.seek(self.pos)
            chunk = f.read()
            self.pos = f.tell()
        self.buf += chunk
        *lines, self.buf = self.buf.split("\n")
        out = []
        for line in lines:
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                pass
        return out


class BusMonitor(threading.Thread):
    """Logs every frame on the bus to a candump file (a passive third node).

    Every frame is marked received (``R``): the monitor sends nothing (SocketCAN reports the
    frames of other sockets of the same host as local, which python-can would write as ``T``).
    With ``sim_time`` (lockstep) the stamps are simulated time, not the wall clock: a frame is
    stamped with the time of the last SYNC the monitor heard (its ``sim_time_ms``) plus 1 us
    per frame since that SYNC, so the log keeps the bus order and spans the simulated
    duration (``cantools plot``, ``python -m can.player`` then show the run's own time base).
    Frames before the first SYNC count from 0. In real time the stamps are the kernel's.
    """

    FRAME_STEP_S = 1e-6  # between frames of one tick in a simulated-time log

    def __init__(self, interface: str, channel: str, path: Path, sim_time: bool = False) -> None:
        super().__init__(daemon=True)
        import can

        from bus.transport import BusConfig, open_bus

        self.bus = open_bus(BusConfig(interface=interface, channel=channel))
        self.writer = can.CanutilsLogWriter(str(path), channel=channel)
        self.frames = 0
        self.error: str | None = None  # why bus.log stopped (disk full...), None if it did not
        self._halt = threading.Event()
        self.sim_time = sim_time
        self._sync_s, self._since_sync = 0.0, 0

    def _stamp(self, m) -> None:
        """Received, and in simulated time when asked (see the class doc)."""
        from bus.catalog import CATALOG, SYNC_ID
        from bus.codec import range_problem, unpack

        m.is_rx = True
        if not self.sim_time:
            return
        if m.arbitration_id == SYNC_ID and not m.is_error_frame and len(m.data) == 8:
            f = CATALOG.frame("SYNC")
            raws = unpack(f, bytes(m.data))
            if range_problem(f, raws) is None:  # a SYNC failing its checks is not used
                self._sync_s, self._since_sync = raws["sim_time_ms"] / 1000.0, 0
        m.timestamp = self._sync_s + self._since_sync * self.FRAME_STEP_S
        self._since_sync += 1

    def run(self) -> None:
        while not self._halt.is_set():
            m = self.bus.recv(0.1)
            if m is not None and self.error is None:
                self._stamp(m)
                try:
                    self.writer.on_message_received(m)
                except OSError as exc:  # the bus log is lost from here; the run goes on
                    self.error = f"bus.log: {exc.strerror or exc}"
                    continue
                self.frames += 1

    def stop(self) -> None:
        self._halt.set()
        self.join(2.0)
        try:
            self.writer.stop()
        except OSError as exc:
            self.error = self.error or f"bus.log: {exc.strerror or exc}"
        self.bus.shutdown()


class LcmMonitor(threading.Thread):
    """``bus.log`` of an LCM run: every HIL_* message of the bus as the CAN frames it stands
    for (candump format, decodable with ``bus/hil.dbc``), plus the LCM bytes seen."""

    def __init__(self, url: str, path: Path) -> None:
        super().__init__(daemon=True)
        import can

        from bus.lcm_schema import by_channel
        from bus.lcm_transport import open_lcm

        self.lc = open_lcm(url)
        self.structs = by_channel()
        self.writer = can.CanutilsLogWriter(str(path), channel="lcm")
        self.frames = 0
        self.lcm_messages = 0
        self.lcm_bytes = 0
        self.error: str | None = None
        self._halt = threading.Event()
        self.lc.subscribe(r"HIL_.*", self._on)

    def _on(self, channel: str, data: bytes) -> None:
        from bus.lcm_schema import decode_struct, to_frames
        from bus.transport import to_can_message

        st = self.structs.get(channel)
        if st is None:
            return
        self.lcm_messages += 1
        self.lcm_bytes += len(data)
        if self.error is not None:
            return
        try:
            frames = to_frames(st, decode_struct(st, data))
        except (ValueError, KeyError, TypeError, OverflowError):
            return  # the nodes count it; the log keeps what is frames
        t = time.time()
        try:
            for fr in frames:
                self.writer.on_message_received(to_can_message(fr, t))
                self.frames += 1
        except OSError as exc:
            self.error = f"bus.log: {exc.strerror or exc}"

    def run(self) -> None:
        while not self._halt.is_set():
            self.lc.handle_timeout(100)

    def stop(self) -> None:
        self._halt.set()
        self.join(2.0)
        try:
            self.writer.stop()
        except OSError as exc:
            self.error = self.error or f"bus.log: {exc.strerror or exc}"


def _monitor(args, path: Path, sim_time: bool = False):
    """The bus.log writer of this bus (over LCM the stamps stay the wall clock's)."""
    if args.interface == "lcm":
        return LcmMonitor(args.channel, path)
    return BusMonitor(args.interface, args.channel, path, sim_time=sim_time)


def resolve_bus(args, sc=None) -> None:
    """``--bus`` / the scenario's ``bus:`` -> ``args.interface`` / ``args.channel`` (LCM is
    carried as interface ``lcm`` with the URL as its channel, through every layer)."""
    from bus.lcm_transport import DEFAULT_URL

    kind = getattr(args, "bus", None)
    url = getattr(args, "lcm_url", None)
    cfg_bus = sc.cfg.bus if sc is not None else None
    if kind is None and cfg_bus is not None:
        kind = cfg_bus.kind
        url = url or cfg_bus.url
    if kind == "lcm":
        # --interface / --channel name a python-can bus: over LCM they would be ignored.
        # (Interface ``lcm`` is how a re-run in a namespace or user-mode Linux carries LCM.)
        for flag, val in (("--interface", args.interface), ("--channel", args.channel)):
            if val is not None and args.interface != "lcm":
                raise UsageError(f"{flag}: expected no python-can {flag[2:]} with the lcm bus "
                                 f"(--lcm-url names its provider), got {val!r}")
        args.interface, args.channel = "lcm", url or DEFAULT_URL
    elif url is not None and not (getattr(args, "telemetry", None)
                                  or getattr(args, "lcm_log", False)):
        with_ = ("--bus lcm, --telemetry or --lcm-log" if hasattr(args, "telemetry")
                 else "--bus lcm")
        raise UsageError(f"--lcm-url: expected it with {with_}, got {url!r} with the "
                         f"{kind or 'can'} bus alone")
    args.interface = args.interface or "socketcan"
    args.channel = args.channel or "vcan0"
    # Telemetry (hil.telemetry): always over an LCM bus, on request over CAN.
    if args.interface == "lcm":
        args.telemetry = args.channel
    elif getattr(args, "telemetry", None) or getattr(args, "lcm_log", False):
        args.telemetry = url or (args.telemetry if isinstance(getattr(args, "telemetry", None),
                                                              str) else DEFAULT_URL)
    else:
        args.telemetry = None


def _lcm_argv(args) -> list[str]:
    """The bus and telemetry flags for a re-run (namespace, user-mode Linux): an LCM run goes
    as interface ``lcm`` with its URL as the channel; a CAN run says ``--bus can``, so that a
    scenario naming LCM is not turned back to it there."""
    out = ["--telemetry", args.telemetry] if args.telemetry and args.interface != "lcm" else []
    out += ["--bus", "can"] if args.interface != "lcm" else []
    return out + (["--lcm-log"] if getattr(args, "lcm_log", False) else [])


def maybe_in_netns(args, argv: list[str]) -> int | None:
    """Re-run this command in a private network namespace for LCM over udpm (hil.netns):
    the LCM bus, or the telemetry of a CAN run. SocketCAN's vcan0 lives in the host's (or
    user-mode Linux's) namespace, so a SocketCAN run keeps its namespace: inside user-mode
    Linux the route goes on the instance's loopback; natively the host needs its own."""
    if args.telemetry is None:
        return None
    from hil.netns import NETNS_ENV, host_has_multicast_route, run_in_namespace

    if args.interface == "socketcan" and not os.environ.get(INSIDE_UML_ENV):
        if not _vcan_ready(args.channel) or os.environ.get(NETNS_ENV):
            return None  # user-mode Linux next: its own loopback gets the route
        if not host_has_multicast_route(args.telemetry):
            raise BusError(f"--telemetry: LCM {args.telemetry} over the host's vcan0 needs "
                           "a multicast route on the host, got none (hil never adds one "
                           "there); use --interface udp_multicast, or a kernel without CAN")
        print("hil: LCM telemetry on the host's multicast route (vcan0 is in the host's "
              "network namespace)", flush=True)
        os.environ[NETNS_ENV] = "host"
        return None
    return run_in_namespace(argv, args.telemetry, cwd=os.getcwd())


LCM_LOG = LOG_NAME  # DIR/run.lcmlog (hil.lcm_replay reads it back)
RUN_END_CHANNEL = "HIL_RUN_END"
LOGGER_FLUSH_MS = 100
LOGGER_NICE = -10


def _log_counts(path: Path) -> dict[str, int] | None:
    """The telemetry messages ``run.lcmlog`` holds per channel (None: unreadable), beside
    the ticks of the JSON lines: a log short of them lost messages on the way."""
    from hil.lcm_replay import CHANNELS, count_log

    try:
        counts = count_log(path)
    except UsageError:
        return None
    return {ch: counts[ch] for ch in CHANNELS}


def _start_lcm_logger(args, out: Path) -> subprocess.Popen:
    """LCM's own ``lcm-logger`` on the run's URL, writing ``DIR/run.lcmlog`` (every HIL_*
    channel: the control bus when it is LCM, and the telemetry)."""
    from hil.lcm_cmd import lcm_tool

    (out / LCM_LOG).unlink(missing_ok=True)
    p = subprocess.Popen([lcm_tool("lcm-logger"), "--lcm-url", args.telemetry, "--channel",
                          "HIL_.*", "--flush-interval", str(LOGGER_FLUSH_MS), "--force",
                          "--quiet", str(out / LCM_LOG)],
                         stdout=subprocess.DEVNULL, stderr=(out / "lcm-logger.log").open("w"))
    # A logger starved of CPU loses what overflows its socket's receive buffer (about 75
    # telemetry messages; 5 ticks lost in 1 of 3 lockstep runs with the CPUs busy): where
    # allowed (root) it gets a higher priority than the nodes. It uses little CPU.
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, p.pid, LOGGER_NICE)
    t_end = time.monotonic() + 10
    while not (out / LCM_LOG).exists():  # subscribed once its file is open
        if p.poll() is not None or time.monotonic() > t_end:
            raise BusError(f"lcm-logger did not start (exit {p.poll()}); see "
                           f"{out / 'lcm-logger.log'}")
        time.sleep(0.02)
    return p


LOGGER_END_WAIT_S = 10.0


def _marker_in_log(path: Path) -> bool:
    """True when the end of ``path`` holds a ``HIL_RUN_END`` event (written and flushed)."""
    try:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - 65536))
            return RUN_END_CHANNEL.encode() in f.read()
    except OSError:
        return False


def _stop_lcm_logger(p: subprocess.Popen, url: str, path: Path) -> None:
    """Stop lcm-logger with every message of the run in its file. lcm-logger flushes its
    file when it writes an event a flush interval after the last flush, and does not flush
    what it holds on SIGINT: so a marker (``HIL_RUN_END``, no payload) goes out every flush
    interval until one is in the file (up to ``LOGGER_END_WAIT_S``), and only then the
    signal. Under load the logger can be a second behind the run (its socket holds the
    backlog): a fixed two markers then lost the run's last ticks from the file."""
    from bus.lcm_transport import open_lcm

    lc = open_lcm(url)
    t_end = time.monotonic() + LOGGER_END_WAIT_S
    while True:
        time.sleep(1.2 * LOGGER_FLUSH_MS / 1000)
        lc.publish(RUN_END_CHANNEL, b"")
        if _marker_in_log(path) or time.monotonic() > t_end or p.poll() is not None:
            break
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _phase_argv(args) -> list[str]:
    """``--actuation-phase-ms`` for a re-run of the command (user-mode Linux, a namespace)."""
    ms = getattr(args, "actuation_phase_ms", None)
    return [] if ms is None else ["--actuation-phase-ms", repr(ms)]


def _node_cmd(node: str, scenario: Path, out: Path, args,
              start_after: Path | None = None) -> list[str]:
    cmd = [sys.executable, "-m", "hil.nodes", node, "--scenario", str(scenario),
           "--out", str(out), "--mode", args.mode, "--interface", args.interface,
           "--channel", args.channel, "--key-file", str(out / KEY_FILE)]
    if start_after is not None:
        cmd += ["--start-after", str(start_after)]
    if getattr(args, "telemetry", None):
        cmd += ["--telemetry-url", args.telemetry]
    if getattr(args, "rt_priority", False):
        cmd.append("--rt-priority")
    return cmd + _phase_argv(args)


# A node's start (imports, the cores' set-up, the bus) inside user-mode Linux on a loaded
# machine took over 30 s once (a fresh clone, nothing compiled yet); a node that dies is seen
# at once, so the limit only bounds a hang.
READY_TIMEOUT_S = 90.0


def _wait_ready(path: Path, proc: subprocess.Popen, timeout_s: float = READY_TIMEOUT_S) -> None:
    t_end = time.monotonic() + timeout_s
    while not path.exists():
        if proc.poll() is not None:
            raise BusError(f"{path.stem} process exited with {proc.returncode} before it was "
                           f"ready; see {path.with_suffix('.log')}")
        if time.monotonic() > t_end:
            raise BusError(f"{path.stem} process not ready after {timeout_s:.0f} s")
        time.sleep(0.02)


def _stop(proc: subprocess.Popen, grace_s: float = 3.0) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def supervise(scenario_path: Path, out: Path, args, *, viewer: bool = False,
              quiet: bool = False, endless: bool = False) -> dict:
    """Start flight then plant, follow them until the plant ends, stop all, write outputs.

    ``endless`` (``hil up``): the run ends when the operator stops it, so an interruption
    or an unreached duration is not a failure of the run."""
    sc = load_scenario(scenario_path)
    n_ticks = int(round(sc.cfg.duration_s / sc.vehicle.timing.tick_s))
    out.mkdir(parents=True, exist_ok=True)
    for name in ("plant.jsonl", "flight.jsonl", "run.rrd", "summary.json", "plant.ready",
                 "flight.ready", "bus.log", "netns.pid"):
        (out / name).unlink(missing_ok=True)
    reset_control(out)  # stale requests or a stop request of an earlier run in this folder
    new_key_file(out)  # this run's SecOC key (hil.secoc_key), for the nodes and the panel
    monitor = _monitor(args, out / "bus.log", sim_time=args.mode == "lockstep")
    monitor.start()
    logger = _start_lcm_logger(args, out) if getattr(args, "lcm_log", False) else None
    if args.interface == "lcm":
        from hil.netns import write_pid

        write_pid(out)
    # The rerun recording is built from the JSON lines after the run (``build_rrd``): logging it
    # live cost the supervisor more CPU than the flight software used, in the middle of the
    # lockstep loop, and importing the SDK delayed the start. Live only when a viewer is asked.
    rrd = None
    if viewer:
        rrd = RrdRecorder(out / "run.rrd", recording_id=f"{sc.cfg.name}")
        rrd.spawn_viewer()
    logs = {n: (out / f"{n}.log").open("w") for n in ("flight", "plant")}
    procs: dict[str, subprocess.Popen] = {}
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    t_wall = time.monotonic()
    stop_file = stop_path(out)
    killed_flight_at = getattr(args, "kill_flight_at", None)
    killed: dict[str, tuple[float, float]] = {}
    interrupted: str | None = None  # what ended the run before its end (a signal, a request)
    try:
        procs["flight"] = subprocess.Popen(_node_cmd("flight", scenario_path, out, args),
                                           stdout=logs["flight"], stderr=subprocess.STDOUT,
                                           env=env, cwd=REPO_ROOT)
        # Both start at once (their imports and set-up overlap); the plant's first tick waits
        # for the flight's ready file, so the first SYNC finds the flight listening.
        procs["plant"] = subprocess.Popen(
            _node_cmd("plant", scenario_path, out, args, start_after=out / "flight.ready"),
            stdout=logs["plant"], stderr=subprocess.STDOUT, env=env, cwd=REPO_ROOT)
        if endless:  # hil up: the fault panel's way in through the run folder (hil.panel_bridge)
            logs["panel"] = (out / "panel.log").open("w")
            procs["panel"] = subprocess.Popen(
                [sys.executable, "-m", "hil.panel_server", "--run", str(out),
                 "--interface", args.interface, "--channel", args.channel],
                stdout=logs["panel"], stderr=subprocess.STDOUT, env=env, cwd=REPO_ROOT)
        _wait_ready(out / "flight.ready", procs["flight"])
        _wait_ready(out / "plant.ready", procs["plant"])
        tails = {"plant": _Tail(out / "plant.jsonl"), "flight": _Tail(out / "flight.jsonl")}
        last_print, plant_tick = 0.0, 0
        while True:
            done = procs["plant"].poll() is not None
            new = [(s, r) for s, r in merge_by_tick(("plant", tails["plant"].read()),
                                                     ("flight", tails["flight"].read()))]
            if rrd is not None:
                rrd.log_batch(new)
            for source, r in new:
                if not quiet:
                    for e in r.get("events", []):
                        print(f"  t={r['t_s']:7.1f} s  {source}: {e}", flush=True)
                if source == "plant" and killed_flight_at is not None and \
                        r["t_s"] >= killed_flight_at and procs["flight"].poll() is None:
                    procs["flight"].kill()  # SIGKILL: the reliability check of docs/design.md 10
                    killed["flight"] = (killed_flight_at, round(float(r["t_s"]), 3))
                    print(f"  t={r['t_s']:7.1f} s  hil: flight process killed (SIGKILL)",
                          flush=True)
            if new and rrd is not None:
                rrd.flush()
            now = time.monotonic()
            # The plant's newest tick so far (a batch may hold flight records only).
            plant_tick = max((r["tick"] for s, r in new if s == "plant"), default=plant_tick)
            if not quiet and now - last_print > 2.0 and new:
                tick = plant_tick
                print(f"  {sc.cfg.name}: tick {tick}/{n_ticks} "
                      f"({tick * sc.vehicle.timing.tick_s:.0f} s simulated, "
                      f"{now - t_wall:.0f} s wall)", flush=True)
                last_print = now
            if done:
                break
            if stop_file.exists():  # the host's Ctrl-C or SIGTERM, through the run folder
                interrupted = _stop_reason(stop_file)
                print(f"hil: {interrupted}, stopping the processes", file=sys.stderr, flush=True)
                break
            time.sleep(0.05)
    except KeyboardInterrupt as exc:
        interrupted = str(exc) or "interrupted (SIGINT)"
        print(f"hil: {interrupted}, stopping the processes", file=sys.stderr, flush=True)
    finally:
        # A second Ctrl-C or SIGTERM must not cut the clean-up that keeps the run's result.
        old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)} \
            if threading.current_thread() is threading.main_thread() else {}
        for p in procs.values():
            _stop(p)
        monitor.stop()
        if logger is not None:
            _stop_lcm_logger(logger, args.telemetry, out / LCM_LOG)
        for f in logs.values():
            f.close()
        if rrd is not None:
            rrd.close()
    io_errors = [monitor.error] if monitor.error else []
    if rrd is None:
        try:
            build_rrd(out, recording_id=sc.cfg.name)
        except (OSError, RuntimeError) as exc:  # rerun reports I/O errors as RuntimeError
            io_errors.append(f"run.rrd: {getattr(exc, 'strerror', None) or exc}")
    # Everything the processes wrote, up to their last tick (also after a kill).
    plant_records = list(read_jsonl(out / "plant.jsonl"))
    flight_records = list(read_jsonl(out / "flight.jsonl"))
    wall = time.monotonic() - t_wall
    sim = plant_records[-1]["t_s"] if plant_records else 0.0
    summary = summarise(
        scenario=sc.cfg.name, vehicle=sc.vehicle.name, mode=args.mode,
        plant_records=[r for r in plant_records if not r.get("final")] or plant_records,
        flight_records=flight_records, expect=sc.cfg.expect,
        extra={"wall_s": round(wall, 3), "sim_s": sim,
               **speed_figures(plant_records, sim, wall, t_wall),
               "bus_frames_logged": monitor.frames,
               **({"bus_kind": "lcm", "lcm_url": args.channel,
                   "lcm_messages_logged": monitor.lcm_messages,
                   "lcm_bytes_logged": monitor.lcm_bytes,
                   "network": os.environ.get("HIL_LCM_NETNS", "host")}
                  if args.interface == "lcm" else {"bus_kind": "can"}),
               "telemetry": getattr(args, "telemetry", None),
               **({"lcm_log": LCM_LOG, "lcm_log_telemetry": _log_counts(out / LCM_LOG)}
                  if getattr(args, "lcm_log", False) else {}),
               "exit_codes": {k: p.returncode for k, p in procs.items()},
               "timing": timing_summary(plant_records, flight_records,
                                        sc.vehicle.timing.tick_s),
               "where": ("user-mode Linux" if os.environ.get(INSIDE_UML_ENV) else "native")
               + (f", LCM: {os.environ.get('HIL_LCM_NETNS', 'host')} network"
                  if args.interface == "lcm" else "")},
        expected_ticks=None if endless else n_ticks,
        exit_codes={k: p.returncode for k, p in procs.items()}, killed=killed,
        interrupted=bool(interrupted) and not endless, io_error="; ".join(io_errors) or None,
    )
    # An interrupted run keeps its result: the ticks done are in ``ticks``, what ended it here.
    summary["interrupted"] = bool(interrupted)
    summary["interrupted_by"] = interrupted
    write_summary(out, summary)
    for s, handler in old.items():
        signal.signal(s, handler)
    return summary


def reset_control(out: Path) -> None:
    """Empty ``out/control`` (``hil.panel_bridge``) before a run starts in ``out``."""
    d = control_dir(out)
    if d.is_dir():
        for f in d.iterdir():
            with contextlib.suppress(OSError):
                f.unlink()


def _stop_reason(stop_file: Path) -> str:
    try:
        return str(json.loads(stop_file.read_text()).get("why") or "stop requested")
    except (OSError, ValueError, AttributeError):
        return "stop requested"


class _Signalled(KeyboardInterrupt):
    """SIGTERM (``timeout``, ``kill``) handled as Ctrl-C: the run stops and keeps its result."""


@contextlib.contextmanager
def stop_on_signals():
    """SIGINT and SIGTERM raise ``KeyboardInterrupt`` naming the signal, for the duration."""
    def handler(signum, _frame):
        raise _Signalled(f"interrupted ({signal.Signals(signum).name})")

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def write_summary(out: Path, summary: dict) -> None:
    """``summary.json`` whole or not at all (written beside, then renamed). When it cannot be
    written (disk full, read-only), the run is failed with that reason and the summary goes
    to stderr as one JSON line, so the verdict is never lost."""
    path = out / "summary.json"
    tmp = out / ".summary.json.tmp"
    try:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        reason = f"output could not be written: summary.json: {exc.strerror or exc}"
        summary["run_failures"] = [*summary["run_failures"], reason]
        summary["expectations_met"] = False
        summary["verdict"] = "run_failed"
        print(f"hil: {reason}; the summary follows on stderr", file=sys.stderr)
        print(json.dumps(summary, separators=(",", ":")), file=sys.stderr)


def check_writable(out: Path) -> None:
    """Before anything boots: the output folder exists or can be made, and takes a file."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".hil-write-probe-{os.getpid()}"
        with probe.open("wb") as f:
            f.write(b"x" * 4096)
            f.flush()
            os.fsync(f.fileno())
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"{out}: expected a folder the run can write to, got "
                         f"{exc.strerror or exc}") from None


SPEED_BASIS = ("simulated seconds per wall second of the plant's loop, its first tick to its "
               "last: start-up (process start to the first tick) and shut-down excluded; "
               "end_to_end_x_realtime includes them")


def speed_figures(plant_records: list[dict], sim_s: float, wall_s: float,
                  t_start_monotonic_s: float) -> dict:
    """The summary's speed: ``speed_x_realtime`` over the plant's loop only (``SPEED_BASIS``),
    ``startup_s`` from the start of ``supervise`` to the plant's first tick (CLOCK_MONOTONIC is
    shared by the processes of one kernel), and the end-to-end figure beside them."""
    final = next((r for r in reversed(plant_records) if r.get("final")), {})
    loop = final.get("wall_s")
    t0 = final.get("loop_t0_monotonic_s")
    return {
        "speed_x_realtime": round(sim_s / loop, 2) if loop else None,
        "speed_basis": SPEED_BASIS,
        "loop_wall_s": loop,
        "startup_s": round(t0 - t_start_monotonic_s, 3) if t0 is not None else None,
        "end_to_end_x_realtime": round(sim_s / wall_s, 2) if wall_s > 0 else None,
    }


def _print_verdict(s: dict, out: Path) -> None:
    speed = (f"{s['speed_x_realtime']}x real time in the loop (start-up {s.get('startup_s')} s "
             f"excluded; {s.get('end_to_end_x_realtime')}x end to end, {s['wall_s']} s wall)"
             if "end_to_end_x_realtime" in s else f"{s['speed_x_realtime']}x real time")
    print(f"{s['scenario']} ({s['vehicle']}, {s['mode']}, {s['where']}): "
          f"{s['ticks']} ticks, {speed}")
    for d in s["detections"]:
        lat = f"{d['latency_s']:.1f} s" if d["latency_s"] is not None else "-"
        print(f"  detection: {d['type']} {d['thruster']} at {d['t_s']:.1f} s, latency {lat}, "
              f"{'correct' if d['correct'] else 'WRONG'}")
    for f in s["missed_faults"]:
        print(f"  missed: {f['type']} {f['thruster'] or 'the gyro'} at {f['t_s']:.1f} s")
    print(f"  compute ms p50/p99/max: {s['compute_ms']['p50']}/{s['compute_ms']['p99']}/"
          f"{s['compute_ms']['max']}, overruns {s['overruns']}")
    logged = s.get("lcm_log_telemetry")
    if logged is not None and min(logged.values()) < s["ticks"]:
        print(f"  run.lcmlog: telemetry of {min(logged.values())} of {s['ticks']} ticks "
              f"({logged}; lcm-logger lost the rest)")
    for line in s["run_failures"]:
        print(f"  RUN FAILED: {line}")
    for line in s["expectation_failures"]:
        print(f"  FAILED: {line}")
    if s["verdict"] == "run_failed":
        print(f"  run FAILED (exit {EXIT_RUN_FAILED}): its expectations cannot be judged; "
              f"outputs in {out}")
    else:
        print(f"  expectations {'met' if s['expectations_met'] else 'NOT met'}; "
              f"outputs in {out}")


def _batch_policy() -> None:
    """The supervisor runs SCHED_BATCH so it does not preempt a flight tick on one CPU (the
    nodes set their own policy)."""
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))


def scenario_path(arg: str, option: str = "SCENARIO") -> Path:
    """A scenario file, or the name of one in ``configs/scenarios`` (``S000-stuck``), as
    vehicles are named; a name that is neither gets the list of names."""
    from hil.config import SCENARIO_DIR

    p = Path(arg)
    if p.exists() or p.suffix in (".yaml", ".yml"):
        return p
    named = SCENARIO_DIR / f"{arg}.yaml"
    if named.exists():
        return named
    raise UsageError(f"{option}: expected a scenario file or one of "
                     f"{sorted(q.stem for q in SCENARIO_DIR.glob('*.yaml'))}, got {arg!r}")


def _cmd_run(args) -> int:
    scenario = scenario_path(args.scenario, "hil run: SCENARIO")
    sc = load_scenario(scenario)  # config errors exit 2 before anything starts
    resolve_bus(args, sc)
    out = Path(args.out or Path("runs") / sc.cfg.name)
    check_writable(out)  # before user-mode Linux boots
    argv = ["run", str(scenario.resolve()), "--mode", args.mode, "--out", str(out.resolve()),
            "--interface", args.interface, "--channel", args.channel]
    if args.kill_flight_at is not None:
        argv += ["--kill-flight-at", str(args.kill_flight_at)]
    if args.rt_priority:
        argv.append("--rt")
    argv += _phase_argv(args)
    argv += _lcm_argv(args)
    rc = maybe_in_netns(args, argv)
    if rc is None:
        rc = maybe_in_uml(args, argv, out.resolve())
    if rc is not None:
        return rc
    _batch_policy()
    with stop_on_signals():
        s = supervise(scenario.resolve(), out.resolve(), args)
    _print_verdict(s, out)
    return EXIT_CODES[s["verdict"]]


def _cmd_up(args) -> int:
    check_writable(Path(args.out or "runs/up"))  # before anything is made or boots
    if args.scenario:
        scenario = scenario_path(args.scenario, "hil up: --scenario").resolve()
        resolve_bus(args, load_scenario(scenario))  # config errors exit 2 before anything
    else:
        resolve_bus(args)
        from hil.config import VEHICLE_DIR

        if not (VEHICLE_DIR / f"{args.vehicle}.yaml").exists():
            raise UsageError(f"hil up: --vehicle: expected one of "
                             f"{sorted(p.stem for p in VEHICLE_DIR.glob('*.yaml'))}, "
                             f"got {args.vehicle!r}")
        tmp = Path(tempfile.mkdtemp(prefix="hil-up-", dir=Path(args.out).parent
                                    if args.out else None))
        scenario = tmp / "up.yaml"
        scenario.write_text(yaml.safe_dump({"name": f"up-{args.vehicle}",
                                            "vehicle": args.vehicle,
                                            "duration_s": float(args.duration)}))
    out = Path(args.out or "runs/up").resolve()
    argv = ["up", "--scenario", str(scenario), "--mode", args.mode, "--out", str(out),
            "--interface", args.interface, "--channel", args.channel]
    if args.rt_priority:
        argv.append("--rt")
    argv += _phase_argv(args)
    argv += _lcm_argv(args)
    if getattr(args, "console", False):
        return _up_with_console(argv + ["--duration", str(args.duration)], out)
    feed = None
    if args.viewer or args.web:  # fed from here, also when the run is inside UML
        from hil.live_viewer import LiveViewer, find_viewer

        if args.viewer:
            find_viewer()  # one line and exit 2 before anything boots when it is missing
        feed = LiveViewer(out, recording_id=scenario.stem, web=args.web)
        if feed.url:
            print(f"hil: web viewer at {feed.url}", flush=True)
        feed.start()
    try:
        rc = maybe_in_netns(args, argv)
        if rc is None:
            rc = maybe_in_uml(args, argv, out)
        if rc is not None:
            return rc
        _batch_policy()
        with stop_on_signals():
            s = supervise(scenario, out, args, endless=True)
    finally:
        if feed is not None:
            feed.stop()
    _print_verdict(s, out)
    return 0


def _up_with_console(argv: list[str], out: Path) -> int:
    """``hil up --console``: the run in a child ``hil up`` (its output to ``out/up.log``), the
    console in this terminal; quitting the console stops the run as Ctrl-C does, and its
    verdict lines are printed here."""
    from hil.console import _app_classes

    log_path = out / "up.log"
    out.mkdir(parents=True, exist_ok=True)
    (out / "plant.jsonl").unlink(missing_ok=True)  # the console must not show an old run
    with log_path.open("w") as log:
        child = subprocess.Popen([sys.executable, "-m", "hil.cli", "up", *argv[1:]],
                                 stdout=log, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        app_cls, _ = _app_classes()
        app_cls(out, title_note=f"hil up output: {log_path}").run()
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGINT)
        try:
            rc = child.wait(STOP_GRACE_S + 30)
        except subprocess.TimeoutExpired:
            os.killpg(child.pid, signal.SIGKILL)
            rc = child.wait()
    lines = log_path.read_text().splitlines()
    start = max((i for i, x in enumerate(lines) if " ticks, " in x and "(" in x), default=None)
    for line in lines[start:] if start is not None else lines[-15:]:
        print(line)
    return rc


def _bus_args(p) -> None:
    from hil.node_settings import ACTUATION_PHASE_HELP, actuation_phase_ms

    p.add_argument("--rt", dest="rt_priority", action="store_true",
                   help="ask SCHED_FIFO and locked memory for flight (50) and plant (40); the "
                        "nodes say in their first events what they got")
    p.add_argument("--actuation-phase-ms", type=actuation_phase_ms, metavar="MS",
                   help=ACTUATION_PHASE_HELP)
    p.add_argument("--interface",
                   help="python-can interface (default socketcan; udp_multicast, pcan, ...)")
    p.add_argument("--channel", help="bus channel (default vcan0)")
    p.add_argument("--bus", choices=("can", "lcm"),
                   help="the bus: can (python-can --interface/--channel, the default) or lcm "
                        "(docs/lcm.md; default: the scenario's bus:, else can)")
    p.add_argument("--lcm-url", metavar="URL",
                   help="LCM provider with --bus lcm, --telemetry or --lcm-log (default "
                        "udpm://239.255.76.67:7667?ttl=0, in a private network namespace)")
    p.add_argument("--telemetry", nargs="?", const=True, default=None, metavar="URL",
                   help="publish truth and the flight's view per tick on LCM (HIL_TRUTH, "
                        "HIL_FLIGHT_VIEW; always on with --bus lcm) whatever the bus")
    p.add_argument("--lcm-log", action="store_true",
                   help="record every HIL_* LCM channel with lcm-logger to DIR/run.lcmlog "
                        "(turns --telemetry on)")


RUN_EPILOG = """examples:
  hil run S000-stuck                     a reference scenario by name (configs/scenarios)
  hil run my.yaml --mode realtime        a scenario file, real time
  hil run S000-stuck --out runs/a        then: hil report runs/a

exit codes: 0 expectations met, 1 not met, 2 usage/configuration error, 3 the run failed.
Ctrl-C or SIGTERM stops the run and keeps its result (summary.json marked interrupted)."""

UP_EPILOG = """examples:
  hil up                                 the generic vehicle in real time, until Ctrl-C
  hil up --vehicle orel --out runs/up    then, in another terminal:
  hil console                            watch it (and inject from its fault panel)
  hil fault inject --thruster X+ --type stuck_on
  hil report runs/up                     after Ctrl-C: the verdict of what ran

Where the kernel has no CAN the processes run inside user-mode Linux; hil fault and hil
console reach them through the run folder (--out)."""


def _help(sub, name: str, summary: str, epilog: str):
    import argparse

    return sub.add_parser(name, help=summary, description=summary, epilog=epilog,
                          formatter_class=argparse.RawDescriptionHelpFormatter)


def register(sub) -> None:
    p = _help(sub, "run", "run a scenario over the bus and judge it against its expectations",
              RUN_EPILOG)
    p.add_argument("scenario", metavar="SCENARIO",
                   help="a scenario file, or the name of one in configs/scenarios")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--out", metavar="DIR", help="output folder (default runs/<scenario name>)")
    p.add_argument("--kill-flight-at", type=number(ge=0, le=MAX_DURATION_S), metavar="T",
                   help="SIGKILL the flight process at simulated time T (safe-state check)")
    _bus_args(p)
    p.set_defaults(func=_cmd_run)

    u = _help(sub, "up", "bring plant and flight up until Ctrl-C; watch with hil console, inject "
                         "with hil fault", UP_EPILOG)
    u.add_argument("--vehicle", default="generic")
    u.add_argument("--scenario", help="scenario file or name instead of a bare vehicle")
    u.add_argument("--mode", choices=("realtime", "lockstep"), default="realtime")
    u.add_argument("--duration", type=number(gt=0, le=MAX_DURATION_S), default=3600.0,
                   help="seconds (default 3600)")
    u.add_argument("--out", metavar="DIR", help="output folder (default runs/up)")
    u.add_argument("--viewer", action="store_true",
                   help="open the rerun viewer (.venv/bin/rerun) fed live from the run folder")
    u.add_argument("--console", action="store_true",
                   help="show hil console in this terminal (the run's output goes to "
                        "OUT/up.log); quitting it (q) stops the run")
    u.add_argument("--web", action="store_true",
                   help="serve the rerun web viewer on 127.0.0.1 (port 9090), print its URL")
    u.add_argument("--kill-flight-at", type=number(ge=0, le=MAX_DURATION_S),
                   help=argparse_suppress())
    _bus_args(u)
    u.set_defaults(func=_cmd_up)


def argparse_suppress() -> str:
    import argparse

    return argparse.SUPPRESS
