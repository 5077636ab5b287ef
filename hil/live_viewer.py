"""`hil up --viewer` / `--web`: the rerun viewer fed live from the run folder.

The feed reads what the plant and flight write (``plant.jsonl``, ``flight.jsonl``, whole
lines as they grow) and sends it to a viewer, from the process the operator started: on the
host, also when the processes run inside user-mode Linux (which has no display and no network
to the host). ``run.rrd`` is written by the supervisor when the run ends, as without a viewer.

The viewer is the ``rerun`` executable that rerun-sdk installs beside the Python that runs
``hil`` (``.venv/bin/rerun``), else the one on PATH; without either ``--viewer`` is refused in
one line before anything boots. ``--web`` serves the web viewer instead (port 9090, the data
on 9876) and prints its URL on 127.0.0.1; rerun-sdk binds both ports on every interface (it
has no bind-address option), so on a shared network put it behind a firewall.
"""

from __future__ import annotations

import shutil
import sys
import threading
from pathlib import Path

from hil.errors import UsageError

WEB_PORT = 9090
GRPC_PORT = 9876


def find_viewer() -> Path:
    """The rerun viewer executable: beside this Python (the venv's bin), else on PATH."""
    beside = Path(sys.executable).parent / "rerun"
    if beside.is_file():
        return beside
    found = shutil.which("rerun")
    if found:
        return Path(found)
    raise UsageError(f"hil up: --viewer: expected the rerun viewer (the `rerun` executable of "
                     f"rerun-sdk) in {beside.parent} or on PATH, got none: install rerun-sdk "
                     f"(bash scripts/setup.sh) or use --web")


class LiveViewer(threading.Thread):
    """Follows ``run``'s JSON lines and logs them to a rerun viewer every ``period_s``."""

    def __init__(self, run: Path, recording_id: str, web: bool = False,
                 web_port: int = WEB_PORT, period_s: float = 0.2) -> None:
        super().__init__(daemon=True)
        import rerun as rr

        from hil.recorder import RrdRecorder

        self.run_dir, self.period_s = Path(run), period_s
        self._halt = threading.Event()
        self.rec = RrdRecorder.__new__(RrdRecorder)  # no file sink: the viewer only
        self.rec._rr = rr
        self.rec.rec = rr.RecordingStream("thruster_hil", recording_id=recording_id)
        self.rec._declared = {}
        self.url: str | None = None
        if web:
            grpc = rr.serve_grpc(recording=self.rec.rec)
            rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=grpc)
            self.url = f"http://127.0.0.1:{web_port}/?url={grpc}"
        else:
            rr.spawn(executable_path=str(find_viewer()), recording=self.rec.rec,
                     connect=True)

    def run(self) -> None:
        from hil.follow import RunFollower
        from hil.recorder import merge_by_tick

        follow = RunFollower(self.run_dir)
        while not self._halt.wait(self.period_s):
            plant, flight = follow.read()
            new = list(merge_by_tick(("plant", plant), ("flight", flight)))
            if new:
                self.rec.log_batch(new)

    def stop(self) -> None:
        self._halt.set()
        self.join(2.0)
        self.rec.rec.flush(timeout_sec=2.0)
