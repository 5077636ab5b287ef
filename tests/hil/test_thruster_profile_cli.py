"""`hil thruster-profile` (hil.thruster_profile_cmd): lags and pulse impulses via the CLI.

Oracles: the configured lags of ``configs/vehicles/orel.yaml`` (seed 004 section 4: 30 ms on,
27 ms off), the nominal thrust read from the same file, and seed 004's effective firing time
``tau - tau_on + tau_off = tau - 3 ms``; the lags are also recomputed here by quadrature of eq.
4.1 from the printed constants ``T_R, k1, n1, k2, n2`` (equal-area definition).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from scipy.integrate import quad

from hil.cli import main
from hil.config import VEHICLE_DIR

OREL = yaml.safe_load((VEHICLE_DIR / "orel.yaml").read_text())
P_NOM_N = OREL["thrusters"][0]["thrust_n"]
# Seed 004 section 4: 10 ms quanta, at least 30 ms on and 30 ms off in a 200 ms tick.
ALLOWED_MS = [0, *range(30, 171, 10), 200]


@pytest.fixture(scope="module")
def report_json() -> dict:
    """``hil thruster-profile --vehicle orel --json`` parsed (run once for the module)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["thruster-profile", "--vehicle", "orel", "--json"])
    assert rc == 0
    assert err.getvalue() == ""
    return json.loads(out.getvalue())


def test_orel_config_is_what_the_oracles_assume() -> None:
    """The oracles below rest on these configured figures (all 30 thrusters equal)."""
    assert {t["thrust_n"] for t in OREL["thrusters"]} == {P_NOM_N}
    assert len(OREL["thrusters"]) == 30
    assert OREL["thrust_profile"]["on_lag_ms"] == 30.0
    assert OREL["thrust_profile"]["off_lag_ms"] == 27.0


def test_json_lags_equal_configured_30_and_27_ms(report_json: dict) -> None:
    r = report_json
    assert r["vehicle"] == "orel"
    assert r["thrust_n"] == P_NOM_N
    assert r["on_lag_ms_from_profile"] == pytest.approx(30.0, abs=0.1)
    assert r["off_lag_ms_from_profile"] == pytest.approx(27.0, abs=0.1)
    assert r["on_lag_ms_config"] == 30.0 and r["off_lag_ms_config"] == 27.0


def test_json_constants_reproduce_the_lags_by_quadrature(report_json: dict) -> None:
    """Seed 004's definition from the printed constants alone: missing area up to 0.99 P_nom
    (from the command, T_R included) = tau_on, added area down to 0.01 P_nom = tau_off."""
    r = report_json
    t_r = r["T_R_ms"] / 1000.0
    k1, n1, k2, n2 = r["k1_per_s_n1"], r["n1"], r["k2_per_s_n2"], r["n2"]
    t99 = t_r + (math.log(100.0) / k1) ** (1 / n1)
    t01 = t_r + (math.log(100.0) / k2) ** (1 / n2)
    assert t99 * 1000 == pytest.approx(r["rise_to_99pct_ms"], rel=1e-9)
    assert t01 * 1000 == pytest.approx(r["decay_to_1pct_ms"], rel=1e-9)
    on = t_r + quad(lambda x: math.exp(-k1 * x**n1), 0.0, t99 - t_r, epsrel=1e-12)[0]
    off = t_r + quad(lambda x: math.exp(-k2 * x**n2), 0.0, t01 - t_r, epsrel=1e-12)[0]
    assert on * 1000 == pytest.approx(30.0, abs=0.1)
    assert off * 1000 == pytest.approx(27.0, abs=0.1)


def test_json_impulses_equal_p_nom_times_tau_minus_3_ms(report_json: dict) -> None:
    """Every allowed duration is listed; for tau >= 50 ms the impulse is ``P_nom (tau - 3 ms)``
    within 1 % (docs/design.md 5.4); 0 ms gives 0; the 30 and 40 ms pulses fall short (they never
    reach P_nom), which the table reports as a negative deviation."""
    rows = {row["on_ms"]: row for row in report_json["pulses"]}
    assert sorted(rows) == ALLOWED_MS
    for tau_ms, row in rows.items():
        ideal = P_NOM_N * (tau_ms - 3.0) / 1000.0 if tau_ms else 0.0
        assert row["ideal_Ns"] == pytest.approx(ideal, rel=1e-12, abs=1e-15)
        assert row["impulse_Ns"] == pytest.approx(row["impulse_per_N_s"] * P_NOM_N, rel=1e-12)
        if tau_ms >= 50:
            assert row["impulse_Ns"] == pytest.approx(ideal, rel=0.01)
            assert abs(row["deviation_pct"]) < 1.0
            assert row["deviation_pct"] == pytest.approx(100 * (row["impulse_Ns"] / ideal - 1),
                                                         rel=1e-9, abs=1e-9)
        elif tau_ms == 0:
            assert row["impulse_Ns"] == 0.0 and row["deviation_pct"] is None
        else:
            assert row["impulse_Ns"] < ideal
    # Each extra 10 ms of a lit thruster adds P_nom x 10 ms (within 1 %: the 50 ms pulse has
    # not quite reached P_nom).
    lit = [rows[t]["impulse_Ns"] for t in ALLOWED_MS if t >= 50]
    steps = [b - a for a, b in zip(lit[:-1], lit[1:], strict=True)]
    assert all(s == pytest.approx(P_NOM_N * 0.010, rel=0.01) for s in steps[:-1])


def test_table_shows_the_same_figures(capsys, report_json: dict) -> None:
    """The human table carries the lags and one row per allowed duration, with the JSON's
    impulse in N s (6 decimals)."""
    assert main(["thruster-profile", "--vehicle", "orel"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("vehicle orel")
    on_line = next(ln for ln in lines if ln.strip().startswith("on-lag"))
    off_line = next(ln for ln in lines if ln.strip().startswith("off-lag"))
    assert float(on_line.split()[1]) == pytest.approx(30.0, abs=0.1)
    assert float(off_line.split()[1]) == pytest.approx(27.0, abs=0.1)
    rows = {}
    for ln in lines:
        parts = ln.split()
        if parts and parts[0].isdigit():
            rows[int(parts[0])] = [float(p) for p in parts[1:]]
    assert sorted(rows) == ALLOWED_MS
    by_ms = {row["on_ms"]: row for row in report_json["pulses"]}
    for tau_ms, vals in rows.items():
        assert vals[0] == pytest.approx(by_ms[tau_ms]["impulse_Ns"], abs=5e-7)
        assert vals[1] == pytest.approx(P_NOM_N * max(tau_ms - 3.0, 0.0) / 1000.0
                                        if tau_ms else 0.0, abs=5e-7)


def test_unknown_vehicle_exits_2_with_one_line(capsys) -> None:
    assert main(["thruster-profile", "--vehicle", "nosuch"]) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    lines = cap.err.splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("error: ") and "nosuch" in lines[0]
    assert "Traceback" not in cap.err


def test_unknown_vehicle_through_the_console_script() -> None:
    """The installed ``hil`` entry: exit 2, exactly one ``error:`` line, no traceback."""
    hil = Path(sys.executable).with_name("hil")
    proc = subprocess.run([str(hil), "thruster-profile", "--vehicle", "nosuch"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "nosuch" in lines[0]


def test_missing_vehicle_argument_is_a_usage_error(capsys) -> None:
    assert main(["thruster-profile"]) == 2
    assert "--vehicle" in capsys.readouterr().err
