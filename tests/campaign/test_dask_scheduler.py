"""A real `dask scheduler` and two `dask worker` processes on 127.0.0.1; the campaign runs
through `hil campaign --scheduler` and gives the same table as in this process."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.campaign.engine import read_rows, run_campaign, table
from hil.campaign.load import load_campaign

DASK = str(Path(sys.executable).parent / "dask")


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def test_campaign_on_an_existing_cluster(tmp_path: Path, ci_campaign: Path) -> None:
    sfile = tmp_path / "scheduler.json"
    procs: list[subprocess.Popen] = []
    logs = [(tmp_path / f"{n}.log").open("w") for n in ("scheduler", "w1", "w2")]
    try:
        procs.append(subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(sfile)], stdout=logs[0], stderr=subprocess.STDOUT))
        t_end = time.monotonic() + 60
        while not sfile.exists() and time.monotonic() < t_end:
            time.sleep(0.1)
        assert sfile.exists(), (tmp_path / "scheduler.log").read_text()
        time.sleep(0.2)
        address = json.loads(sfile.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for log in logs[1:]:
            procs.append(subprocess.Popen(
                [DASK, "worker", address, "--nthreads", "1", "--nworkers", "1",
                 "--host", "127.0.0.1", "--no-dashboard"], stdout=log,
                stderr=subprocess.STDOUT, cwd=tmp_path))
        from distributed import Client

        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=90)
        out = tmp_path / "out"
        r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", str(ci_campaign),
                            "--scheduler", address, "--out", str(out), "--no-progress"],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode in (0, 1), r.stderr
        assert f"on the Dask cluster at {address} (2 worker(s))" in r.stdout
        rows = read_rows(out / "runs.jsonl")
        assert len(rows) == 24
    finally:
        for p in reversed(procs):
            _stop(p)
        for log in logs:
            log.close()
    ref = tmp_path / "ref"
    run_campaign(load_campaign(ci_campaign), ref, workers=1, progress=False)
    assert table(rows) == table(read_rows(ref / "runs.jsonl"))


def test_unreachable_scheduler_is_a_one_line_error(tmp_path: Path, ci_campaign: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", str(ci_campaign),
                        "--scheduler", "tcp://127.0.0.1:9", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert lines[-1].startswith("error: hil campaign: --scheduler: expected the address of a "
                                "running Dask scheduler, got tcp://127.0.0.1:9 (")
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("bad", ["0", "-3"])
def test_bad_worker_count(tmp_path: Path, ci_campaign: Path, bad: str) -> None:
    r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", str(ci_campaign),
                        "--workers", bad, "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr == f"error: hil campaign: --workers: expected an integer >= 1, got {bad}\n"
