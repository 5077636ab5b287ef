"""A run's LCM telemetry log back into per-tick records (docs/lcm.md, "Replay").

``hil run --lcm-log`` leaves ``RUN/run.lcmlog``, written by LCM's own ``lcm-logger``: one
``hil_telemetry.truth_t`` (``HIL_TRUTH``) and one ``flight_view_t`` (``HIL_FLIGHT_VIEW``)
per tick (``hil.telemetry``). ``replay`` plays the log with LCM's own ``lcm-logplayer`` onto
an LCM URL and listens there: every message becomes the record it was made from, as
``plant.jsonl`` / ``flight.jsonl`` hold it, for what the telemetry carries:

* plant: ``tick``, ``t_s``, ``att_err_deg``, ``rate_err_deg_s``, ``fuel_kg``, ``dv_B_m_s``,
  ``safe``, ``series`` (every entity and label of ``run.rrd``) and ``events``;
* flight: ``tick``, ``t_s``, ``compute_s``, ``overruns``, ``safe``, ``detection`` (``tick``,
  ``t_s``, ``thruster``, ``type``, ``source``, ``rho``), ``series`` and ``events``.

Not carried, so not rebuilt: the faults as fields (``faults_injected``; their events are),
the FDIR block, the bus counters, the command gate, a degraded detection's fraction, the
last line's loop figures, and series values that were null. The recording (``run.rrd``) and
the report's plots need only ticks, series and events, so ``hil record --from-lcm-log`` and
``hil report --from-lcm-log`` make them as from the JSON lines; the report's table still comes
from ``summary.json``.

The replay is checked whole: the messages received are counted against the log's own (read
with ``lcm.EventLog``), and a shortfall (a receive buffer overrun at a high ``--speed``) is a
one-line error, never a quiet gap. ``read_log`` decodes the log directly, without a network.
"""

from __future__ import annotations

import math
import struct
import subprocess
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.errors import BusError, UsageError
from hil.telemetry import FLIGHT_CHANNEL, TRUTH_CHANNEL

CHANNELS = (TRUTH_CHANNEL, FLIGHT_CHANNEL)
LOG_NAME = "run.lcmlog"  # what hil run --lcm-log writes in the run folder
# Without --speed the log is paced to this many telemetry messages per second: a lockstep
# log holds a tick every few milliseconds, and played at its own pace (or faster) its
# messages (about 2.7 kB each) came faster than the listener decodes them and a few were lost
# in the socket's buffer (2 of 300 once at 20x); at 300 per second a 30 s run replays in 1 s.
PACE_MSG_S = 300.0
QUIET_S = 0.5  # after lcm-logplayer exits: no message for this long ends the listening


def _series(names: Iterable[str], values: Iterable[float]) -> dict[str, dict[str, float]]:
    """``entity/label`` pairs back into ``{entity: {label: value}}`` (every entity path is two
    components, ``truth/omega_deg_s``; a label may hold a ``/``)."""
    out: dict[str, dict[str, float]] = {}
    for name, v in zip(names, values, strict=True):
        parts = name.split("/", 2)
        if len(parts) != 3:
            raise ValueError(f"series name {name!r}: expected entity/label")
        out.setdefault(f"{parts[0]}/{parts[1]}", {})[parts[2]] = float(v)
    return out


def _finite(x: float) -> bool:
    return not math.isnan(x)


def plant_record(m) -> dict[str, Any]:
    """The ``plant.jsonl`` fields of one ``truth_t`` (see the module doc)."""
    rec: dict[str, Any] = {"tick": int(m.tick), "t_s": float(m.t_s)}
    for key in ("att_err_deg", "rate_err_deg_s", "fuel_kg"):
        v = float(getattr(m, key))
        if _finite(v):
            rec[key] = v
    dv = [float(x) for x in m.dv_B_m_s]
    if any(_finite(x) for x in dv):
        rec["dv_B_m_s"] = dv
    rec["safe"] = bool(m.safe)
    rec["series"] = _series(m.names, m.values)
    rec["events"] = list(m.events)
    return rec


def flight_record(m) -> dict[str, Any]:
    """The ``flight.jsonl`` fields of one ``flight_view_t`` (see the module doc)."""
    rec: dict[str, Any] = {"tick": int(m.tick), "t_s": float(m.t_s), "detection": None}
    if m.detection_type:
        names = m.detection_thruster.split("|") if m.detection_thruster else []
        rec["detection"] = {
            "t_s": float(m.t_s), "tick": int(m.tick),
            "thruster": (names[0] if len(names) == 1 else names) if names else None,
            "type": m.detection_type, "source": m.detection_source,
            "rho": float(m.detection_rho)}
    if m.compute_s >= 0:
        rec["compute_s"] = float(m.compute_s)
    rec["overruns"] = int(m.overruns)
    rec["safe"] = bool(m.safe)
    rec["series"] = _series(m.names, m.values)
    rec["events"] = list(m.events)
    return rec


@dataclass
class Records:
    """The records rebuilt from a log, in the order received, and where they came from."""

    plant: list[dict[str, Any]] = field(default_factory=list)
    flight: list[dict[str, Any]] = field(default_factory=list)
    how: str = ""
    malformed: int = 0  # messages on the channels that are not their struct

    def add(self, channel: str, data: bytes) -> None:
        from hil.hil_telemetry import flight_view_t, truth_t

        try:
            if channel == TRUTH_CHANNEL:
                self.plant.append(plant_record(truth_t.decode(data)))
            elif channel == FLIGHT_CHANNEL:
                self.flight.append(flight_record(flight_view_t.decode(data)))
        except (ValueError, struct.error, UnicodeDecodeError):
            self.malformed += 1

    def sorted(self) -> Records:
        """By tick (a replay keeps the log's order; this makes it independent of it)."""
        return Records(sorted(self.plant, key=lambda r: r["tick"]),
                       sorted(self.flight, key=lambda r: r["tick"]), self.how, self.malformed)


