"""Following a run folder as the processes write it (the console, the live viewer).

Each process writes one whole JSON line per tick (``hil.node_shell``), in one ``write(2)``,
into ``plant.jsonl`` / ``flight.jsonl`` of the run folder; reading those lines is how a
watcher attaches to a running system inside or outside user-mode Linux (the folder is on the
shared disk). A new run in the same folder replaces the files: the follower notices the new
file (another inode, or a shorter one) and starts it from its beginning.
"""

from __future__ import annotations

import json
import os
from pathlib import Path


class JsonlFollower:
    """The whole JSON lines appended to ``path`` since the last :meth:`read`."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.pos, self.buf, self.ino = 0, b"", None
        self.restarts = 0  # how many times the file was replaced under us

    def read(self) -> list[dict]:
        try:
            st = os.stat(self.path)
        except OSError:
            return []
        if self.ino is not None and (st.st_ino != self.ino or st.st_size < self.pos):
            self.pos, self.buf = 0, b""
            self.restarts += 1
        self.ino = st.st_ino
        if st.st_size == self.pos:
            return []
        with self.path.open("rb") as f:
            f.seek(self.pos)
            chunk = f.read()
            self.pos = f.tell()
        *lines, self.buf = (self.buf + chunk).split(b"\n")
        out = []
        for line in lines:
            try:
                out.append(json.loads(line))
            except ValueError:
                pass  # a line cut by a full disk is not a record
        return out


class RunFollower:
    """Both processes' records of one run folder, as they grow."""

    def __init__(self, run: Path) -> None:
        self.run = Path(run)
        self.plant = JsonlFollower(self.run / "plant.jsonl")
        self.flight = JsonlFollower(self.run / "flight.jsonl")

    def read(self) -> tuple[list[dict], list[dict]]:
        return self.plant.read(), self.flight.read()
