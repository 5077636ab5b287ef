"""Run a campaign's runs as tasks on Dask distributed, write one row per run as it arrives.

Each task is one in-process lockstep run (``hil.sim.simulate``) of run k's scenario files,
written by ``hil.campaign.expansion.write_run`` into the worker's temporary folder and loaded
by the scenario loader, exactly as ``hil campaign expand`` writes them. A task returns one row
(``hil.campaign.statistics.classify``): parameters, detections, verdict, latency, error, fuel,
wall time. Where it runs:

* default: an embedded ``LocalCluster``, one single-threaded worker process per core;
* ``--workers N``: N such processes; ``--workers 1`` runs every task in this process, one
  after the other, with no cluster (for a debugger);
* ``--scheduler tcp://HOST:8786``: an existing cluster (``dask scheduler`` / ``dask worker``,
  dask-jobqueue, Kubernetes); its workers need this project installed, nothing else: the task
  carries the whole scenario and, when the run changes it, the vehicle.

Rows go to ``DIR/runs.jsonl`` as they arrive (flushed per row), in arrival order; the results
table is the rows sorted by run. Started again on the same folder, the campaign computes only
the runs that have no row (a killed campaign loses at most the runs that were in flight). A run
that raises is a row with its error (verdict ``error``); a task lost with its worker (the
worker died) is not a row, so the next start computes it. Ctrl-C stops cleanly: the runs in
flight are cancelled, the finished ones are kept.

``DIR/meta.json`` holds the campaign's fingerprint (``Campaign.fingerprint``): a folder holds
the rows of one campaign; raising ``runs`` in the file extends it.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.campaign.expansion import RunSpec, expand_run, needs_command, write_run
from hil.campaign.file import Bare, Campaign, CampaignError
from hil.campaign.statistics import classify

ROWS = "runs.jsonl"
META = "meta.json"
# Fields of a row that differ between two computations of the same run.
VOLATILE = ("wall_s", "cpu_s")


# --------------------------------------------------------------------------- one task


@dataclass(frozen=True)
class Task:
    """What a worker needs for one run: the expanded run, and whether to keep the detector's
    per-tick inputs for a threshold sweep (``hil.campaign.sweep``)."""

    spec: RunSpec
    record: bool = False


class _Collector:
    """Per-tick figures the row needs, taken from the flight's tick outputs (``on_tick``):
    which thrusters were commanded (N,) bool; with ``record`` also the detector's projections
    xi (N,) and the available set (N,) bool."""

    def __init__(self, record: bool) -> None:
        self.record = record
        self.commanded: list[np.ndarray] = []
        self.on_ms: list[np.ndarray] = []
        self.xi: list[np.ndarray] = []
        self.available: list[np.ndarray] = []

    def __call__(self, n: int, out: Any, truth: Any) -> None:
        on = np.asarray(out.on_ms)
        self.on_ms.append(on.astype(np.int16))
        if self.record:
            self.xi.append(np.asarray(out.xi, dtype=float).copy())
            self.available.append(np.asarray(out.available, dtype=bool).copy())


def _command_timing(spec: RunSpec) -> tuple[int, float, float]:
    """The faulty thruster's index, the tick (s) and the plant's command latency (s): a tick
    n's command acts from ``n h + latency``."""
    names = [t["name"] for t in spec.vehicle["thrusters"]]
    h = float(spec.vehicle["timing"]["tick_s"])
    lat = float((spec.scenario.get("plant") or {}).get("command_latency_ms", 0.0)) / 1000.0
    return names.index(spec.fault["thruster"]), h, lat


def _commands_after(spec: RunSpec, col: _Collector) -> tuple[int, float | None] | None:
    """Ticks on which the faulty thruster had a command acting after the fault time, and the
    plant time that first such command started to act (None: the fault needs no command)."""
    f = spec.fault
    if not needs_command(f) or not col.on_ms:
        return None
    i, h, lat = _command_timing(spec)
    ticks, first = 0, None
    for n, on in enumerate(col.on_ms):
        if on[i] > 0 and n * h + lat + on[i] / 1000.0 > f["t_s"] + 1e-9:
            ticks += 1
            if first is None:
                first = max(n * h + lat, f["t_s"])
    return ticks, first


def _stuck_ticks(spec: RunSpec, col: _Collector) -> tuple[float, list[tuple[float, float]]]:
    """For a stuck-on fault: the tick (s), and for every tick whose command acts after the
    fault the plant time it acts from (``n h + latency``) and the faulty thruster's on-time (s)
    in it; no ticks for other faults."""
    f = spec.fault
    if not f or f.get("kind") != "stuck_on" or f.get("thruster") is None or not col.on_ms:
        return 0.0, []
    i, h, lat = _command_timing(spec)
    return h, [(n * h + lat, float(on[i]) / 1000.0) for n, on in enumerate(col.on_ms)
               if n * h + lat + h > f["t_s"] + 1e-9]


