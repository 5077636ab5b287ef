"""The LCM options and settings without a network (docs/lcm.md): one-line errors, the bus a
run resolves to, telemetry messages built from records, the sender's set order."""

from __future__ import annotations

import argparse
from pathlib import Path

import lcm
import pytest

from bus.codec import Gyro, ThrCmd
from bus.lcm_transport import DEFAULT_URL, LcmPort
from hil.cli import main as hil_main
from hil.config import load_scenario
from hil.hil_telemetry import flight_view_t, truth_t
from hil.run import resolve_bus
from hil.telemetry import Telemetry, flight_view_message, truth_message

REPO = Path(__file__).resolve().parents[2]
S000 = REPO / "configs/scenarios/S000-stuck.yaml"


def _scenario(tmp_path: Path, bus_line: str) -> Path:
    text = S000.read_text().replace("vehicle: generic", f"vehicle: {REPO}/configs/vehicles/"
                                    "generic.yaml")
    p = tmp_path / "s.yaml"
    p.write_text(text + f"\nbus: {bus_line}\n")
    return p


@pytest.mark.parametrize("bus_line, message", [
    ('{kind: lcm, url: "memq://"}',
     r"bus.url: expected a string matching ^(udpm|tcpq)://[^\s]+$, got 'memq://'"),
    ('{kind: can, url: "udpm://239.1.1.1:7667"}',
     "bus.url: expected no url with kind can (the LCM provider is for kind lcm), got "
     "'udpm://239.1.1.1:7667'"),
    ("{kind: zmq}", "bus.kind: expected one of 'can' or 'lcm', got 'zmq'"),
])
def test_scenario_bus_errors_are_one_line(tmp_path, capsys, bus_line, message):
    p = _scenario(tmp_path, bus_line)
    assert hil_main(["config", "check", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {p}: {message}"


def _args(**kw) -> argparse.Namespace:
    base = dict(interface=None, channel=None, bus=None, lcm_url=None,
                telemetry=None, lcm_log=False)
    return argparse.Namespace(**{**base, **kw})


def test_the_bus_a_run_resolves_to(tmp_path):
    sc = load_scenario(_scenario(tmp_path, '{kind: lcm, url: "udpm://239.255.76.67:7700"}'))
    a = _args()
    resolve_bus(a, sc)
    assert (a.interface, a.channel, a.telemetry) == ("lcm", "udpm://239.255.76.67:7700",
                                                     "udpm://239.255.76.67:7700")
    a = _args(bus="can")  # the command line wins over the scenario
    resolve_bus(a, sc)
    assert (a.interface, a.channel, a.telemetry) == ("socketcan", "vcan0", None)
    # ... also in the re-run (namespace, user-mode Linux), which gets the resolved bus
    from hil.run import _lcm_argv

    assert _lcm_argv(a) == ["--bus", "can"]
    again = _args(bus="can", interface="socketcan", channel="vcan0")
    resolve_bus(again, sc)
    assert again.interface == "socketcan"
    a = _args(lcm_log=True)  # a CAN run with its telemetry on the default URL
    resolve_bus(a, load_scenario(S000))
    assert (a.interface, a.telemetry) == ("socketcan", DEFAULT_URL)


def test_lcm_url_alone_is_refused(capsys):
    assert hil_main(["run", str(S000), "--lcm-url", "udpm://239.255.76.67:7700"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: --lcm-url: expected it with --bus lcm, --telemetry or --lcm-log, got "
        "'udpm://239.255.76.67:7700' with the can bus alone")
    assert hil_main(["fault", "clear", "--vehicle", "generic", "--lcm-url", "udpm://x:1"]) == 2
    assert "fault: --lcm-url: expected it with --bus lcm" in capsys.readouterr().err


def test_telemetry_messages_carry_the_records():
    plant = {"tick": 7, "t_s": 1.6, "att_err_deg": 3.5, "rate_err_deg_s": 0.25,
             "fuel_kg": 0.0125, "dv_B_m_s": [0.1, 0.0, -0.2], "safe": True,
             "series": {"truth/omega_deg_s": {"x": 1.0, "y": 2.0, "z": 3.0}},
             "events": ["fault active: stuck_on X+ at 1.60 s"]}
    m = truth_t.decode(truth_message(plant).encode())
    assert (m.tick, m.t_s, m.att_err_deg, m.fuel_kg, m.safe) == (7, 1.6, 3.5, 0.0125, True)
    assert list(m.dv_B_m_s) == [0.1, 0.0, -0.2]
    assert dict(zip(m.names, m.values, strict=True)) == {
        "truth/omega_deg_s/x": 1.0, "truth/omega_deg_s/y": 2.0, "truth/omega_deg_s/z": 3.0}
    assert list(m.events) == plant["events"]
    flight = {"tick": 9, "t_s": 1.8, "compute_s": 0.002, "overruns": 1,
              "detection": {"type": "stuck_on", "thruster": ["X+", "Y-"], "source": "residual",
                            "rho": 4.5}, "series": {}, "events": []}
    v = flight_view_t.decode(flight_view_message(flight).encode())
    assert (v.detection_type, v.detection_thruster, v.detection_rho) == ("stuck_on", "X+|Y-",
                                                                          4.5)
    assert v.n_values == 0 and v.compute_s == 0.002 and v.overruns == 1


def test_telemetry_publishes_on_its_channels():
    lc = lcm.LCM("memq://")
    got = []
    lc.subscribe("HIL_.*", lambda ch, data: got.append(ch))
    Telemetry("plant", "memq://", lc=lc).publish({"tick": 0, "t_s": 0.2})
    Telemetry("flight", "memq://", lc=lc).publish({"tick": 0, "t_s": 0.0})
    while lc.handle_timeout(50) > 0:
        pass
    assert got == ["HIL_TRUTH", "HIL_FLIGHT_VIEW"]


def test_a_set_sent_out_of_order_is_lost_whole():
    """LCM carries whole sets: a frame out of set order loses the partial set (counted in
    tx_errors), and nothing half-made goes on the bus."""
    lc = lcm.LCM("memq://")
    tx, rx = LcmPort("memq://", lc=lc), LcmPort("memq://", lc=lc)
    frames = tx.protect(ThrCmd(3, (3, 4, 5), 1, 9))
    for fr in (frames[0], frames[1], frames[3]):
        tx.send_frame(fr)
    assert tx.tx_errors == 3 and tx.tx_frames == 0
    assert rx.poll(0.1) == []
    tx.send(Gyro(1, (0.0, 0.0, 0.0), 1))
    assert [type(m) for m, _ in rx.poll(0.1)] == [Gyro]
    tx.close()
    rx.close()


@pytest.mark.parametrize("argv, message", [
    (["run", str(S000), "--bus", "lcm", "--interface", "udp_multicast"],
     "error: --interface: expected no python-can interface with the lcm bus (--lcm-url names "
     "its provider), got 'udp_multicast'"),
    (["run-all", "--bus", "lcm", "--channel", "vcan1"],
     "error: run-all: --channel: expected no python-can channel with the lcm bus (--lcm-url "
     "names its provider), got 'vcan1'"),
    (["run-all", "--lcm-url", "udpm://239.255.76.67:7700"],
     "error: run-all: --lcm-url: expected it with the lcm bus, got "
     "'udpm://239.255.76.67:7700' with the can bus"),
    (["soak", "--hours", "1", "--bus", "lcm", "--interface", "socketcan"],
     "error: --interface: expected no python-can interface with the lcm bus (--lcm-url names "
     "its provider), got 'socketcan'"),
    (["soak", "--hours", "1", "--lcm-url", "udpm://239.255.76.67:7700"],
     "error: --lcm-url: expected it with --bus lcm, got 'udpm://239.255.76.67:7700' with the "
     "can bus alone"),
    (["bench", "--bus", "lcm", "--parts", "realtime,bus"],
     "error: hil bench: --parts: expected realtime, lockstep, allocator with --bus lcm (bus and "
     "load measure CAN; bench/bench_lcm.py measures LCM), got 'realtime,bus'"),
    (["bench", "--bus", "lcm", "--bitrate", "500000"],
     "error: hil bench: --bitrate: expected it only with the can bus (the ping-pong and the bus "
     "load are CAN's), got 500000 with --bus lcm"),
    (["bench", "--lcm-url", "udpm://239.255.76.67:7700"],
     "error: hil bench: --lcm-url: expected it with --bus lcm, got "
     "'udpm://239.255.76.67:7700' with the can bus"),
    (["campaign", "expand", str(REPO / "configs/campaigns/ci-generic.yaml"), "--run", "1",
      "--bus", "lcm"],
     "error: hil campaign expand: --bus: expected no such option for this action, got 'lcm'"),
])
def test_options_of_the_other_bus_are_refused(capsys, argv, message):
    assert hil_main(argv) == 2
    assert capsys.readouterr().err.strip() == message


def test_run_all_takes_one_bus_for_the_set(tmp_path, capsys):
    """Without --bus the scenarios' bus: decides, and they must agree (never a CAN run of a
    scenario that names LCM); --bus decides for all."""
    from hil.errors import UsageError
    from hil.runall import run_all_bus

    a = _scenario(tmp_path, '{kind: lcm}')
    b = tmp_path / "b.yaml"
    b.write_text(S000.read_text().replace("vehicle: generic",
                                          f"vehicle: {REPO}/configs/vehicles/generic.yaml"))
    args = argparse.Namespace(bus=None, interface=None, channel=None, lcm_url=None)
    with pytest.raises(UsageError) as exc:
        run_all_bus(args, [a, b])
    assert str(exc.value) == ("run-all: bus: expected every scenario on one bus (or --bus "
                              "can|lcm for all), got s: lcm, b: can")
    assert run_all_bus(args, [a]) == "lcm" and args.interface == "socketcan"
    args = argparse.Namespace(bus="can", interface=None, channel=None, lcm_url=None)
    assert run_all_bus(args, [a, b]) == "can" and args.channel == "vcan0"


def test_an_expanded_campaign_run_keeps_its_base_bus(tmp_path):
    """`hil campaign --bus` runs a sampled run over the bus its base scenario names."""
    import yaml

    from hil.campaign.expansion import expand_run
    from hil.campaign.load import load_campaign

    base = _scenario(tmp_path, '{kind: lcm, url: "udpm://239.255.76.67:7701?ttl=0"}')
    c = tmp_path / "c.yaml"
    c.write_text(yaml.safe_dump({"name": "c", "base": {"scenario": str(base)}, "runs": 2,
                                 "seed": 1, "duration_s": 2.0}))
    spec = expand_run(load_campaign(c), 1)
    assert spec.scenario["bus"] == {"kind": "lcm", "url": "udpm://239.255.76.67:7701?ttl=0"}
