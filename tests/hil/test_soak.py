"""`hil soak`'s figures: growth per simulated hour by least squares over the second half."""

from __future__ import annotations

import json
import os

import pytest

from hil.soak import figures, growth_per_hour, last_t_s, rss_kb


def test_growth_is_the_slope_per_simulated_hour_over_the_second_half() -> None:
    # 2 MB of start-up in the first half, then exactly 27 MB per simulated hour.
    samples = [{"wall_s": k, "sim_s": 60.0 * k,
                "plant_rss_kb": 70_000 + (2048 if k > 0 else 0) + 27 * 1024 * (k / 60.0)}
               for k in range(40)]
    assert growth_per_hour(samples, "plant_rss_kb") == pytest.approx(27 * 1024)
    fig = figures(samples)
    assert fig["plant_rss_mb"]["per_sim_hour"] == pytest.approx(27.0, abs=1e-3)
    assert fig["samples"] == 40 and fig["sim_s"] == 60.0 * 39


def test_too_few_samples_give_no_growth_figure() -> None:
    assert growth_per_hour([{"sim_s": 1.0, "x": 1}] * 3, "x") is None
    assert figures([]) == {"samples": 0}


def test_last_record_time_reads_the_tail_and_skips_a_torn_line(tmp_path) -> None:
    p = tmp_path / "plant.jsonl"
    p.write_text("".join(json.dumps({"tick": n, "t_s": 0.2 * n}) + "\n" for n in range(5000))
                 + '{"tick": 5000, "t_')
    assert last_t_s(p) == pytest.approx(0.2 * 4999)
    assert last_t_s(tmp_path / "none.jsonl") is None


def test_rss_of_this_process_and_of_a_gone_one() -> None:
    assert rss_kb(os.getpid()) > 1000
    assert rss_kb(2**22 + 12345) is None


def test_soak_leaves_no_temporary_folder_behind(tmp_path, monkeypatch, capsys) -> None:
    """The generated scenario lives in a temporary folder that goes with the command, also
    when the command stops on an argument error."""
    import tempfile

    from hil.cli import main as hil_main

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert hil_main(["soak", "--hours", "1", "--bus", "lcm", "--interface", "socketcan"]) == 2
    assert "--interface" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