def _closed_after(spec: RunSpec, col: _Collector) -> tuple[int, float | None] | None:
    """For a stuck-on fault: the ticks on which the faulty thruster's valve was commanded
    closed for part or all of the tick after the fault (the only ticks a stuck valve shows
    on: the mirror of ``_commands_after``), and the plant time the first such closed time
    began (the valve is meant closed from the end of the tick's on-time to the tick's end);
    None for other faults."""
    f = spec.fault
    if not f or f.get("kind") != "stuck_on" or f.get("thruster") is None or not col.on_ms:
        return None
    h, ticks = _stuck_ticks(spec, col)
    closed = [t0 + on for t0, on in ticks if on < h - 1e-9]
    return len(closed), (max(closed[0], f["t_s"]) if closed else None)


def _open_throughout(spec: RunSpec, col: _Collector) -> bool | None:
    """For a stuck-on fault: whether its thruster was commanded on for the whole tick at every
    tick acting after the fault (its valve was open anyway: the fault changed nothing the
    plant could show); None for other faults, or no tick after the fault."""
    h, ticks = _stuck_ticks(spec, col)
    if not ticks:
        return None
    return all(on >= h - 1e-9 for _, on in ticks)


def run_task(task: Task) -> dict[str, Any]:
    """Run one task and return its row (never raises for a run's own failure)."""
    from hil.config import load_scenario
    from hil.sim import simulate

    spec = task.spec
    t0 = time.perf_counter()
    c0 = time.process_time()
    col = _Collector(task.record)
    tmp = tempfile.mkdtemp(prefix="hil-run-")
    try:
        path = write_run(spec, Path(tmp), absolute=True)
        sc = load_scenario(path)
        res = simulate(sc, on_tick=col)
        cmds = _commands_after(spec, col)
        closed = _closed_after(spec, col)
        row = classify(spec, res.summary, commanded_after=None if cmds is None else cmds[0] > 0,
                       commanded_ticks=None if cmds is None else cmds[0],
                       first_command_s=None if cmds is None else cmds[1],
                       open_throughout=_open_throughout(spec, col),
                       closed_ticks=None if closed is None else closed[0],
                       first_closed_s=None if closed is None else closed[1])
    except Exception as exc:  # noqa: BLE001 - a run that raises is a row, not a crash
        tb = traceback.extract_tb(exc.__traceback__)
        where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
        row = classify(spec, None, error=f"{type(exc).__name__}: {exc} ({where})")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    row["wall_s"] = round(time.perf_counter() - t0, 3)
    # CPU time of the task: on a shared machine it says what the run costs, wall time not.
    row["cpu_s"] = round(time.process_time() - c0, 3)
    if task.record and row["verdict"] not in ("error",) and col.xi:
        row["_residuals"] = {
            "xi": np.stack(col.xi), "on_ms": np.stack(col.on_ms),
            "available": np.stack(col.available)}
    return row


# --------------------------------------------------------------------------- results folder


def read_rows(path: Path, repair: bool = False) -> list[dict[str, Any]]:
    """Every complete row of a ``runs.jsonl``; with ``repair`` a torn last line (a campaign
    killed while writing) is cut off so that appending goes on cleanly."""
    if not path.exists():
        return []
    data = path.read_bytes()
    rows, good = [], 0
    for line in data.split(b"\n"):
        end = good + len(line) + 1
        if end > len(data):  # the last piece has no newline: torn
            break
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            break
        good = end
    if repair and good < len(data):
        with path.open("r+b") as f:
            f.truncate(good)
    return rows


