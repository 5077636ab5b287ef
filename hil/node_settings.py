"""The settings of a plant or flight process: one typed, frozen object made from its command line.

``python -m hil.nodes NODE --scenario S.yaml --out DIR ...`` (``build_parser``) gives a
``NodeSettings``; the shells read it and nothing mutates it. What the process learns at
start-up about its scheduling (``sched_note``, ``rt_event``) is added with
``dataclasses.replace`` before the shell is built.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, fields
from typing import Literal

from bus.catalog import CATALOG, HEARTBEAT_PERIOD_S

# Real time: THR_CMD(n) takes effect this long after its tick's gyro sample went out
# (time-triggered actuation, docs/design.md section 3; 0: on arrival, --actuation-phase-ms 0).
# Sample-to-command is 4-9 ms typically inside user-mode Linux with bursts of 20-35 ms; on
# arrival, kalman_cube read those bursts as thrust errors (S002-15/50/100 in real time).
REALTIME_ACTUATION_PHASE_MS = 30.0
# A phase must leave the command inside its frame's deadline (half a tick).
ACTUATION_PHASE_MAX_MS = 1000.0 * CATALOG.frame("THR_CMD_0").deadline_s


@dataclass(frozen=True)
class NodeSettings:
    """One process's settings (the flags of ``build_parser``; units in the names).

    ``lost_after``, ``heartbeat_lost_s``, ``gyro_lost_after``: None keeps the scenario's
    ``safety:`` value. ``sched_note``: the scheduler policy the process got (first record);
    ``rt_event``: the event line of a ``--rt-priority`` request.
    """

    node: Literal["plant", "flight"]
    scenario: str
    out: str
    mode: Literal["lockstep", "realtime"] = "lockstep"
    interface: str = "socketcan"
    channel: str = "vcan0"
    reply_timeout: float = 2.0
    lost_after: int | None = None
    heartbeat_lost_s: float | None = None
    gyro_lost_after: int | None = None
    gyro_wait_ms: float = 50.0
    release_offset_ms: float = -2.0
    align_samples: int = 3
    rt_priority: bool = False
    sched: Literal["auto", "other", "batch"] = "auto"
    bus_log: bool = False
    telemetry_url: str | None = None
    start_after: str | None = None
    key_file: str | None = None
    actuation_phase_ms: float | None = None
    sched_note: str | None = None
    rt_event: str | None = None

    def actuation_phase_s(self) -> float:
        """When THR_CMD(n) takes effect after its tick's sample is out, s (0: on arrival).

        ``--actuation-phase-ms``, else ``REALTIME_ACTUATION_PHASE_MS`` in real time and 0 in
        lockstep. Plant and flight get the same value (the flight's onboard model adds it to
        its command latency)."""
        if self.actuation_phase_ms is not None:
            return self.actuation_phase_ms / 1000.0
        return REALTIME_ACTUATION_PHASE_MS / 1000.0 if self.mode == "realtime" else 0.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> NodeSettings:
        return cls(**{f.name: getattr(args, f.name) for f in fields(cls)
                      if hasattr(args, f.name)})


def parse_settings(argv: list[str] | None = None) -> NodeSettings:
    """``NodeSettings`` from a node's command line (argparse errors exit 2)."""
    return NodeSettings.from_args(build_parser().parse_args(argv))


def _ticks(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {n}")
    return n


def actuation_phase_ms(text: str) -> float:
    """``--actuation-phase-ms``: finite, 0 <= x < the THR_CMD deadline."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected milliseconds, got {text!r}") from None
    if not (math.isfinite(x) and 0.0 <= x < ACTUATION_PHASE_MAX_MS):
        raise argparse.ArgumentTypeError(
            f"expected 0 <= ms < {ACTUATION_PHASE_MAX_MS:g} (the THR_CMD deadline), got {text}")
    return x


def _heartbeat_s(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not x > HEARTBEAT_PERIOD_S:
        raise argparse.ArgumentTypeError(
            f"expected > the heartbeat period {HEARTBEAT_PERIOD_S:g} s, got {x:g}")
    return x


ACTUATION_PHASE_HELP = (
    f"THR_CMD(n) takes effect MS after tick n's gyro sample went out, whenever it arrived "
    f"before (time-triggered; a later one is applied on arrival, counted as late, and its tick "
    f"kept out of the FDIR evidence); the flight's onboard model assumes the same; 0: on "
    f"arrival (default: {REALTIME_ACTUATION_PHASE_MS:g} in real time, 0 in lockstep)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m hil.nodes",
                                description="The plant or flight process of the HIL.")
    p.add_argument("node", choices=("plant", "flight"))
    p.add_argument("--scenario", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--reply-timeout", type=float, default=2.0,
                   help="lockstep: wall seconds the plant waits for THR_CMD(n) (generous: a "
                        "loaded machine must not change a lockstep run; once the flight is "
                        "declared lost the wait drops to 50 ms per tick)")
    p.add_argument("--lost-after", type=_ticks,
                   help="ticks without THR_CMD before the plant closes every valve "
                        "(default: the scenario's safety.thr_cmd_lost_ticks, 3)")
    p.add_argument("--heartbeat-lost-s", type=_heartbeat_s,
                   help="real time: seconds of flight heartbeat silence before the plant "
                        "closes every valve (default: safety.heartbeat_lost_s, 1.5)")
    p.add_argument("--gyro-lost-after", type=_ticks,
                   help="ticks without a valid gyro sample before the flight's safe mode "
                        "(default: safety.gyro_lost_ticks, 3)")
    p.add_argument("--gyro-wait-ms", type=float, default=50.0,
                   help="real time: longest wait after a release for the tick's gyro sample "
                        "(default 50 ms, a quarter of the tick)")
    p.add_argument("--release-offset-ms", type=float, default=-2.0,
                   help="real time: flight release relative to the earliest observed gyro "
                        "arrival (default -2 ms: already waiting when the sample comes, and "
                        "awake between the plant's pre-wake and its sample)")
    p.add_argument("--align-samples", type=int, default=3,
                   help="real time: gyro samples observed to place the flight's tick grid")
    p.add_argument("--rt-priority", action="store_true", help="try SCHED_FIFO and mlockall")
    p.add_argument("--actuation-phase-ms", type=actuation_phase_ms, metavar="MS",
                   help=ACTUATION_PHASE_HELP)
    p.add_argument("--sched", choices=("auto", "other", "batch"), default="auto",
                   help="scheduler policy without --rt-priority (auto: plant SCHED_BATCH, "
                        "flight SCHED_OTHER, see hil.process_policy.set_policy)")
    p.add_argument("--bus-log", action="store_true", help="write NODE.bus.log (candump format)")
    p.add_argument("--telemetry-url", metavar="URL",
                   help="publish each tick's record on LCM at URL (HIL_TRUTH from the plant, "
                        "HIL_FLIGHT_VIEW from the flight; docs/lcm.md)")
    p.add_argument("--key-file", metavar="FILE",
                   help="SecOC key (mode 0600, made by hil run / hil up): THR_CMD, "
                        "FAULT_CMD, GYRO, SYNC and heartbeats are signed and checked; without "
                        "it they are not")
    p.add_argument("--start-after", metavar="FILE",
                   help="set up, then wait until FILE exists before the first tick (hil run "
                        "starts both processes at once and gives the plant the flight's "
                        "ready file: their start-ups overlap, the first SYNC finds the flight "
                        "listening)")
    return p
