"""A virtual SocketCAN interface: natively, or in user-mode Linux where the kernel has no CAN.

docs/design.md section 4. ``hil vcan up|down|status`` manage ``vcan0`` on this kernel.
``hil vcan exec -- COMMAND...`` is the transparent path that test scripts and ``hil run`` use:

* ``vcan0`` already present here: run COMMAND natively (bringing the link up first if it is
  down and we may);
* absent, but this kernel has the vcan driver and we hold CAP_NET_ADMIN: create it
  (``modprobe vcan``, ``ip link add``, MTU 72 for CAN FD, up), then run COMMAND natively;
* otherwise run COMMAND inside user-mode Linux (``hil.uml.run_in_uml``), where a fresh
  ``vcan0`` exists. No root is needed for that path.

``--native`` and ``--uml`` force one path. The exit status is COMMAND's. Natively COMMAND
inherits stdin, stdout and stderr; inside UML see ``hil.uml`` (stdin is /dev/null, output live).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from hil.argtypes import number
from hil.errors import BusError, UsageError
from hil.uml import command_argv, in_uml, run_in_uml

ARPHRD_CAN = 280  # include/uapi/linux/if_arp.h
CANFD_MTU = 72
_CHANNEL_RE = re.compile(r"^[A-Za-z0-9_.-]{1,15}$")
_CAP_NET_ADMIN = 12

NO_CAN_HINT = (
    "this kernel has no CAN support (Unknown device type); use `hil vcan exec` or `hil uml`, "
    "which run inside user-mode Linux"
)


class VcanError(BusError):
    """vcan could not be created, removed or used on this kernel."""


def _check_channel(channel: str) -> str:
    if not _CHANNEL_RE.match(channel):
        raise UsageError(f"--channel: expected an interface name (1-15 of A-Z a-z 0-9 _ . -), "
                         f"got {channel!r}")
    return channel


def _sys_net(channel: str) -> Path:
    return Path("/sys/class/net") / channel


def vcan_present(channel: str = "vcan0") -> bool:
    """True if ``channel`` exists on this kernel and is a CAN interface."""
    try:
        return int((_sys_net(_check_channel(channel)) / "type").read_text()) == ARPHRD_CAN
    except (OSError, ValueError):
        return False


def vcan_up(channel: str = "vcan0") -> bool:
    """True if ``channel`` exists and is administratively up (IFF_UP)."""
    try:
        return bool(int((_sys_net(channel) / "flags").read_text(), 16) & 0x1)
    except (OSError, ValueError):
        return False


def vcan_mtu(channel: str = "vcan0") -> int | None:
    try:
        return int((_sys_net(channel) / "mtu").read_text())
    except (OSError, ValueError):
        return None


def native_vcan_supported() -> bool:
    """True if this kernel can have a vcan interface (driver loaded, built in, or on disk).

    Looks only at /sys and /lib/modules: needs no privileges and changes nothing.
    """
    if Path("/sys/module/vcan").exists():
        return True
    try:
        if any(vcan_present(p.name) for p in Path("/sys/class/net").iterdir()
               if _CHANNEL_RE.match(p.name)):
            return True
    except OSError:
        pass
    moddir = Path("/lib/modules") / os.uname().release
    for index in ("modules.dep", "modules.builtin"):
        try:
            text = (moddir / index).read_text(errors="replace")
        except OSError:
            continue
        if re.search(r"(^|/)vcan\.ko", text, re.MULTILINE):
            return True
    return False


def has_net_admin() -> bool:
    """True if this process holds CAP_NET_ADMIN (root normally does)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("CapEff:"):
                return bool(int(line.split()[1], 16) >> _CAP_NET_ADMIN & 1)
    except (OSError, ValueError, IndexError):
        pass
    return os.geteuid() == 0


