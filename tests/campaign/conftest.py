"""Shared campaign fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.config import CONFIG_DIR

CI_CAMPAIGN = CONFIG_DIR / "campaigns" / "ci-generic.yaml"


@pytest.fixture
def write_campaign():
    """``write_campaign(folder, text, name="c.yaml") -> Path``."""
    def write(folder: Path, text: str, name: str = "c.yaml") -> Path:
        p = folder / name
        p.write_text(text)
        return p
    return write


@pytest.fixture
def ci_campaign() -> Path:
    return CI_CAMPAIGN
