"""The campaign file: strict validation with one-line errors; run k from (seed, k) alone."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hil.campaign.expansion import expand_run, write_run
from hil.campaign.file import CampaignError
from hil.campaign.load import load_campaign
from hil.config import load_scenario

GOOD = """name: t
base: {vehicle: generic}
runs: 40
seed: 5
duration_s: 10.0
dispersions:
  thrust_scale: {uniform: [0.85, 1.15]}
  initial_angle_deg: {uniform: [0, 30]}
  initial_rate_deg_s: {uniform: [0, 3.5]}
  command_latency_ms: {choice: [0.0, 5.0, 15.0]}
  gyro_bias_rad_s: {normal: [0.0, 1.0e-5]}
fault:
  kind: {cycle: [stuck_on, fail_to_fire]}
  thruster: {cycle: all, stride: 2}
  t_s: {uniform: [2.0, 8.0]}
  fraction: {stuck_on: {fixed: 0.5}}
"""


@pytest.mark.parametrize("text, message", [
    (GOOD.replace("runs: 40", "runs: 0"), "runs: expected >= 1, got 0"),
    (GOOD.replace("seed: 5", "seed: 5\nsneed: 1"),
     "sneed: expected no such field (unknown key), got 1"),
    (GOOD.replace("[0.85, 1.15]", "[1.15, 0.85]"),
     "dispersions.thrust_scale.uniform: expected [low, high] with low <= high, got [1.15, 0.85]"),
    (GOOD.replace("thrust_scale:", "thrust_scael:"),
     "dispersions.thrust_scael: expected one of ['command_latency_ms', 'direction_error_deg', "
     "'flex_freq_scale', 'flex_log_decrement_scale', 'gyro_bias_rad_s', 'gyro_noise_std_rad_s', "
     "'initial_angle_deg', 'initial_axis', 'initial_rate_deg_s', 'noise_seed', 'thrust_scale', "
     "'thrust_scale_per_thruster'], got an unknown name"),
    (GOOD.replace("{cycle: all, stride: 2}", "{choice: [X+, W9]}"),
     "fault.thruster: expected thruster names of the vehicle (or any, all, {manifold: M}), "
     "got 'W9'"),
    (GOOD.replace("[0.85, 1.15]", "[0.0, 1.15]"),
     "dispersions.thrust_scale.uniform: expected a range above 0, got [0.0, 1.15]"),
    (GOOD.replace("t_s: {uniform: [2.0, 8.0]}", "t_s: {uniform: [2.0, 18.0]}"),
     "fault.t_s: expected times before the shortest duration (10 s), got up to 18 s"),
    (GOOD.replace("{cycle: [stuck_on, fail_to_fire]}", "{cycle: [stuck_on, leaks]}"),
     "fault.fraction.stuck_on: expected"),  # placeholder, replaced below
    (GOOD.replace("base: {vehicle: generic}", "base: {vehicle: nosuch}"),
     "base.vehicle: expected a vehicle name in configs/vehicles, got 'nosuch'"),
    (GOOD.replace("gyro_bias_rad_s: {normal: [0.0, 1.0e-5]}", "flex_freq_scale: 1.1"),
     "dispersions.flex_freq_scale: expected a vehicle with flex_modes, got 'vehicle generic "
     "without flex modes'"),
])
def test_bad_campaign_one_line_error(write_campaign, tmp_path: Path, text: str,
                                    message: str) -> None:
    p = write_campaign(tmp_path, text)
    if "leaks" in text:
        # An unknown fault kind is the scenario loader's to reject: run 1 carries it.
        message = ("run 1: expected a run the scenario loader accepts, got faults[0].kind: "
                   "expected one of")
    with pytest.raises(CampaignError) as e:
        load_campaign(p)
    assert "\n" not in str(e.value)
    assert str(e.value).startswith(f"{p}: {message}") or \
        str(e.value).startswith(f"{p.name}: {message}"), str(e.value)


def test_bad_campaign_on_the_command_line(write_campaign, tmp_path: Path) -> None:
    p = write_campaign(tmp_path, GOOD.replace("runs: 40", "runs: many"))
    r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", str(p), "--workers", "1"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr == "error: c.yaml: runs: expected an integer, got 'many'\n"
    assert r.stdout == ""


def test_option_of_another_action_is_refused(write_campaign, tmp_path: Path) -> None:
    p = write_campaign(tmp_path, GOOD)
    r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", str(p), "--run", "3"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr == ("error: hil campaign run: --run: expected no such option for this "
                        "action, got '3'\n")


def test_run_k_depends_on_seed_and_index_alone(write_campaign, tmp_path: Path) -> None:
    c = load_campaign(write_campaign(tmp_path, GOOD))
    # More runs in the file and a new dispersion change nothing of run 7's other draws.
    c2 = load_campaign(write_campaign(
        tmp_path, GOOD.replace("runs: 40", "runs: 400").replace(
            "dispersions:\n", "dispersions:\n  direction_error_deg: {uniform: [0, 2]}\n"),
        "c2.yaml"))
    a, b = expand_run(c, 7), expand_run(c2, 7)
    assert a.scenario["plant"]["thrust_scale"] == b.scenario["plant"]["thrust_scale"]
    assert a.scenario["initial"] == b.scenario["initial"]
    assert a.fault == b.fault and a.scenario["seed"] == b.scenario["seed"]
    assert "direction_error_deg" in b.scenario["plant"]
    # Different runs differ; the same run expanded twice is identical.
    assert expand_run(c, 7) == a
    assert expand_run(c, 8).scenario["seed"] != a.scenario["seed"]
    # A different master seed gives different draws.
    c3 = load_campaign(write_campaign(tmp_path, GOOD.replace("seed: 5", "seed: 6"), "c3.yaml"))
    assert expand_run(c3, 7).scenario["seed"] != a.scenario["seed"]


def test_cycle_covers_every_kind_and_thruster(write_campaign, tmp_path: Path) -> None:
    c = load_campaign(write_campaign(tmp_path, GOOD))
    pairs = {(expand_run(c, k).fault["kind"], expand_run(c, k).fault["thruster"])
             for k in range(12)}
    assert len(pairs) == 12  # 2 kinds x 6 thrusters
    assert all(expand_run(c, k).fault.get("fraction") == (0.5 if expand_run(c, k).fault["kind"]
                                                          == "stuck_on" else None)
               for k in range(12))


def test_draws_within_their_distributions(write_campaign, tmp_path: Path) -> None:
    c = load_campaign(write_campaign(tmp_path, GOOD))
    for k in range(40):
        s = expand_run(c, k)
        assert 0.85 <= s.scenario["plant"]["thrust_scale"] <= 1.15
        assert s.scenario["plant"]["command_latency_ms"] in (0.0, 5.0, 15.0)
        assert 0.0 <= s.params["initial_angle_deg"] <= 30.0
        r = s.scenario["initial"]["rate_B_deg_s"]
        assert abs(sum(x * x for x in r) ** 0.5 - s.params["initial_rate_deg_s"]) < 1e-9
        assert 2.0 <= s.fault["t_s"] <= 8.0


def test_expanded_run_is_an_ordinary_scenario(write_campaign, tmp_path: Path) -> None:
    c = load_campaign(write_campaign(tmp_path, GOOD))
    s = expand_run(c, 3)
    path = write_run(s, tmp_path / "out")
    sc = load_scenario(path)
    assert sc.cfg.name == "t-00003"
    assert sc.cfg.seed == s.scenario["seed"]
    assert sc.cfg.faults[0].thruster == s.fault["thruster"]
    assert sc.cfg.plant.thrust_scale == s.scenario["plant"]["thrust_scale"]
    # Gyro bias is a vehicle figure: the run carries its own vehicle file.
    assert (tmp_path / "out" / "t-00003.vehicle.yaml").exists()
    assert list(sc.vehicle.gyro.bias_rad_s) == s.vehicle["gyro"]["bias_rad_s"]
    # The command line writes the same file.
    out2 = tmp_path / "cli"
    r = subprocess.run([sys.executable, "-m", "hil.cli", "campaign", "expand",
                        str(tmp_path / "c.yaml"), "--run", "3", "--out", str(out2)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (out2 / "t-00003.yaml").read_text() == path.read_text()


def test_base_scenario(write_campaign, tmp_path: Path) -> None:
    from hil.config import SCENARIO_DIR

    text = (f"name: b\nbase: {{scenario: {SCENARIO_DIR / 'S003-flex.yaml'}}}\nruns: 3\n"
            "seed: 1\ndispersions:\n  flex_freq_scale: {uniform: [0.9, 1.1]}\n")
    c = load_campaign(write_campaign(tmp_path, text))
    base = load_scenario(SCENARIO_DIR / "S003-flex.yaml")
    s = expand_run(c, 1)
    sc = load_scenario(write_run(s, tmp_path / "o"))
    assert sc.cfg.duration_s == base.cfg.duration_s
    assert sc.cfg.plant.thrust_scale == base.cfg.plant.thrust_scale
    assert sc.vehicle.flight == base.vehicle.flight
    for m, m0, k in zip(sc.vehicle.flex_modes, base.vehicle.flex_modes, s.params[
            "flex_freq_scale"], strict=True):
        assert m.freq_hz == pytest.approx(m0.freq_hz * k, rel=1e-10)
        assert 0.9 <= k <= 1.1


GYRO = """name: g
base: {vehicle: generic}
runs: 40
seed: 3
duration_s: 20.0
fault:
  kind: {cycle: [gyro_spike, gyro_bias_step, gyro_frozen, gyro_noise]}
  thruster: none
  axis: {choice: [0, 1, 2]}
  t_s: {uniform: [2.0, 10.0]}
  magnitude_rad_s:
    gyro_spike: {uniform: [2.0e-3, 2.0e-2]}
    gyro_bias_step: {uniform: [2.0e-4, 1.0e-3]}
    gyro_noise: {fixed: 5.0e-5}
  clear_after_s: {gyro_frozen: {uniform: [2.0, 4.0]}}
