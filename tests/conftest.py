"""Shared hook: where vcan0 is promised, a vcan test that skips is a failure.

Tests marked ``vcan`` skip when ``vcan0`` is absent, so that a plain ``pytest`` on a machine
without CAN stays green. The vcan run of the test command (``hil vcan exec -- pytest -m vcan``)
must never pass by skipping: ``hil vcan exec`` puts ``HIL_REQUIRE_VCAN=1`` in the command's
environment (natively, and inside user-mode Linux, which receives every ``HIL_*`` variable), and
then a skipped ``vcan`` test is reported as failed, with the skip reason.

Second hook: the groups of the parallel unit run (``pytest -n 2 --dist loadgroup``, the test
command). Each test file is one group (a file's fixtures are built once, as with
``--dist loadfile``), except the files that start systems over ``udp_multicast`` on the host:
python-can binds every such socket to the same UDP port, and Linux delivers a datagram for any
group joined on the host to every socket bound to that port, so two such runs side by side
hear each other whatever group they chose. Those files share one group: one worker, one at a
time.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

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


@lru_cache(maxsize=None)
def _starts_udp_systems(path: str) -> bool:
    try:
        return "udp_multicast" in Path(path).read_text(encoding="utf-8")
    except OSError:
        return False


def pytest_collection_modifyitems(config, items):
    for item in items:
        path = str(item.path)
        group = "host-udp-multicast" if _starts_udp_systems(path) else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))
