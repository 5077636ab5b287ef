"""The campaign engine on real Dask clusters: determinism, resume, failures recorded."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.campaign.engine import read_rows, run_campaign, table
from hil.campaign.load import load_campaign

RUNS = 24


def _table(out: Path) -> list[dict]:
    return table(read_rows(out / "runs.jsonl"))


@pytest.fixture(scope="module")
def reference(tmp_path_factory, ci_campaign_path) -> list[dict]:
    """The CI campaign computed in this process (--workers 1)."""
    out = tmp_path_factory.mktemp("ref")
    o = run_campaign(load_campaign(ci_campaign_path), out, workers=1, progress=False)
    assert (o.computed, o.before, o.interrupted) == (RUNS, 0, False)
    return _table(out)


@pytest.fixture(scope="module")
def ci_campaign_path() -> Path:
    from hil.config import CONFIG_DIR

    return CONFIG_DIR / "campaigns" / "ci-generic.yaml"


def test_local_cluster_same_table_as_one_process_and_as_a_second_run(
        tmp_path: Path, ci_campaign_path: Path, reference: list[dict]) -> None:
    c = load_campaign(ci_campaign_path)
    assert len(reference) == RUNS and [r["run"] for r in reference] == list(range(RUNS))
    # The campaign is not trivial: it has detections, misses and unobservable runs.
    verdicts = {r["verdict"] for r in reference}
    assert {"detected", "unobservable"} <= verdicts and "error" not in verdicts
    a = run_campaign(c, tmp_path / "a", workers=2, progress=False)
    assert a.where == "a LocalCluster of 2 single-threaded worker process(es)"
    assert a.computed == RUNS
    assert _table(tmp_path / "a") == reference
    b = run_campaign(c, tmp_path / "b", workers=2, progress=False)
    assert b.computed == RUNS and _table(tmp_path / "b") == reference
    # Started again on a finished folder: nothing to compute.
    again = run_campaign(c, tmp_path / "a", workers=2, progress=False)
    assert (again.computed, again.before) == (0, RUNS)


def test_resume_after_a_killed_campaign_computes_only_the_missing_runs(
        tmp_path: Path, ci_campaign_path: Path, reference: list[dict]) -> None:
    out = tmp_path / "k"
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "campaign", str(ci_campaign_path),
                             "--workers", "1", "--out", str(out), "--no-progress"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rows = out / "runs.jsonl"
    t_end = time.monotonic() + 120
    while time.monotonic() < t_end:
        if rows.exists() and rows.read_text().count("\n") >= 6:
            break
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    # The kill may also tear the row being written: the folder must cope with that.
    with rows.open("a") as f:
        f.write('{"run": 23, "verdict": "pa')
    done = len(read_rows(rows))
    assert 6 <= done < RUNS
    kept = rows.read_text().split("\n")[:done]
    o = run_campaign(load_campaign(ci_campaign_path), out, workers=1, progress=False)
    assert (o.before, o.computed) == (done, RUNS - done)
    lines = rows.read_text().split("\n")
    assert lines[:done] == kept  # the finished rows were kept as they were
    assert len(read_rows(rows)) == RUNS  # no run twice
    assert _table(out) == reference


def test_another_campaign_in_the_same_folder_is_refused(
        tmp_path: Path, ci_campaign_path: Path, write_campaign) -> None:
    from hil.campaign.file import CampaignError

    run_campaign(load_campaign(ci_campaign_path), tmp_path, workers=1, progress=False)
    other = write_campaign(tmp_path.parent, ci_campaign_path.read_text().replace(
        "seed: 11", "seed: 12"), "other.yaml")
    with pytest.raises(CampaignError, match="meta.json: expected results of this campaign"):
        run_campaign(load_campaign(other), tmp_path, workers=1, progress=False)


def test_a_run_that_raises_is_recorded_not_fatal(tmp_path: Path, write_campaign,
                                                 ci_campaign_path: Path) -> None:
    # Run 16 of this file carries a fault kind the scenario loader rejects (past the first
    # runs the loader checks up front): on a real cluster it is a row with its error.
    kinds = ", ".join(["stuck_on"] * 16 + ["leaks"])
    text = ci_campaign_path.read_text().replace(
        "kind: {cycle: [stuck_on, fail_to_fire, degraded]}", f"kind: {{cycle: [{kinds}]}}"
    ).replace("runs: 24", "runs: 18").replace(
        "stuck_on: {choice: [1.0, 0.5, 0.15]}, degraded: {uniform: [0.2, 0.6]}",
        "stuck_on: {choice: [1.0, 0.5, 0.15]}")
    c = load_campaign(write_campaign(tmp_path, text))
    o = run_campaign(c, tmp_path / "o", workers=2, progress=False)
    assert o.computed == 18
    rows = _table(tmp_path / "o")
    bad = [r for r in rows if r["verdict"] == "error"]
    assert [r["run"] for r in bad] == [16]
    assert bad[0]["error"].startswith("ConfigError: ") and "faults[0].kind" in bad[0]["error"]
    assert all(r["verdict"] != "error" for r in rows if r["run"] != 16)


def test_a_raising_simulation_and_an_incomplete_summary_in_process(
        tmp_path: Path, ci_campaign_path: Path, monkeypatch) -> None:
    import hil.sim

    real = hil.sim.simulate

    def fake(sc, **kw):
        if sc.cfg.name.endswith("-00003"):
            raise RuntimeError("plant diverged")
        res = real(sc, **kw)
        if sc.cfg.name.endswith("-00005"):
            res.summary["ticks"] -= 1
        return res

    monkeypatch.setattr(hil.sim, "simulate", fake)
    c = load_campaign(ci_campaign_path)
    o = run_campaign(c, tmp_path, workers=1, progress=False)
    assert o.computed == RUNS
    rows = {r["run"]: r for r in _table(tmp_path)}
    assert rows[3]["verdict"] == "error"
    assert rows[3]["error"].startswith("RuntimeError: plant diverged (")
    assert rows[5]["verdict"] == "incomplete" and rows[5]["reason"] == "59 plant ticks of 60"
    # The report counts them as failures, in no rate.
    from hil.campaign.report import write_report

    doc = write_report(list(rows.values()), tmp_path, campaign=c.name,
                       campaign_file=str(c.path), runs_planned=c.runs,
                       fingerprint=c.fingerprint())
    assert [f["run"] for f in doc["failures"]] == [3, 5]
    assert sum(st.get("runs", 0) - st.get("completed", st.get("runs", 0))
               for st in doc["by_vehicle"]["generic"].values()) == 2
    assert (tmp_path / "report.md").exists() and (tmp_path / "latency.png").exists()
    assert json.loads((tmp_path / "campaign.json").read_text())["rows"] == RUNS


def test_ctrl_c_stops_cleanly_and_keeps_what_finished(tmp_path: Path, ci_campaign_path: Path,
                                                      reference: list[dict]) -> None:
    out = tmp_path / "i"
    # The CI campaign made long (its runs are drawn per run index, so its first 24 are the
    # reference's): 24 runs finish in about 2 s on two workers, so a loaded machine could
    # see them all done before the signal lands.
    big_runs = 2000
    big = tmp_path / "big.yaml"
    big.write_text(ci_campaign_path.read_text().replace(f"runs: {RUNS}\n",
                                                        f"runs: {big_runs}\n"))
    assert f"runs: {big_runs}" in big.read_text()
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "campaign", str(big),
                             "--workers", "2", "--out", str(out)], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rows = out / "runs.jsonl"
    t_end = time.monotonic() + 120
    while time.monotonic() < t_end and not (rows.exists() and rows.read_text().count("\n") >= 4):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    kept = len(read_rows(rows))
    assert 4 <= kept < big_runs
    assert f"interrupted: {kept} of {big_runs} runs kept in" in stderr
    assert "Traceback" not in stderr
    # Nothing of the cluster is left behind in its process group (worker processes exit on
    # their own shortly after the scheduler closed).
    t_end = time.monotonic() + 20
    while time.monotonic() < t_end:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        raise AssertionError("processes of the campaign's group still alive after 20 s")
    first = [x for x in read_rows(rows) if x["run"] < RUNS]
    assert first, "no run of the first 24 kept"
    assert table(first) == [r for r in reference if r["run"] in {x["run"] for x in first}]


def test_a_folder_another_campaign_is_writing_is_refused(tmp_path: Path,
                                                          ci_campaign_path: Path) -> None:
    """Two campaigns on one folder would append the same runs twice: the second is refused
    with one line, and the folder is usable once the first lets go."""
    import fcntl

    from hil.campaign.engine import LOCK
    from hil.campaign.file import CampaignError

    c = load_campaign(ci_campaign_path)
    with (tmp_path / LOCK).open("w") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        held.write("4242\n")
        held.flush()
        with pytest.raises(CampaignError, match="held by process 4242"):
            run_campaign(c, tmp_path, workers=1, progress=False)
    assert not (tmp_path / "runs.jsonl").exists()
