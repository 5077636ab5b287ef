"""One run of a shipped campaign in this process (``hil.sim.simulate``), optionally with
detector settings over the vehicle's, for the closed-loop tests of the detector mechanisms:
the plant's truth (the fault it was given) is the oracle."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def campaign_run(tmp_path: Path, campaign: str, run: int,
                 detector: dict[str, Any] | None = None):
    """(the run's spec, its ``SimRun``) for run ``run`` of ``configs/campaigns/<campaign>.yaml``,
    written under ``tmp_path``; ``detector``: ``flight.detector`` overrides, each value written
    as YAML text (``"null"``, ``"false"``, ``0.05``)."""
    from hil.campaign.expansion import expand_run, write_run
    from hil.campaign.load import load_campaign
    from hil.config import CONFIG_DIR
    from hil.sim import simulate

    spec = expand_run(load_campaign(CONFIG_DIR / "campaigns" / f"{campaign}.yaml"), run)
    path = write_run(spec, tmp_path)
    if detector:
        text = path.read_text()
        assert "\nflight:" not in text
        path.write_text(text + "flight:\n  detector:\n" + "".join(
            f"    {k}: {v}\n" for k, v in detector.items()))
    return spec, simulate(path)
