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
REQUIRE_LCM_ENV = "HIL_REQUIRE_LCM"  # set by `hil netns exec`: a skipped `lcm` test fails


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    required = [m for m, env in (("vcan", REQUIRE_VCAN_ENV), ("lcm", REQUIRE_LCM_ENV))
                if os.environ.get(env) == "1" and item.get_closest_marker(m) is not None]
    if rep.skipped and not hasattr(rep, "wasxfail") and required:
        reason = rep.longrepr[2] if isinstance(rep.longrepr, tuple) else str(rep.longrepr)
        rep.outcome = "failed"
        rep.longrepr = (
            f"{item.nodeid}: expected to run ({required[0]} is required: "
            f"{REQUIRE_VCAN_ENV if required[0] == 'vcan' else REQUIRE_LCM_ENV}=1), "
            f"got skipped: {reason}"
        )