def table(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """The results table: one row per run, sorted by run, without the volatile fields."""
    out = {}
    for r in rows:
        out[r["run"]] = {k: v for k, v in r.items() if k not in VOLATILE}
    return [out[k] for k in sorted(out)]


def prepare_folder(c: Campaign, out: Path, kind: str = "campaign") -> list[dict[str, Any]]:
    """Create or check ``out``; return the rows already there (resume)."""
    out.mkdir(parents=True, exist_ok=True)
    meta_path = out / META
    meta = {"campaign": c.name, "fingerprint": c.fingerprint(), "kind": kind,
            "vehicle": c.vehicle_name, "runs": c.runs}
    if meta_path.exists():
        old = json.loads(meta_path.read_text())
        if old.get("fingerprint") != meta["fingerprint"] or old.get("kind") != kind:
            raise CampaignError(
                str(out), META, f"results of this {kind} ({c.name}, fingerprint "
                f"{meta['fingerprint']}); use another --out or remove the folder",
                Bare(f"{old.get('kind', 'campaign')} {old.get('campaign')} (fingerprint "
                      f"{old.get('fingerprint')})"))
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    with contextlib.suppress(OSError):
        shutil.copyfile(c.path, out / "campaign.yaml")
    rows = read_rows(out / ROWS, repair=True)
    return [r for r in rows if 0 <= r.get("run", -1) < c.runs]


# --------------------------------------------------------------------------- executors


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Worker processes started inside inherit an ignored SIGINT, so Ctrl-C in the terminal
    reaches only this process, which then stops the cluster itself."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


# How often the cluster's futures are looked at while none has finished (s).
_POLL_S = 0.05


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[threading.Event]:
    """Ctrl-C sets the event the caller looks at between results, instead of raising inside
    Dask's own waits: distributed's ``sync()`` (2026.8) then logs a traceback from its cancel
    callback (a NameError on a future not yet made) however the campaign handles the
    interrupt. The caller raises KeyboardInterrupt itself, outside Dask."""
    stop = threading.Event()
    try:
        old = signal.signal(signal.SIGINT, lambda *_: stop.set())
    except ValueError:  # not the main thread: Ctrl-C is the main thread's business
        yield stop
        return
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, old)


