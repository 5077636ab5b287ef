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


def maybe_in_uml(args, argv: list[str]) -> int | None:
    """Re-run this command inside user-mode Linux when socketcan has no vcan here."""
    if args.interface != "socketcan" or os.environ.get(INSIDE_UML_ENV):
        return None
    if _vcan_ready(args.channel):
        return None
    from hil.uml import run_in_uml

    print("hil: this kernel has no CAN; running inside user-mode Linux (real vcan0 there)",
          flush=True)
    env = dict(os.environ, **{INSIDE_UML_ENV: "1"})
    return run_in_uml([sys.executable, "-m", "hil.cli", *argv], env=env, cwd=os.getcwd())


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
    """Logs every frame on the bus to a candump file (a passive third node)."""

    def __init__(self, interface: str, channel: str, path: Path) -> None:
        super().__init__(daemon=True)
        import can

        from bus.transport import BusConfig, open_bus

        self.bus = open_bus(BusConfig(interface=interface, channel=channel))
        self.writer = can.CanutilsLogWriter(str(path), channel=channel)
        self.frames = 0
        self.error: str | None = None  # why bus.log stopped (disk full...), None if it did not
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            m = self.bus.recv(0.1)
            if m is not None and self.error is None:
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


def _node_cmd(node: str, scenario: Path, out: Path, args,
              start_after: Path | None = None) -> list[str]:
    cmd = [sys.executable, "-m", "hil.nodes", node, "--scenario", str(scenario),
           "--out", str(out), "--mode", args.mode, "--interface", args.interface,
           "--channel", args.channel, "--key-file", str(out / KEY_FILE)]
    if start_after is not None:
        cmd += ["--start-after", str(start_after)]
    if getattr(args, "rt_priority", False):
        cmd.append("--rt-priority")
    return cmd


def _wait_ready(path: Path, proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
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
                 "flight.ready", "bus.log"):
        (out / name).unlink(missing_ok=True)
    new_key_file(out)  # this run's SecOC key (hil.secoc_key), for the nodes and the panel
    monitor = BusMonitor(args.interface, args.channel, out / "bus.log")
    monitor.start()
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
    killed_flight_at = getattr(args, "kill_flight_at", None)
    killed: dict[str, tuple[float, float]] = {}
    interrupted = False
    try:
        procs["flight"] = subprocess.Popen(_node_cmd("flight", scenario_path, out, args),
                                           stdout=logs["flight"], stderr=subprocess.STDOUT,
                                           env=env, cwd=REPO_ROOT)
        # Both start at once (their imports and set-up overlap); the plant's first tick waits
        # for the flight's ready file, so the first SYNC finds the flight listening.
        procs["plant"] = subprocess.Popen(
            _node_cmd("plant", scenario_path, out, args, start_after=out / "flight.ready"),
            stdout=logs["plant"], stderr=subprocess.STDOUT, env=env, cwd=REPO_ROOT)
        _wait_ready(out / "flight.ready", procs["flight"])
        _wait_ready(out / "plant.ready", procs["plant"])
        tails = {"plant": _Tail(out / "plant.jsonl"), "flight": _Tail(out / "flight.jsonl")}
        last_print = 0.0
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
            if not quiet and now - last_print > 2.0 and new:
                tick = max((r["tick"] for s, r in new if s == "plant"), default=0)
                print(f"  {sc.cfg.name}: tick {tick}/{n_ticks} "
                      f"({tick * sc.vehicle.timing.tick_s:.0f} s simulated, "
                      f"{now - t_wall:.0f} s wall)", flush=True)
                last_print = now
            if done:
                break
            time.sleep(0.05)
    except KeyboardInterrupt:
        interrupted = True
        print("hil: interrupted, stopping the processes", file=sys.stderr)
    finally:
        for p in procs.values():
            _stop(p)
        monitor.stop()
        for f in logs.values():
            f.close()
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
               "exit_codes": {k: p.returncode for k, p in procs.items()},
               "timing": timing_summary(plant_records, flight_records,
                                        sc.vehicle.timing.tick_s),
               "where": "user-mode Linux" if os.environ.get(INSIDE_UML_ENV) else "native"},
        expected_ticks=None if endless else n_ticks,
        exit_codes={k: p.returncode for k, p in procs.items()}, killed=killed,
        interrupted=interrupted and not endless, io_error="; ".join(io_errors) or None,
    )
    write_summary(out, summary)
    return summary


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
        print(f"  missed: {f['type']} {f['thruster']} at {f['t_s']:.1f} s")
    print(f"  compute ms p50/p99/max: {s['compute_ms']['p50']}/{s['compute_ms']['p99']}/"
          f"{s['compute_ms']['max']}, overruns {s['overruns']}")
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


