"""Loading a campaign file: parse and validate it (``hil.campaign.file``), then expand its
first runs and load them as a task will (``hil.campaign.expansion``), so that a campaign whose
early runs the scenario loader rejects stops at once with that one-line error."""

from __future__ import annotations

from pathlib import Path

from hil.campaign.expansion import expand_run, write_run
from hil.campaign.file import Bare, Campaign, CampaignError, display, parse_campaign


def load_campaign(path: str | Path) -> Campaign:
    """The validated campaign of ``path`` (``CampaignError``: one line)."""
    c = parse_campaign(path)
    check_first_runs(c, display(Path(path)))
    return c


def check_first_runs(c: Campaign, where: str, first: int = 16) -> None:
    """Expand the first runs and load them as the scenario loader will in a task: a campaign
    whose early runs the loader rejects stops here with that one-line error (any later run
    the loader rejects becomes that run's error row)."""
    import tempfile

    from hil.config import load_scenario

    with tempfile.TemporaryDirectory(prefix="hil-campaign-") as tmp:
        for k in range(min(first, c.runs)):
            p = write_run(expand_run(c, k), Path(tmp) / str(k), absolute=True)
            try:
                load_scenario(p)
            except Exception as exc:  # noqa: BLE001 - the loader's own one-line error
                msg = str(exc).split(": ", 1)[-1]
                raise CampaignError(where, f"run {k}", "a run the scenario loader accepts",
                                    Bare(msg)) from None
