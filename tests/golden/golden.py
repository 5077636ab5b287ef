"""Golden traces: every reference scenario in ``configs/scenarios/`` run in-process
(``hil.sim.simulate``), reduced to SHA-256 digests of the raw float64 bytes of the plant's truth
and the flight's outputs per tick, plus the detections in full.

The reference files ``tests/golden/<scenario>.json`` were written on the commit before the
architecture restructuring (which left every one unchanged) and written again, on purpose,
when the FDIR envelope work changed the detector, the observer and the plant's random torque,
and again with the isolation of opposite thrusters on numpy 2.4.6 / scipy 1.17.1 (pinned in
pyproject.toml; the earlier files no longer matched on this machine's libraries), and for
orel's five scenarios with its per-channel flex frequencies and common thrust-scale share,
and for the five whose gyro-check verdicts moved when a jump after a jump stopped being held
(REC-stuck detects at 30.8 s, was 31.0; the others' detections unchanged), and for those the
gyro check's later changes moved without moving a detection (S000-stuck, S002-100, S002-50,
S004-polar), and when the detector stopped taking the observer's residual where the measured
rate changed as the model said and the gyro check's jump level went to 5 dead zones
(REC-nofire, REC-stuck, S000-nofire, S002-50 unchanged detections; S002-15 detects at 701.6 s,
was 704.4), and again when the last tick's thrusters came to count in the gyro check's slack on
ticks without thrust (S000-nofire, S002-50, S002-15: the same detections), and for REC-nofire
when orel's flight came to test a thruster whose burn read short with pulses of it alone (19
named fails to fire at 38.8 s by the pulses, was 38.6 s by the detector's crossing: the test
holds the controller's commands, the crossing came from them), and for the nine orel and
iss_rs scenarios when their flight records came to count the test pulses (``pulse_tests``;
their truth, flight outputs and detections did not move);
``test_golden.py`` re-runs the scenarios and compares bit for bit.

Every trace is computed in a child process under one numeric environment whatever the CPU
(``PORTABLE_ENV``): glibc's libm, NumPy's loops and OpenBLAS on their SSE code paths (the
settings ``hil.uml_fpu`` uses inside user-mode Linux) and one BLAS thread. On their default
paths they pick kernels by CPU (AVX2, AVX-512, FMA) that round differently: the files written
on an Intel machine with AVX-512 did not match on an AMD one. They were written again under
that environment (every detection the same, to the bit in time, kind and thruster).
A change that is meant to change the numbers regenerates them on purpose::

    .venv/bin/python -m tests.golden.golden            # every scenario
    .venv/bin/python -m tests.golden.golden S000-stuck  # one
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from hil.uml_fpu import SSE_ONLY_ENV

GOLDEN_DIR = Path(__file__).resolve().parent
ROOT = GOLDEN_DIR.parents[1]
SCENARIO_DIR = ROOT / "configs" / "scenarios"
# The numeric environment of every trace (module doc); the child checks it got it.
PORTABLE_ENV = {**SSE_ONLY_ENV, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}

TRUTH_FIELDS = ("q_BO", "q_BI", "omega_B_rad_s", "omega_BO_B_rad_s", "flex_q", "flex_qdot",
                "flex_rate_gyro_B_rad_s", "v_O_m_s", "dv_B_m_s", "thrust_n", "valve_cmd",
                "manifold_open", "impulse_Ns", "fuel_kg", "h_cmg_B_Nms")
OUTPUT_FIELDS = ("on_ms", "manifold_open", "available", "omega_meas", "omega_est", "omega_pred",
                 "residual", "gamma_est", "freq_est_hz", "xi", "rho_on", "rho_off")


def scenario_names() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def _digest(rows: list[Any]) -> str:
    h = hashlib.sha256()
    for r in rows:
        h.update(np.ascontiguousarray(np.asarray(r, dtype=np.float64)).tobytes())
    return h.hexdigest()


def trace(name: str) -> dict[str, Any]:
    """``trace_here(name)`` computed in a child process under ``PORTABLE_ENV``."""
    env = {**os.environ, **PORTABLE_ENV}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(GOLDEN_DIR), env.get("PYTHONPATH"))
                                        if p)
    proc = subprocess.run([sys.executable, "-c", f"import golden; golden._child({name!r})"],
                          env=env, cwd=ROOT, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"golden trace of {name}: child exited {proc.returncode}: "
                           f"{proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout)


def _child(name: str) -> None:
    missing = {k: v for k, v in PORTABLE_ENV.items() if os.environ.get(k) != v}
    if missing:
        raise SystemExit(f"golden: expected the environment {missing}")
    sys.stdout.write(json.dumps(trace_here(name)))


def trace_here(name: str) -> dict[str, Any]:
    """Digests and detections of one in-process run of scenario ``name``, in this process
    (whatever its numeric environment: ``trace`` is the one the files hold)."""
    from hil.sim import simulate

    run = simulate(SCENARIO_DIR / f"{name}.yaml", keep=True)
    truth = {f: _digest([getattr(t, f) for t in run.truth]) for f in TRUTH_FIELDS}
    truth["t_s"] = _digest([t.t_s for t in run.truth])
    truth["fuel_total_kg"] = _digest([t.fuel_total_kg for t in run.truth])
    outputs = {f: _digest([getattr(o, f) for o in run.outputs]) for f in OUTPUT_FIELDS}
    records = hashlib.sha256(json.dumps([run.plant_records, run.flight_records],
                                        sort_keys=True).encode()).hexdigest()
    detections = [r["detection"] for r in run.flight_records if r["detection"] is not None]
    last = run.truth[-1]
    return {
        "scenario": name,
        "ticks": len(run.truth),
        "final": {"t_s": float(last.t_s).hex(),
                  "omega_B_rad_s": [float(x).hex() for x in last.omega_B_rad_s],
                  "q_BO": [float(x).hex() for x in last.q_BO]},
        "truth_sha256": truth,
        "outputs_sha256": outputs,
        "records_sha256": records,
        "detections": detections,
    }


def write(names: list[str]) -> None:
    for name in names:
        out = GOLDEN_DIR / f"{name}.json"
        out.write_text(json.dumps(trace(name), indent=1, sort_keys=True) + "\n")
        print(f"golden: wrote {out.relative_to(GOLDEN_DIR.parents[1])}")


if __name__ == "__main__":
    write(sys.argv[1:] or scenario_names())