def _ip(*args: str, where: str) -> None:
    ip = shutil.which("ip") or shutil.which("ip", path="/usr/sbin:/sbin")
    if not ip:
        raise VcanError(f"{where}: the `ip` command (Debian package iproute2) is not installed")
    res = subprocess.run([ip, *args], capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if res.returncode != 0:
        msg = (res.stderr or res.stdout).strip().splitlines()
        msg = msg[-1] if msg else f"exit {res.returncode}"
        if "Unknown device type" in msg or "Address family not supported" in msg:
            raise VcanError(f"{where}: {NO_CAN_HINT}")
        if "Operation not permitted" in msg:
            raise VcanError(f"{where}: `ip {' '.join(args)}` needs root (CAP_NET_ADMIN); "
                            "run as root or with sudo")
        raise VcanError(f"{where}: `ip {' '.join(args)}` failed: {msg}")


def ensure_vcan(channel: str = "vcan0", *, where: str = "hil vcan up") -> None:
    """Make ``channel`` exist on this kernel, up, with MTU 72 (CAN FD). Idempotent.

    Raises ``VcanError`` with one line saying what to do: the kernel has no CAN (use
    ``hil vcan exec`` or ``hil uml``), or creating it needs root.
    """
    _check_channel(channel)
    if vcan_present(channel) and vcan_up(channel):
        return
    if not vcan_present(channel) and not native_vcan_supported():
        hint = NO_CAN_HINT if where != "hil vcan exec" else NO_CAN_HINT.replace(
            "use `hil vcan exec`", "use `hil vcan exec` without --native")
        raise VcanError(f"{where}: {hint}")
    if not has_net_admin():
        verb = "bringing up" if vcan_present(channel) else "creating"
        raise VcanError(f"{where}: {verb} {channel} needs root (CAP_NET_ADMIN); "
                        "run as root or with sudo")
    if not vcan_present(channel):
        modprobe = shutil.which("modprobe") or shutil.which("modprobe", path="/usr/sbin:/sbin")
        if modprobe and not Path("/sys/module/vcan").exists():
            # Failure is not final: the driver may be built in; `ip link add` decides.
            subprocess.run([modprobe, "vcan"], capture_output=True, stdin=subprocess.DEVNULL)
        _ip("link", "add", "dev", channel, "type", "vcan", where=where)
    if vcan_mtu(channel) != CANFD_MTU:
        _ip("link", "set", "dev", channel, "mtu", str(CANFD_MTU), where=where)
    _ip("link", "set", "dev", channel, "up", where=where)


def remove_vcan(channel: str = "vcan0", *, where: str = "hil vcan down") -> bool:
    """Delete ``channel`` if present; return whether it was there."""
    _check_channel(channel)
    if not vcan_present(channel):
        return False
    if not has_net_admin():
        raise VcanError(f"{where}: removing {channel} needs root (CAP_NET_ADMIN); "
                        "run as root or with sudo")
    _ip("link", "del", "dev", channel, where=where)
    return True


def choose_path(channel: str, *, force: str | None = None) -> str:
    """``"native"`` or ``"uml"``: where ``hil vcan exec`` runs its command (see module doc)."""
    if force:
        return force
    if vcan_present(channel):
        return "native" if (vcan_up(channel) or has_net_admin()) else "uml"
    if native_vcan_supported() and has_net_admin():
        return "native"
    return "uml"


def run_native(argv: list[str]) -> int:
    """Run ``argv`` here, inheriting stdio; the exit status as a shell reports it."""
    try:
        proc = subprocess.Popen(argv)
    except FileNotFoundError:
        print(f"hil vcan exec: {argv[0]}: command not found", file=sys.stderr)
        return 127
    except PermissionError:
        print(f"hil vcan exec: {argv[0]}: permission denied", file=sys.stderr)
        return 126
    while True:
        try:
            rc = proc.wait()
            break
        except KeyboardInterrupt:
            continue  # the child got the same SIGINT; wait for it to finish
    return 128 - rc if rc < 0 else rc


def exec_with_vcan(argv: list[str], *, channel: str = "vcan0", force: str | None = None,
                   mem: str = "1G", timeout_s: float | None = None,
                   verbose: bool = False) -> int:
    """Run ``argv`` where ``channel`` is a real vcan interface; return its exit status.

    ``argv`` gets ``HIL_REQUIRE_VCAN=1`` in its environment on both paths: the test suite's
    hook (``tests/conftest.py``) then fails a ``vcan`` test that would skip.
    """
    _check_channel(channel)
    os.environ["HIL_REQUIRE_VCAN"] = "1"
    path = choose_path(channel, force=force)
    if path == "native":
        ensure_vcan(channel, where="hil vcan exec")
        if verbose:
            print(f"hil vcan exec: running natively ({channel} on this kernel)", file=sys.stderr)
        return run_native(argv)
    if in_uml():
        raise VcanError(f"hil vcan exec: already inside user-mode Linux and {channel} is absent")
    if verbose:
        print("hil vcan exec: running inside user-mode Linux", file=sys.stderr)
    return run_in_uml(argv, mem=mem, timeout_s=timeout_s, channels=(channel,))


# --------------------------------------------------------------------------- CLI


def _cmd_up(args: argparse.Namespace) -> int:
    ensure_vcan(args.channel)
    print(f"{args.channel}: up, mtu {vcan_mtu(args.channel)}")
    return 0


def _cmd_down(args: argparse.Namespace) -> int:
    removed = remove_vcan(args.channel)
    print(f"{args.channel}: removed" if removed else f"{args.channel}: absent")
    return 0


def _cmd_status(args: argparse.Namespace) -> int:
    ch = _check_channel(args.channel)
    where = "user-mode Linux" if in_uml() else "native kernel"
    if vcan_present(ch):
        state = "up" if vcan_up(ch) else "down"
        print(f"{ch}: present, {state}, mtu {vcan_mtu(ch)} ({where})")
        return 0 if state == "up" else 1
    if native_vcan_supported():
        print(f"{ch}: absent; this kernel supports vcan (`hil vcan up` creates it)")
    else:
        print(f"{ch}: absent; {NO_CAN_HINT}")
    return 1


def _cmd_exec(args: argparse.Namespace) -> int:
    argv = command_argv(args.command_argv)
    if not argv:
        raise UsageError("hil vcan exec: no command given (usage: hil vcan exec -- COMMAND...)")
    if args.timeout is not None and args.timeout <= 0:
        raise UsageError(f"hil vcan exec: --timeout: expected > 0 seconds, got {args.timeout}")
    force = "uml" if args.uml else "native" if args.native else None
    return exec_with_vcan(argv, channel=args.channel, force=force, mem=args.mem,
                          timeout_s=args.timeout, verbose=args.verbose)


def register(sub) -> None:
    """Add ``hil vcan up|down|status|exec`` to ``sub``."""
    p = sub.add_parser("vcan", help="create, remove or check vcan0; run a command with vcan0",
                       description="Manage a virtual SocketCAN interface on this kernel, or run "
                                   "a command where one exists (natively or in user-mode Linux).")
    vsub = p.add_subparsers(dest="vcan_command", metavar="ACTION", required=True)

    def channel_arg(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--channel", default="vcan0", help="interface name (default vcan0)")

    up = vsub.add_parser("up", help="create vcan0 (up, MTU 72) on this kernel; needs root")
    channel_arg(up)
    up.set_defaults(func=_cmd_up)
    down = vsub.add_parser("down", help="remove vcan0 from this kernel; needs root")
    channel_arg(down)
    down.set_defaults(func=_cmd_down)
    st = vsub.add_parser("status", help="report vcan0 (exit 0 if present and up, else 1)")
    channel_arg(st)
    st.set_defaults(func=_cmd_status)
    ex = vsub.add_parser(
        "exec", help="run a command where vcan0 exists (natively, else in user-mode Linux)",
        description="Run COMMAND where a real vcan interface exists: natively when this kernel "
                    "has it (creating it if needed and allowed), otherwise inside user-mode "
                    "Linux. Exits with COMMAND's exit status.")
    channel_arg(ex)
    force = ex.add_mutually_exclusive_group()
    force.add_argument("--uml", action="store_true", help="always run inside user-mode Linux")
    force.add_argument("--native", action="store_true",
                       help="always run natively (error if vcan cannot exist here)")
    ex.add_argument("--mem", default="1G", help="memory of the UML kernel (default 1G)")
    ex.add_argument("--timeout", type=number(gt=0), default=None, metavar="S",
                    help="stop a user-mode Linux run after S seconds (error, exit 2)")
    ex.add_argument("-v", "--verbose", action="store_true",
                    help="say on stderr which path was taken")
    ex.add_argument("command_argv", nargs=argparse.REMAINDER, metavar="-- COMMAND...")
    ex.set_defaults(func=_cmd_exec)

