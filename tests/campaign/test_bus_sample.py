"""`hil campaign --bus`: a sample of the runs over the real bus agrees with the in-process rows."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil import vcan


@pytest.mark.vcan
@pytest.mark.skipif(not vcan.vcan_present("vcan0"),
                    reason="vcan0 absent; run through `hil vcan exec`")
def test_bus_sample_agrees_with_in_process(tmp_path: Path, ci_campaign: Path) -> None:
    text = ci_campaign.read_text().replace("runs: 24", "runs: 6") + "bus_sample: 2\n"
    c = tmp_path / "c.yaml"
    c.write_text(text)
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", str(c), "--workers", "1",
                        "--out", str(out), "--no-progress", "--bus"],
                       capture_output=True, text=True, timeout=600)
    assert "bus: 2/2 sampled runs agree with the in-process result" in r.stdout, (
        r.stdout + r.stderr)
    res = json.loads((out / "bus.json").read_text())
    assert [x["agree"] for x in res] == [True, True]
    rows = {json.loads(line)["run"]: json.loads(line)
            for line in (out / "runs.jsonl").read_text().splitlines()}
    for x in res:
        s = json.loads((out / "bus" / rows[x["run"]]["name"] / "run" / "summary.json")
                       .read_text())
        assert s["mode"] == "lockstep" and s["ticks"] == 60
