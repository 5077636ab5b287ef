"""Shared hook: where vcan0 is promised, a vcan test that skips is a failure.

Tests marked ``vcan`` skip when ``vcan0`` is absent, so that a plain ``pytest`` on a machine
without CAN stays green. The vcan run of the test command (``hil vcan exec -- pytest -m vcan``)
must never pass by skipping: ``hil vcan exec`` puts ``HIL_REQUIRE_VCAN=1`` in the command's
environment (natively, and inside user-mode Linux, which receives every ``HIL_*`` variable), and
then a skipped ``vcan`` test is reported as failed, with the skip reason.
"""

from __future__ import annotations

import os

import pytest

REQUIRE_VCAN_ENV = "HIL_REQUIRE_VCAN"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    if (
        rep.skipped
        and not hasattr(rep, "wasxfail")
        and os.environ.get(REQUIRE_VCAN_ENV) == "1"
        and item.get_closest_marker("vcan") is not None
    ):
        reason = rep.longrepr[2] if isinstance(rep.longrepr, tuple) else str(rep.longrepr)
        rep.outcome = "failed"
        rep.longrepr = (
            f"{item.nodeid}: expected to run ({REQUIRE_VCAN_ENV}=1: vcan0 is required), "
            f"got skipped: {reason}"
        )
