"""Run recording: per-tick JSON lines from each process, and the rerun recording built from them.

Each process appends one JSON object per tick to its own file in the run directory
(``plant.jsonl``: the truth; ``flight.jsonl``: the flight software's view) and flushes it at
once, so a killed process leaves every tick up to the kill on disk. The rerun recording
(``run.rrd``) puts both on one timeline (``tick`` sequence and ``sim_time`` duration);
``build_rrd`` makes it from the JSON lines after the run (``hil run``), and with a live viewer
(``hil up --viewer``) the supervisor appends what the processes wrote every 50 ms instead.

A record is ``{"tick": n, "t_s": t, "series": {path: {label: value, ...}}, "events": [...]}``.
Every series becomes one rerun entity holding one scalar per label (one line per label in the
time-series view). Entity paths (documented in the README):

========================================  ====================================================
``truth/omega_deg_s``                     true rigid body rate x, y, z relative to the orbit frame
``truth/omega_BI_deg_s``                  true rigid body rate x, y, z, inertial (as the gyro)
``truth/attitude_error_deg``              true attitude error about x, y, z (plant)
``truth/thrust_n``                        actual thrust of every thruster (plant)
``truth/flex_gyro_deg_s``                 the flex modes' rate at the gyro (plant)
``timing/s2a_ms``                         sensor-to-actuator latency of the tick (plant, real time)
``flight/omega_meas_deg_s``               gyro rate as received (flight)
``flight/omega_est_deg_s``                observer's rigid rate estimate (flight)
``flight/omega_pred_deg_s``               onboard model's one-tick prediction (flight)
``flight/attitude_error_deg``             estimated attitude error (flight)
``flight/residual_deg_s``                 residual w_obs - w_calc (flight)
``flight/rho_on`` / ``flight/rho_off``    integral residuals per thruster (flight)
``flight/thresholds``                     +threshold_off and -threshold_on (flight)
``flight/on_ms``                          commanded on-time per thruster, THR_CMD (flight)
``flight/compute_ms``                     per-stage compute time (flight)
``timing/flight_ms``                      release jitter, gyro wait and compute (flight, real time)
``events/plant``, ``events/flight``       faults, detections, safe states, overruns (text log)
========================================  ====================================================
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any


class OutputLost(OSError):
    """A record could not be written (disk full, read-only file system, I/O error); the file
    ends with the last whole record (``JsonlWriter.write``)."""


class JsonlWriter:
    """Append-only JSON lines file, one object per tick, each line one ``write(2)``.

    A whole line goes to the kernel in a single system call, so a process killed with
    SIGKILL (the reliability check) leaves whole lines behind, except that the kernel may stop
    a write between two pages of the file when the signal comes inside it: the last line can be
    torn then (seen once in CI, a flight killed at 10 s), and ``read_jsonl`` drops it. When the
    write fails part way (ENOSPC, EIO, EROFS) the file is cut back to its last whole line and
    ``OutputLost`` raised: a full disk leaves no torn line either.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self._size = os.fstat(self._fd).st_size  # end of the last whole line

    def write(self, record: dict[str, Any]) -> None:
        if self._fd is None:
            raise ValueError(f"{self.path}: write after close")
        data = (json.dumps(record, separators=(",", ":"), allow_nan=True) + "\n").encode()
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._fd, view):]
        except OSError as exc:
            try:
                os.ftruncate(self._fd, self._size)
            except OSError:
                pass  # nothing more can be done for this file
            raise OutputLost(exc.errno, f"{self.path}: {exc.strerror}") from exc
        self._size += len(data)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def read_jsonl(path: Path) -> Iterator[dict[str, Any]]:
    """Read a JSON lines file; a torn last line (process killed mid-write) is ignored."""
    path = Path(path)
    if not path.exists():
        return
    with path.open(encoding="utf-8") as f:
        for line in f:
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                return


class RrdRecorder:
    """Log records to a rerun ``.rrd`` file.

    :meth:`log_batch` sends what the processes wrote since the last call column by column (one
    ``send_columns`` per entity and batch: a row-by-row ``log`` costs about 0.3 ms per entity
    and tick, which in lockstep took more CPU than the flight software); :meth:`flush` after
    each batch.
    """

    def __init__(self, path: Path, recording_id: str, application_id: str = "thruster_hil") -> None:
        import rerun as rr  # imported here: only the recorder needs the viewer SDK

        self._rr = rr
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(str(path))
        self._declared: dict[str, tuple[str, ...]] = {}

    def spawn_viewer(self) -> None:
        self.rec.spawn(connect=True)

    def log(self, source: str, record: dict[str, Any]) -> None:
        """One record (:meth:`log_batch` of one)."""
        self.log_batch([(source, record)])

    def log_batch(self, items: Iterable[tuple[str, dict[str, Any]]]) -> None:
        """Records ``(source, record)`` in tick order: series as columns, events as text logs."""
        import numpy as np

        rr, rec = self._rr, self.rec
        cols: dict[tuple[str, tuple[str, ...]], tuple[list, list, list]] = {}
        events: list[tuple[str, int, float, str]] = []
        for source, record in items:
            tick, t_s = int(record["tick"]), float(record["t_s"])
            for path, values in record.get("series", {}).items():
                labels = tuple(values)
                ticks, times, rows = cols.setdefault((path, labels), ([], [], []))
                ticks.append(tick)
                times.append(t_s)
                rows.append([float(values[k]) for k in labels])
            for text in record.get("events", []):
                events.append((source, tick, t_s, text))
        for (path, labels), (ticks, times, rows) in cols.items():
            if self._declared.get(path) != labels:
                rec.log(path, rr.SeriesLines(names=list(labels)), static=True)
                self._declared[path] = labels
            rr.send_columns(
                path,
                indexes=[rr.TimeColumn("tick", sequence=ticks),
                         rr.TimeColumn("sim_time", duration=times)],
                columns=rr.Scalars.columns(scalars=np.asarray(rows, dtype=float)),
                recording=rec,
            )
        for source, tick, t_s, text in events:
            rec.set_time("tick", sequence=tick)
            rec.set_time("sim_time", duration=t_s)
            warn = any(w in text for w in ("fault", "overrun", "safe", "lost"))
            rec.log(f"events/{source}", rr.TextLog(text, level="WARN" if warn else "INFO"))

    def flush(self) -> None:
        self.rec.flush(timeout_sec=5.0)

    def close(self) -> None:
        """Flush and end the recording (the file gets its footer; ``rerun rrd verify``)."""
        self.flush()
        self.rec.disconnect()


def build_rrd(run_dir: Path, out: Path | None = None, recording_id: str | None = None) -> Path:
    """Rebuild ``run.rrd`` from the run's JSON lines (plant and flight merged by tick)."""
    run_dir = Path(run_dir)
    out = out or run_dir / "run.rrd"
    if out.exists():
        out.unlink()
    rec = RrdRecorder(out, recording_id or run_dir.name)
    rec.log_batch(merge_by_tick(
        ("plant", read_jsonl(run_dir / "plant.jsonl")),
        ("flight", read_jsonl(run_dir / "flight.jsonl")),
    ))
    rec.close()
    return out


def merge_by_tick(*streams: tuple[str, Iterable[dict[str, Any]]]) -> Iterator[tuple[str, dict]]:
    """Interleave (source, records) streams by tick; within a tick, the given source order."""
    items = []
    for order, (source, records) in enumerate(streams):
        for r in records:
            items.append((int(r["tick"]), order, source, r))
    items.sort(key=lambda x: (x[0], x[1]))
    for _, _, source, r in items:
        yield source, r
