"""No gyro fault is named while a thruster fault is latched and not yet answered (single-fault
assumption, docs/design.md "Gyro faults").

In real time S002-50 (a stuck-on, time-triggered actuation) named a gyro bias step 4.6 s after
the correct stuck-on: the thruster the FDIR reports but does not switch off keeps moving the
rate away from the onboard model, and the gyro check took that for the sensor. The check still
keeps such ticks out of the evidence; only the naming is dropped. The cost, stated by the first
test: a real sensor fault after an unanswered thruster fault is not named either, as a second
thruster fault is not (the detector is latched until the response).

Oracles: the injected faults (the truth of what happened) in the in-process simulator; the
same gyro fault alone is named (the rule hides nothing when no thruster fault is latched).
"""

from __future__ import annotations

from pathlib import Path

from hil.sim import simulate


def _scenario(tmp_path: Path, faults: str) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text("name: gyro-after-thruster\nvehicle: generic\nduration_s: 40.0\nseed: 0\n"
                 "initial: {attitude: {axis: [1.0, 0.0, 0.0], angle_deg: 22.5}}\n"
                 "faults:\n" + faults)
    return p


STUCK = "  - {kind: stuck_on, thruster: X+, t_s: 18.0, fraction: 1.0}\n"
BIAS = "  - {kind: gyro_bias_step, t_s: 28.0, magnitude_rad_s: 0.005}\n"


def _detections(path: Path) -> list[tuple[str, str | None]]:
    s = simulate(path).summary
    return [(d["type"], d.get("thruster")) for d in s["detections"]]


def test_a_gyro_fault_after_a_latched_stuck_on_is_not_named(tmp_path) -> None:
    """generic reports a stuck-on and does not switch it off (response none): the detector
    stays latched, and the bias step 10 s later is not named as a second fault."""
    got = _detections(_scenario(tmp_path, STUCK + BIAS))
    assert got == [("stuck_on", "X+")], got


def test_the_same_gyro_fault_alone_is_named(tmp_path) -> None:
    got = _detections(_scenario(tmp_path, BIAS))
    assert [k for k, _ in got] == ["gyro_fault"], got


def test_after_the_response_a_gyro_fault_is_named_again(tmp_path) -> None:
    """orel closes the stuck thruster's manifold: the detector restarts on the new
    configuration (no latch), and a later bias step is named as a gyro fault."""
    p = tmp_path / "s.yaml"
    p.write_text("name: gyro-after-response\nvehicle: orel\nduration_s: 60.0\nseed: 0\n"
                 "faults:\n  - {kind: stuck_on, thruster: '1', t_s: 10.0, fraction: 1.0}\n"
                 "  - {kind: gyro_bias_step, t_s: 40.0, magnitude_rad_s: 0.005}\n")
    got = _detections(p)
    assert got == [("stuck_on", "1"), ("gyro_fault", None)], got