def _cmd_run(args) -> int:
    scenario = Path(args.scenario)
    sc = load_scenario(scenario)  # config errors exit 2 before anything starts
    out = Path(args.out or Path("runs") / sc.cfg.name)
    check_writable(out)  # before user-mode Linux boots
    argv = ["run", str(scenario.resolve()), "--mode", args.mode, "--out", str(out.resolve()),
            "--interface", args.interface, "--channel", args.channel]
    if args.kill_flight_at is not None:
        argv += ["--kill-flight-at", str(args.kill_flight_at)]
    if args.rt_priority:
        argv.append("--rt")
    rc = maybe_in_uml(args, argv)
    if rc is not None:
        return rc
    _batch_policy()
    s = supervise(scenario.resolve(), out.resolve(), args)
    _print_verdict(s, out)
    return EXIT_CODES[s["verdict"]]


def _cmd_up(args) -> int:
    check_writable(Path(args.out or "runs/up"))  # before anything is made or boots
    if args.scenario:
        scenario = Path(args.scenario).resolve()
        load_scenario(scenario)  # config errors exit 2 before anything starts
    else:
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
    rc = maybe_in_uml(args, argv)
    if rc is not None:
        return rc
    _batch_policy()
    s = supervise(scenario, out, args, viewer=args.viewer, endless=True)
    _print_verdict(s, out)
    return 0


def _bus_args(p) -> None:
    p.add_argument("--rt", dest="rt_priority", action="store_true",
                   help="ask SCHED_FIFO and locked memory for flight (50) and plant (40); the "
                        "nodes say in their first events what they got")
    p.add_argument("--interface", default="socketcan",
                   help="python-can interface (default socketcan; udp_multicast, pcan, ...)")
    p.add_argument("--channel", default="vcan0", help="bus channel (default vcan0)")


def register(sub) -> None:
    p = sub.add_parser("run", help="run a scenario over the bus and judge it (exit 0/1/2)")
    p.add_argument("scenario", metavar="SCENARIO.yaml")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--out", metavar="DIR", help="output folder (default runs/<scenario name>)")
    p.add_argument("--kill-flight-at", type=number(ge=0, le=MAX_DURATION_S), metavar="T",
                   help="SIGKILL the flight process at simulated time T (safe-state check)")
    _bus_args(p)
    p.set_defaults(func=_cmd_run)

    u = sub.add_parser("up", help="bring plant and flight up until Ctrl-C (inject with hil fault)")
    u.add_argument("--vehicle", default="generic")
    u.add_argument("--scenario", help="scenario file instead of a bare vehicle")
    u.add_argument("--mode", choices=("realtime", "lockstep"), default="realtime")
    u.add_argument("--duration", type=number(gt=0, le=MAX_DURATION_S), default=3600.0,
                   help="seconds (default 3600)")
    u.add_argument("--out", metavar="DIR", help="output folder (default runs/up)")
    u.add_argument("--viewer", action="store_true", help="open the rerun viewer live")
    u.add_argument("--kill-flight-at", type=number(ge=0, le=MAX_DURATION_S),
                   help=argparse_suppress())
    _bus_args(u)
    u.set_defaults(func=_cmd_up)


def argparse_suppress() -> str:
    import argparse

    return argparse.SUPPRESS
