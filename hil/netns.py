"""A private network namespace for LCM's UDP multicast (docs/lcm.md).

LCM's ``udpm://`` provider needs a multicast route (``lcm.LCM()`` fails with "LCM requires a
valid multicast route" without one), and every LCM program on a host that uses the same
group and port hears every other one. ``hil run --bus lcm`` (and ``hil up``) therefore
re-runs itself, with its processes, inside a network namespace of its own:

    unshare --net  ->  ip link set lo up; ip link set lo multicast on;
                       ip route add 224.0.0.0/4 dev lo;  exec hil ...

The route goes on the namespace's own loopback: the host's routes are never touched, and
two runs at once (two engineers, ``run-all --jobs 2``) cannot hear each other. As root the
namespace is made directly; otherwise in a user namespace (``unshare --user --map-root-user
--net``) where the kernel allows it. Where no namespace can be made, the run stays on the
host if the host has a multicast route (and says so), else the one-line error says what is
missing. Inside user-mode Linux (``HIL_INSIDE_UML``) the kernel is the instance's own, so
the route is added to its loopback directly.

``hil up`` writes its namespace's process id to ``RUN/netns.pid``; ``hil fault --run RUN``
joins that namespace (``nsenter --net``) to reach the running plant.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from hil.errors import BusError

NETNS_ENV = "HIL_LCM_NETNS"  # set inside the namespace hil made (its value: what it did)
PID_FILE = "netns.pid"
_SETUP = ("ip link set lo up && ip link set lo multicast on && "
          "ip route replace 224.0.0.0/4 dev lo")


def needs_namespace(url: str) -> bool:
    """True for a UDP multicast URL when this process is not yet in hil's namespace."""
    return url.startswith("udpm://") and not os.environ.get(NETNS_ENV)


def _unshare_prefix() -> list[str] | None:
    """The ``unshare`` command that makes a network namespace here, or None."""
    unshare = shutil.which("unshare")
    if unshare is None or shutil.which("ip") is None:
        return None
    probes = [[unshare, "--net"]] if os.geteuid() == 0 else []
    probes.append([unshare, "--user", "--map-root-user", "--net"])
    for prefix in probes:
        r = subprocess.run([*prefix, "sh", "-c", _SETUP], capture_output=True, text=True)
        if r.returncode == 0:
            return prefix
    return None


def host_has_multicast_route(url: str) -> bool:
    """True when an LCM on ``url`` opens in this namespace (it checks the route itself)."""
    import lcm

    try:
        lcm.LCM(url)
    except (OSError, RuntimeError, ValueError):
        return False
    return True


def uml_route() -> None:
    """Inside user-mode Linux: the multicast route on the instance's own loopback."""
    subprocess.run(["sh", "-c", _SETUP], check=True, capture_output=True)


def run_in_namespace(argv: list[str], url: str, cwd: str | None = None) -> int | None:
    """Re-run ``python -m hil.cli ARGV`` in a private network namespace, or None to go on
    here (already inside, inside user-mode Linux, or on a host route when no namespace can
    be made). BusError when LCM cannot run at all."""
    if not needs_namespace(url):
        return None
    from hil.uml import in_uml

    if os.environ.get("HIL_INSIDE_UML") or in_uml():
        uml_route()
        os.environ[NETNS_ENV] = "user-mode Linux loopback"
        print("hil: LCM over udpm on user-mode Linux's own loopback (multicast route added "
              "there, not on the host)", flush=True)
        return None
    prefix = _unshare_prefix()
    if prefix is None:
        if host_has_multicast_route(url):
            print("hil: cannot make a private network namespace here; LCM runs on the host's "
                  "multicast route (other LCM programs on this host with the same URL will "
                  "be heard)", flush=True)
            os.environ[NETNS_ENV] = "host"
            return None
        raise BusError(f"bus: lcm {url}: expected a multicast route or a private network "
                       "namespace (unshare, ip), got neither: run as root or allow user "
                       "namespaces")
    how = "user namespace" if "--user" in prefix else "root"
    print(f"hil: running over LCM inside a private network namespace ({how}; multicast "
          "route 224.0.0.0/4 on its own loopback; the host's routes untouched)", flush=True)
    env = dict(os.environ, **{NETNS_ENV: f"private ({how})"})
    cmd = [*prefix, "sh", "-c", f'{_SETUP} && exec "$@"', "sh",
           sys.executable, "-m", "hil.cli", *argv]
    return subprocess.run(cmd, env=env, cwd=cwd).returncode


