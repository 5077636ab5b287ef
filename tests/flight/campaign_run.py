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


def named_first_and_not_without(tmp_path: Path, campaign: str, run: int, thruster: str,
                                kind: str, within_s: float, off: dict[str, Any],
                                on: dict[str, Any] | None = None):
    """Run ``run`` of ``campaign`` (with the ``on`` detector overrides): its fault is ``kind``
    of ``thruster``, the first detection names it so within ``within_s`` of the fault, and
    with the ``off`` overrides as well nothing is named in the run (the oracle that the
    mechanism can fail). Returns (the spec, the first detection)."""
    spec, r = campaign_run(tmp_path, campaign, run, detector=on)
    assert (spec.fault["kind"], spec.fault["thruster"]) == (kind, thruster)
    dets = r.summary["detections"]
    assert dets and (dets[0]["thruster"], dets[0]["type"]) == (thruster, kind), dets
    assert 0.0 <= dets[0]["t_s"] - spec.fault["t_s"] < within_s, dets
    _, r0 = campaign_run(tmp_path / "off", campaign, run, detector={**(on or {}), **off})
    assert r0.summary["detections"] == [], r0.summary["detections"]
    return spec, dets[0]