class Executor:
    """Where tasks run: ``local`` (this process), an embedded LocalCluster, or a scheduler."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None) -> None:
        if workers is not None and workers < 1:
            raise CampaignError("hil campaign", "--workers", "an integer >= 1", workers)
        if scheduler is not None and workers is not None:
            raise CampaignError("hil campaign", "--workers", "no --workers with --scheduler "
                                "(the cluster has its own workers)", workers)
        self.scheduler = scheduler
        self.workers = workers if workers is not None else (None if scheduler else
                                                            (os.cpu_count() or 1))
        self.client = None
        self.cluster = None

    @property
    def local(self) -> bool:
        return self.scheduler is None and self.workers == 1

    def __enter__(self) -> Executor:
        if self.local:
            return self
        from distributed import Client, LocalCluster

        logging.getLogger("distributed").setLevel(logging.ERROR)
        # Another cluster on this machine holds the default HTTP port: the scheduler picks
        # another one and says so; nothing to tell the user.
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        if self.scheduler is None:
            # The worker processes log at CRITICAL only: what fails in a worker reaches the
            # campaign through its futures (a lost task is counted), while its log lines are
            # shutdown noise, such as a heartbeat that finds the scheduler closed after a
            # Ctrl-C (an ERROR with a traceback, on the user's terminal).
            with _sigint_ignored():
                self.cluster = LocalCluster(
                    n_workers=self.workers, threads_per_worker=1, processes=True,
                    host="127.0.0.1", dashboard_address=None, silence_logs=logging.CRITICAL)
            self.client = Client(self.cluster)
        else:
            try:
                self.client = Client(self.scheduler, timeout=10)
            except (OSError, TimeoutError) as exc:
                raise CampaignError("hil campaign", "--scheduler",
                                    "the address of a running Dask scheduler",
                                    Bare(f"{self.scheduler} ({exc})")) from None
        return self

    def __exit__(self, *exc: object) -> None:
        for obj in (self.client, self.cluster):
            if obj is not None:
                with contextlib.suppress(Exception):
                    obj.close()

    def describe(self) -> str:
        if self.local:
            return "this process (--workers 1)"
        n = len(self.client.scheduler_info().get("workers", {}))
        if self.cluster is not None:
            return f"a LocalCluster of {n} single-threaded worker process(es)"
        return f"the Dask cluster at {self.scheduler} ({n} worker(s))"

    def map(self, fn: Callable[[Task], dict], tasks: list[Task]) -> Iterator[dict[str, Any]]:
        """Results in the order they finish; lost tasks (dead worker) are skipped, counted in
        ``self.lost``."""
        self.lost = 0
        if self.local:
            for t in tasks:
                yield fn(t)
            return
        futs = [self.client.submit(fn, t, pure=False) for t in tasks]
        self._futs = futs
        pending = list(futs)
        with _sigint_deferred() as stop:
            try:
                while pending:
                    if stop.is_set():
                        raise KeyboardInterrupt
                    done = [f for f in pending if f.done()]
                    if not done:
                        time.sleep(_POLL_S)
                        continue
                    ready = set(map(id, done))
                    pending = [f for f in pending if id(f) not in ready]
                    for fut in done:
                        try:
                            row = fut.result()
                        except Exception:  # noqa: BLE001 - the worker, not the run, failed
                            self.lost += 1
                        else:
                            yield row
                        fut.release()
                        if stop.is_set():
                            raise KeyboardInterrupt
            finally:
                for f in futs:
                    if not f.done():
                        f.cancel()


# --------------------------------------------------------------------------- progress


class Progress:
    """Runs done / total, failures and the time left: a rich bar on a terminal, a line every
    10 % otherwise (logs, CI)."""

    def __init__(self, total: int, done: int, title: str, enabled: bool = True) -> None:
        self.total, self.done, self.failures = total, done, 0
        self.t0 = time.monotonic()
        self.start_done = done
        self.enabled = enabled
        self.tty = enabled and sys.stderr.isatty()
        self._next_line = 0.1
        self.bar = None
        if self.tty:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )
            from rich.progress import Progress as RichProgress

            self.bar = RichProgress(
                TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("failures {task.fields[failures]}"), TextColumn("elapsed"),
                TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn(),
                console=Console(stderr=True), transient=False)
            self.bar.start()
            self.task = self.bar.add_task(title, total=total, completed=done, failures=0)

    def update(self, row: dict[str, Any]) -> None:
        self.done += 1
        if row.get("verdict") in ("error", "incomplete"):
            self.failures += 1
        if self.bar is not None:
            self.bar.update(self.task, completed=self.done, failures=self.failures)
        elif self.enabled and self.done / self.total >= self._next_line - 1e-9:
            el = time.monotonic() - self.t0
            rate = (self.done - self.start_done) / el if el > 0 else 0.0
            left = (self.total - self.done) / rate if rate > 0 else float("nan")
            print(f"  {self.done}/{self.total} runs, failures {self.failures}, "
                  f"{el:.0f} s elapsed, ~{left:.0f} s left", file=sys.stderr, flush=True)
            while self._next_line <= self.done / self.total + 1e-9:
                self._next_line += 0.1

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


# --------------------------------------------------------------------------- campaign


@dataclass
class Outcome:
    """What one start of a campaign did: rows already there, computed now, lost, interrupted."""

    total: int
    before: int
    computed: int
    lost: int
    interrupted: bool
    wall_s: float
    where: str


def run_campaign(c: Campaign, out: Path, *, workers: int | None = None,
                 scheduler: str | None = None, record: bool = False,
                 kind: str = "campaign", progress: bool = True,
                 on_row: Callable[[dict[str, Any]], None] | None = None) -> Outcome:
    """Compute every run of ``c`` that has no row in ``out`` yet (module doc)."""
    out.mkdir(parents=True, exist_ok=True)
    with _folder_lock(out):
        return _run_campaign(c, out, workers=workers, scheduler=scheduler, record=record,
                             kind=kind, progress=progress, on_row=on_row)


LOCK = ".lock"


@contextlib.contextmanager
def _folder_lock(out: Path) -> Iterator[None]:
    """One campaign writes a results folder at a time (two would append the same runs twice):
    an exclusive lock on ``DIR/.lock`` for the whole computation, released by the kernel if
    the process dies."""
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            held = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
            raise CampaignError(str(out), "", "a results folder no other campaign is writing",
                                Bare(f"one held by process {held}")) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def _run_campaign(c: Campaign, out: Path, *, workers: int | None, scheduler: str | None,
                  record: bool, kind: str, progress: bool,
                  on_row: Callable[[dict[str, Any]], None] | None) -> Outcome:
    rows = prepare_folder(c, out, kind)
    done = {r["run"] for r in rows}
    todo = [k for k in range(c.runs) if k not in done]
    tasks = [Task(expand_run(c, k), record) for k in todo]
    t0 = time.monotonic()
    computed, interrupted, lost, where = 0, False, 0, "nothing to compute"
    if tasks:
        ex = Executor(workers, scheduler)
        with ex:
            where = ex.describe()
            if progress:
                print(f"campaign {c.name}: {c.runs} runs, {len(done)} already in {out}, "
                      f"computing {len(tasks)} on {where}", file=sys.stderr, flush=True)
            bar = Progress(c.runs, len(done), c.name, enabled=progress)
            try:
                with (out / ROWS).open("a", encoding="utf-8") as f:
                    for row in ex.map(run_task, tasks):
                        if on_row is not None:
                            on_row(row)
                        row.pop("_residuals", None)
                        f.write(json.dumps(row, sort_keys=True) + "\n")
                        f.flush()
                        computed += 1
                        bar.update(row)
            except KeyboardInterrupt:
                interrupted = True
            finally:
                bar.close()
                lost = getattr(ex, "lost", 0)
    return Outcome(total=c.runs, before=len(done), computed=computed, lost=lost,
                   interrupted=interrupted, wall_s=round(time.monotonic() - t0, 3), where=where)