def _check_log(path: Path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: expected an LCM log (hil run --lcm-log writes "
                         f"RUN/run.lcmlog), got {'a folder' if path.is_dir() else 'no such file'}")
    return path


def count_log(path: Path) -> dict[str, int]:
    """Telemetry messages per channel in the log, read with ``lcm.EventLog``; ``span_s``: the
    time from the first to the last of them."""
    import lcm

    path = _check_log(path)
    counts = dict.fromkeys(CHANNELS, 0)
    stamps: list[int] = []
    try:
        for ev in lcm.EventLog(str(path), "r"):
            if ev.channel in counts:
                counts[ev.channel] += 1
                stamps.append(ev.timestamp)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: expected an LCM log, got unreadable events ({exc})") from None
    if not any(counts.values()):
        raise UsageError(f"{path}: expected {TRUTH_CHANNEL} / {FLIGHT_CHANNEL} telemetry "
                         f"(hil run --lcm-log), got none in the log")
    return {**counts, "span_s": (max(stamps) - min(stamps)) / 1e6}


def paced_speed(counts: dict[str, int]) -> float:
    """lcm-logplayer's speed that plays the log at about ``PACE_MSG_S`` messages per second."""
    n = sum(counts[ch] for ch in CHANNELS)
    return max(counts["span_s"] * PACE_MSG_S / n, 0.01)


def read_log(path: Path) -> Records:
    """The records of the log read directly with ``lcm.EventLog`` (no network)."""
    import lcm

    path = _check_log(path)
    out = Records(how=f"{path.name} read with lcm.EventLog")
    for ev in lcm.EventLog(str(path), "r"):
        if ev.channel in CHANNELS:
            out.add(ev.channel, ev.data)
    if out.malformed:
        raise UsageError(f"{path}: expected only telemetry structs on {TRUTH_CHANNEL} / "
                         f"{FLIGHT_CHANNEL}, got {out.malformed} other message(s)")
    return out.sorted()


def replay(path: Path, url: str, speed: float | None = None,
           timeout_s: float = 3600.0) -> Records:
    """Play ``path`` with ``lcm-logplayer`` on ``url`` (telemetry channels only; ``speed``
    None: ``paced_speed``) and rebuild the records from what arrives; ``BusError`` when
    messages were lost on the way."""
    from bus.lcm_transport import open_lcm
    from hil.lcm_cmd import lcm_tool

    path = _check_log(path)
    want = count_log(path)
    speed = paced_speed(want) if speed is None else speed
    lc = open_lcm(url)
    out = Records(how=f"{path.name} replayed by lcm-logplayer at {speed:.3g}x on {url}")
    for ch in CHANNELS:
        sub = lc.subscribe(ch, out.add)
        sub.set_queue_capacity(want[ch] + 16)  # LCM's default keeps 30
    player = subprocess.Popen([lcm_tool("lcm-logplayer"), "--lcm-url", url, "--speed",
                               repr(speed), "--regexp", f"^({'|'.join(CHANNELS)})$",
                               str(path)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    t_end = time.monotonic() + timeout_s
    try:
        while player.poll() is None:
            lc.handle_timeout(50)
            if time.monotonic() > t_end:
                raise BusError(f"replay: lcm-logplayer {path}: expected it to end within "
                               f"{timeout_s:.0f} s, got still playing (raise --speed)")
        quiet_end = time.monotonic() + QUIET_S
        while time.monotonic() < quiet_end:
            if lc.handle_timeout(50) > 0:
                quiet_end = time.monotonic() + QUIET_S
    finally:
        if player.poll() is None:
            player.kill()
        player.wait()
    if player.returncode != 0:
        err = (player.stderr.read() if player.stderr else "").strip().splitlines()
        raise BusError(f"replay: lcm-logplayer {path}: expected exit 0, got "
                       f"{player.returncode} ({err[-1] if err else 'no message'})")
    got = {TRUTH_CHANNEL: len(out.plant), FLIGHT_CHANNEL: len(out.flight)}
    if out.malformed:
        raise BusError(f"replay: {path}: expected only telemetry structs on {TRUTH_CHANNEL} / "
                       f"{FLIGHT_CHANNEL}, got {out.malformed} other message(s)")
    if any(got[ch] != want[ch] for ch in CHANNELS):
        raise BusError(f"replay: {path}: expected {want[TRUTH_CHANNEL]} {TRUTH_CHANNEL} and "
                       f"{want[FLIGHT_CHANNEL]} {FLIGHT_CHANNEL} messages, got "
                       f"{got[TRUTH_CHANNEL]} and {got[FLIGHT_CHANNEL]} (lost on the way at "
                       f"--speed {speed:.3g}: try a lower one)")
    return out.sorted()


def write_records(records: Records, out: Path) -> None:
    """``out/plant.jsonl`` and ``out/flight.jsonl`` of the rebuilt records."""
    from hil.recorder import JsonlWriter

    out.mkdir(parents=True, exist_ok=True)
    for name, recs in (("plant", records.plant), ("flight", records.flight)):
        (out / f"{name}.jsonl").unlink(missing_ok=True)
        w = JsonlWriter(out / f"{name}.jsonl")
        try:
            for r in recs:
                w.write(r)
        finally:
            w.close()
