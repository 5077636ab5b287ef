"""Issue 17: results that survive a full disk or a read-only folder.

A 1 MiB tmpfs (mounted in a private mount namespace, so the host's mounts are untouched)
fills during a lockstep run over ``udp_multicast`` between real processes: the run must end
as a failed run (exit 3) whose reasons say the output was lost, the summary must reach the
user (in the folder, or on stderr when even that fails), and no JSON lines file may end with
a torn line. A read-only ``--out`` is refused before anything starts.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hil.recorder import JsonlWriter, OutputLost
from tests.udp import private_udp_channel

ROOT = Path(__file__).resolve().parents[2]


def _whole_lines(path: Path) -> list[dict]:
    data = path.read_bytes()
    assert data == b"" or data.endswith(b"\n"), f"{path.name} ends with a torn line"
    return [json.loads(line) for line in data.splitlines()]


def test_a_write_that_fails_part_way_leaves_the_last_whole_line(tmp_path, monkeypatch) -> None:
    w = JsonlWriter(tmp_path / "x.jsonl")
    w.write({"tick": 0})
    real_write = os.write
    calls = []

    def half_then_enospc(fd, data):
        calls.append(len(data))
        if len(calls) == 1:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "write", half_then_enospc)
    with pytest.raises(OutputLost) as info:
        w.write({"tick": 1, "payload": "y" * 100})
    monkeypatch.setattr(os, "write", real_write)
    assert info.value.errno == 28 and "No space left on device" in str(info.value)
    assert _whole_lines(tmp_path / "x.jsonl") == [{"tick": 0}]
    w.write({"tick": 2})  # the file goes on from its last whole line
    assert _whole_lines(tmp_path / "x.jsonl") == [{"tick": 0}, {"tick": 2}]


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("unshare") is None,
                    reason="mounting a tmpfs needs root and unshare(1)")
def test_a_full_tmpfs_leaves_a_failed_summary_and_no_torn_line(tmp_path) -> None:
    disk = tmp_path / "disk"
    disk.mkdir()
    scen = tmp_path / "long.yaml"
    scen.write_text("name: full\nvehicle: orel\nduration_s: 600.0\nseed: 2\n"
                    "initial: {attitude: {axis: [1, 0, 0], angle_deg: 10.0}}\n")
    channel = private_udp_channel("239.73")
    out = disk / "run"
    script = (f"mount -t tmpfs -o size=1m tmpfs {disk} && "
              f"{sys.executable} -m hil.cli run {scen} --out {out} --interface udp_multicast "
              f"--channel {channel}; rc=$?; "
              f"mkdir -p {tmp_path}/copy; cp -a {out}/. {tmp_path}/copy/ 2>/dev/null; exit $rc")
    r = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 3, r.stdout[-2000:] + r.stderr[-2000:]
    copy = tmp_path / "copy"
    summary_file = copy / "summary.json"
    if summary_file.exists():
        s = json.loads(summary_file.read_text())
    else:  # the disk was too full even for the summary: it went to stderr
        line = next(ln for ln in r.stderr.splitlines() if ln.startswith("{"))
        s = json.loads(line)
    assert s["verdict"] == "run_failed"
    assert any("could not write its records" in x or "output could not be written" in x
               for x in s["run_failures"]), s["run_failures"]
    for name in ("plant.jsonl", "flight.jsonl"):
        if (copy / name).exists():
            _whole_lines(copy / name)


def test_a_read_only_out_folder_is_refused_before_anything_starts(tmp_path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):  # root writes anyway: a file in the way instead
            target = tmp_path / "file"
            target.write_text("x")
            out = target / "run"
        else:
            out = ro / "run"
        r = subprocess.run([sys.executable, "-m", "hil.cli", "run",
                            str(ROOT / "configs/scenarios/S000-stuck.yaml"), "--out", str(out)],
                           capture_output=True, text=True, timeout=120, cwd=ROOT)
    finally:
        ro.chmod(0o700)
    assert r.returncode == 2, r.stdout + r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "expected a folder the run can write to" in err[0], r.stderr
    assert "user-mode Linux" not in r.stdout