def write_pid(out: Path) -> None:
    """Inside hil's namespace: where ``hil fault`` finds it (``RUN/netns.pid``)."""
    if os.environ.get(NETNS_ENV, "").startswith("private"):
        (out / PID_FILE).write_text(str(os.getpid()))


def join_run_namespace(run: Path, argv: list[str]) -> int | None:
    """Re-run ``hil ARGV`` inside the namespace of the ``hil up`` in ``run`` (None: go on
    here: no such namespace, or already in it)."""
    pid_file = run / PID_FILE
    if os.environ.get(NETNS_ENV) or not pid_file.exists():
        return None
    pid = pid_file.read_text().strip()
    ns = Path(f"/proc/{pid}/ns/net")
    if not pid.isdigit() or not ns.exists():
        raise BusError(f"fault: {pid_file}: expected the process id of a running `hil up` "
                       f"over LCM, got {pid!r} (not running)")
    if os.path.realpath(ns) == os.path.realpath("/proc/self/ns/net"):
        return None
    nsenter = shutil.which("nsenter")
    if nsenter is None:
        raise BusError("fault: expected nsenter (util-linux) to join the run's network "
                       "namespace, got none on PATH")
    env = dict(os.environ, **{NETNS_ENV: f"joined {pid}"})
    return subprocess.run([nsenter, f"--net={ns}", "--", sys.executable, "-m", "hil.cli",
                           *argv], env=env).returncode


REQUIRE_LCM_ENV = "HIL_REQUIRE_LCM"


def exec_in_namespace(cmd: list[str]) -> int:
    """Run ``cmd`` in a private network namespace with the multicast route (``hil netns
    exec``); ``HIL_REQUIRE_LCM=1`` in its environment (a skipped ``lcm`` test then fails)."""
    if not cmd:
        raise BusError("netns exec: expected a command after --, got none")
    env = dict(os.environ, **{REQUIRE_LCM_ENV: "1"})
    from hil.uml import in_uml

    if not os.environ.get(NETNS_ENV) and in_uml():  # the instance's own kernel and loopback
        uml_route()
        env[NETNS_ENV] = "user-mode Linux loopback"
    if env.get(NETNS_ENV):
        return subprocess.run(cmd, env=env).returncode
    prefix = _unshare_prefix()
    if prefix is None:
        raise BusError("netns exec: expected to make a private network namespace (unshare, "
                       "ip; root or user namespaces), got a refusal")
    how = "user namespace" if "--user" in prefix else "root"
    env[NETNS_ENV] = f"private ({how})"
    print(f"hil: running in a private network namespace ({how}; multicast route on its own "
          "loopback)", file=sys.stderr, flush=True)
    return subprocess.run([*prefix, "sh", "-c", f'{_SETUP} && exec "$@"', "sh", *cmd],
                          env=env).returncode


def _cmd_exec(args) -> int:
    cmd = list(args.cmd)
    if cmd and cmd[0] == "--":
        cmd = cmd[1:]
    return exec_in_namespace(cmd)


def register(sub) -> None:
    import argparse

    p = sub.add_parser("netns", help="run a command in a private network namespace for LCM")
    nsub = p.add_subparsers(dest="netns_command", metavar="ACTION", required=True)
    ex = nsub.add_parser(
        "exec", help="run COMMAND in a private network namespace with a multicast route",
        description="Run COMMAND inside a new network namespace whose loopback carries the "
                    "multicast route LCM's udpm needs (the host's routes are untouched); "
                    "exits with COMMAND's status.")
    ex.add_argument("cmd", nargs=argparse.REMAINDER, metavar="-- COMMAND")
    ex.set_defaults(func=_cmd_exec)
