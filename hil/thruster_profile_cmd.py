"""``hil thruster-profile``: the calibrated seed 004 eq. 4.1 profile and its pulse impulses.

Prints ``k1, k2, T_R, n1, n2``, the on/off lags computed back from the profile by numerical
integration of seed 004's equal-area definition (``scipy.integrate.quad``, independent of the
closed-form calibration), and for every allowed on-duration the exact impulse of an isolated
pulse, the ideal ``P (tau - tau_on + tau_off)`` and their deviation in %.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from scipy.integrate import quad

from hil.config import load_vehicle
from plant.thruster import ThrustProfile, allowed_on_ms


def lags_from_profile_s(prof: ThrustProfile) -> tuple[float, float]:
    """Equal-area lags (seed 004) by quadrature: missing area of the rise up to 0.99 P_nom,
    added area of the decay down to 0.01 P_nom, both from the command, in units of P_nom."""
    t99 = prof.rise_time_s(0.99)
    t01 = prof.decay_time_s(0.01)
    on, _ = quad(lambda t: 1.0 - prof.rise_level(t), 0.0, t99, points=[prof.t_r_s],
                 epsabs=1e-13, epsrel=1e-12, limit=200)
    off, _ = quad(prof.decay_level, 0.0, t01, points=[prof.t_r_s], epsabs=1e-13,
                  epsrel=1e-12, limit=200)
    return on, off


def profile_report(vehicle_name: str) -> dict[str, Any]:
    v = load_vehicle(vehicle_name)
    prof = ThrustProfile.calibrate(v.thrust_profile, f"vehicles/{v.name}: thrust_profile")
    on_s, off_s = lags_from_profile_s(prof)
    rows = []
    p_nom = [t.thrust_n for t in v.thrusters]
    p_ref = p_nom[0] if len(set(p_nom)) == 1 else None
    for tau_ms in allowed_on_ms(v.timing):
        imp = prof.pulse_impulse_s(tau_ms / 1000.0)
        ideal = prof.effective_time_s(tau_ms / 1000.0)
        dev = None if ideal == 0 else 100.0 * (imp - ideal) / ideal
        rows.append({
            "on_ms": tau_ms,
            "impulse_per_N_s": imp,
            "ideal_per_N_s": ideal,
            "impulse_Ns": None if p_ref is None else imp * p_ref,
            "ideal_Ns": None if p_ref is None else ideal * p_ref,
            "deviation_pct": dev,
        })
    return {
        "vehicle": v.name,
        "thrust_n": p_ref,
        "T_R_ms": prof.t_r_s * 1000.0,
        "k1_per_s_n1": prof.k1,
        "n1": prof.n1,
        "k2_per_s_n2": prof.k2,
        "n2": prof.n2,
        "on_lag_ms_config": v.thrust_profile.on_lag_ms,
        "off_lag_ms_config": v.thrust_profile.off_lag_ms,
        "on_lag_ms_from_profile": on_s * 1000.0,
        "off_lag_ms_from_profile": off_s * 1000.0,
        "rise_to_99pct_ms": prof.rise_time_s(0.99) * 1000.0,
        "decay_to_1pct_ms": prof.decay_time_s(0.01) * 1000.0,
        "pulses": rows,
    }


def _print_table(r: dict[str, Any]) -> None:
    print(f"vehicle {r['vehicle']}: thrust profile (seed 004 eq. 4.1)")
    print(f"  T_R = {r['T_R_ms']:.3f} ms   n1 = {r['n1']:g}   k1 = {r['k1_per_s_n1']:.6g} s^-n1"
          f"   n2 = {r['n2']:g}   k2 = {r['k2_per_s_n2']:.6g} s^-n2")
    print(f"  on-lag  {r['on_lag_ms_from_profile']:.4f} ms from the profile "
          f"(config {r['on_lag_ms_config']:g}); rise to 0.99 P in {r['rise_to_99pct_ms']:.2f} ms")
    print(f"  off-lag {r['off_lag_ms_from_profile']:.4f} ms from the profile "
          f"(config {r['off_lag_ms_config']:g}); decay to 0.01 P in "
          f"{r['decay_to_1pct_ms']:.2f} ms")
    newtons = r["thrust_n"] is not None
    unit = "N s" if newtons else "P s"
    print()
    print(f"  {'on_ms':>6}  {'impulse ' + unit:>14}  {'ideal ' + unit:>14}  {'dev %':>8}")
    for row in r["pulses"]:
        imp = row["impulse_Ns"] if newtons else row["impulse_per_N_s"]
        ideal = row["ideal_Ns"] if newtons else row["ideal_per_N_s"]
        dev = "" if row["deviation_pct"] is None else f"{row['deviation_pct']:+.3f}"
        print(f"  {row['on_ms']:>6}  {imp:>14.6f}  {ideal:>14.6f}  {dev:>8}")
    print()
    print("  ideal = P (tau - tau_on + tau_off); impulse = exact integral of an isolated pulse")
    if not newtons:
        print("  (thrusters differ: figures per newton of nominal thrust)")


def _cmd_profile(args: argparse.Namespace) -> int:
    r = profile_report(args.vehicle)
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        _print_table(r)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``thruster-profile`` to the ``hil`` sub-commands."""
    p = sub.add_parser(
        "thruster-profile",
        help="calibrated thrust profile, lags and pulse impulses of a vehicle",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--vehicle", required=True, help="vehicle name (configs/vehicles) or YAML path")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=_cmd_profile)
