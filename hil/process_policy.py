"""Process policy of the plant and flight processes: garbage collection out of the tick, the
scheduler class, real-time priority and locked memory. Each says what it got, in words that go
into the node's first record (``sched``) and events.
"""

from __future__ import annotations

import gc
import os

GC_EVERY_TICKS = 10  # 2 s at the 200 ms tick


def quiet_gc() -> None:
    """Garbage collection out of the tick: what start-up made is frozen (never scanned again)
    and automatic collection is off. A generation-2 collection started by an allocation took
    ~4.5 ms in the middle of a flight stage (bench/bench_flight_tick.py: whole-tick p99 5.2 ms
    with it, 1.1 ms without); the cycles a tick leaves are collected by :func:`idle_gc`."""
    gc.collect()
    gc.freeze()
    gc.disable()


def idle_gc(tick: int) -> None:
    """Collect every ``GC_EVERY_TICKS`` ticks, after the tick's record is written: THR_CMD
    and the tick's figures are out, the rest of the tick is idle."""
    if tick % GC_EVERY_TICKS == GC_EVERY_TICKS - 1:
        gc.collect()


_POLICIES = {getattr(os, k): k for k in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH",
                                          "SCHED_IDLE") if hasattr(os, k)}


def sched_policy() -> str:
    """This process's scheduler policy as a name (and priority for the real-time ones)."""
    try:
        pol = os.sched_getscheduler(0)
        name = _POLICIES.get(pol, f"policy {pol}")
        if name in ("SCHED_FIFO", "SCHED_RR"):
            name += f" {os.sched_getparam(0).sched_priority}"
        return name
    except (OSError, AttributeError):
        return "unknown"


def set_policy(node: str, choice: str) -> str:
    """The default (non real-time) policy of a node; says what it got.

    ``auto``: the plant runs SCHED_BATCH, the flight SCHED_OTHER. A SCHED_BATCH process does
    not preempt another when it wakes up, so on a machine with one CPU (user-mode Linux) the
    plant, woken by each THR_CMD frame or its own timer, no longer interrupts the flight
    software in the middle of a tick: it runs when the flight blocks. Measured under
    user-mode Linux (orel, real time): flight compute p50 9.8 -> 4.0 ms, of which sending
    THR_CMD 4.6 -> 0.7 ms. With several CPUs both run at once and nothing changes. Set
    explicitly, not inherited, so a caller's policy does not leak into the nodes.
    """
    want = {"auto": "batch" if node == "plant" else "other"}.get(choice, choice)
    pol = os.SCHED_BATCH if want == "batch" else os.SCHED_OTHER
    try:
        os.sched_setscheduler(0, pol, os.sched_param(0))
    except (PermissionError, OSError, AttributeError) as exc:
        return f"{sched_policy()} ({want} refused: {exc.__class__.__name__})"
    return sched_policy()


RT_PRIORITY = {"flight": 50, "plant": 40}  # the software under test above its emulator


def try_realtime_priority(name: str) -> str:
    """SCHED_FIFO and locked memory when permitted; says what it got.

    The flight gets the higher priority: with equal priorities a FIFO process is never
    preempted by its peer, so on one CPU the flight's release waited for the plant's work
    (release jitter p50 1.9 ms under user-mode Linux, and 230 ms once while the plant
    wrote its last record).
    """
    notes = []
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY.get(name, 45)))
    except (PermissionError, OSError, AttributeError) as exc:
        notes.append(f"SCHED_FIFO refused ({exc.__class__.__name__}: "
                     f"{getattr(exc, 'strerror', None) or exc})")
    notes.insert(0, sched_policy())
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        if libc.mlockall(3) == 0:  # MCL_CURRENT | MCL_FUTURE
            notes.append("memory locked")
        else:
            notes.append(f"memory not locked (errno {ctypes.get_errno()})")
    except OSError:
        notes.append("memory not locked")
    return ", ".join(notes)


def realtime_event(note: str) -> str:
    """The event line of a ``--rt-priority`` request: says plainly what was refused."""
    fifo = note.startswith(("SCHED_FIFO", "SCHED_RR"))
    locked = "memory locked" in note
    if fifo and locked:
        return f"--rt: {note}"
    return f"--rt {'partly refused' if fifo or locked else 'refused'}: {note}"


def where_here() -> dict:
    """Where this process runs: the kernel (native or user-mode Linux) and its CPUs."""
    from hil.uml import in_uml

    return {"kernel": "user-mode Linux" if in_uml() else "native kernel",
            "cpus": os.cpu_count()}
