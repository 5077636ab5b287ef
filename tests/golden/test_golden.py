"""The reference scenarios in-process are identical to the last bit to the saved golden traces.

Oracle: the digests and detections saved by ``tests/golden/golden.py`` on the commit before
the architecture restructuring (the restructuring must not change one bit of any run).
"""

from __future__ import annotations

import json

import pytest
from golden import GOLDEN_DIR, scenario_names, trace


@pytest.mark.parametrize("name", scenario_names())
def test_reference_run_is_bit_identical_to_the_golden_trace(name: str) -> None:
    path = GOLDEN_DIR / f"{name}.json"
    assert path.exists(), f"{path.name}: expected a golden trace, got none (run tests/golden)"
    want = json.loads(path.read_text())
    got = trace(name)
    assert got["detections"] == want["detections"]
    assert got["truth_sha256"] == want["truth_sha256"]
    assert got["outputs_sha256"] == want["outputs_sha256"]
    assert got["final"] == want["final"]
    assert got["records_sha256"] == want["records_sha256"]