"""


def test_magnitude_and_clear_time_per_fault_kind(tmp_path, write_campaign) -> None:
    """``magnitude_rad_s`` and ``clear_after_s`` as mappings fault kind -> distribution: each
    kind draws from its own, a kind without one gets none (the expanded scenario loads)."""
    c = load_campaign(write_campaign(tmp_path, GYRO))
    lim = {"gyro_spike": (2e-3, 2e-2), "gyro_bias_step": (2e-4, 1e-3),
           "gyro_noise": (5e-5, 5e-5)}
    seen = set()
    for k in range(12):
        f = expand_run(c, k).fault
        seen.add(f["kind"])
        if f["kind"] in lim:
            lo, hi = lim[f["kind"]]
            assert lo <= f["magnitude_rad_s"] <= hi, f
            assert "clear_t_s" not in f, f
        else:
            assert "magnitude_rad_s" not in f and 2.0 <= f["clear_t_s"] - f["t_s"] <= 4.0, f
        assert f["axis"] in (0, 1, 2)
    assert seen == {"gyro_spike", "gyro_bias_step", "gyro_frozen", "gyro_noise"}
    (tmp_path / "runs").mkdir()
    path = write_run(expand_run(c, 2), tmp_path / "runs")
    assert load_scenario(path).cfg.faults[0].kind == "gyro_frozen"
    with pytest.raises(CampaignError, match="fault.magnitude_rad_s.gyro_spik: expected a fault "
                                            "kind of fault.kind"):
        load_campaign(write_campaign(tmp_path, GYRO.replace("gyro_spike: {uniform",
                                                            "gyro_spik: {uniform"), "bad.yaml"))
