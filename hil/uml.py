"""Run a command inside user-mode Linux: a real vcan0 even where the host kernel has no CAN.

(Over 600 lines on purpose: one concern, a boot that must not leave anything behind. The
kernel arguments, the generated init script, the status protocol between the init script and
this process, and the clean-up of UML's process group are one sequence, each step relying on
the previous one's details; split, each part would need the others to be read.)

docs/design.md section 4, "A kernel without CAN". Debian's ``user-mode-linux`` package ships a Linux
kernel that runs as an ordinary process (``linux.uml``) together with the CAN modules. We boot
it with the host's root file system as its root (hostfs), so the command sees the same files,
the same working directory and the same virtual environment as on the host, and we give it a
real SocketCAN ``vcan0``. python-can's ``socketcan`` interface then works unchanged.

How one run goes (``run_in_uml``):

1. A private control folder is made on the host (``hil-uml-XXXX`` under the temp folder). It
   holds the generated init script, UML's pid/umid folder (``uml_dir=``, so nothing lands in
   ``~/.uml`` and two runs never share a umid), and the exit-status file.
2. ``linux.uml`` boots with ``init=<script>``. The script (PID 1) mounts ``/proc``, ``/sys``,
   ``/dev/pts`` and a tmpfs on ``/dev/shm`` (the kernel itself mounts devtmpfs on ``/dev``),
   loads ``can``, ``can-raw``, ``can-dev``, ``vcan`` (and ``can-bcm``, ``can-gw`` when
   present) with ``insmod``, brings up ``lo`` and creates each channel (up, MTU 72 so CAN FD
   frames fit).
3. It runs the command in the host's working directory with a chosen environment (below),
   stdin from ``/dev/null``, stdout on the UML console (``con0``, the host's stdout) and stderr
   on the second UML terminal (``con1``, the host's stderr). Both are terminals inside UML,
   so programs line-buffer and their output reaches the caller live.
4. It writes ``exit <status>`` into the status file on the host and powers off with
   ``poweroff -f``. ``linux.uml`` exits 0 whatever happened inside, so the status file is
   the only trustworthy exit status.

Things a caller should know:

* Kernel noise: the kernel boots with ``quiet loglevel=3``; everything the console prints
  before the command starts and after it ends (unique markers bracket the command) is held
  back, and shown only as the tail of an error when boot, set-up or the command's run fails.
* ``/tmp`` and ``TMPDIR`` are the host's: no tmpfs is mounted over any host folder, because
  the command may need files there (pytest's ``tmp_path``, logs to keep after the run).
  Only ``/dev`` (devtmpfs), ``/dev/shm`` (tmpfs, for POSIX semaphores and shared memory),
  ``/dev/pts``, ``/proc`` and ``/sys`` are UML's own.
* Environment: with ``env=None`` the command gets PATH, HOME, USER, LOGNAME, SHELL, LANG,
  TZ, TMPDIR, VIRTUAL_ENV, PYTHONPATH, CI, TERM, NO_COLOR, FORCE_COLOR, and every variable
  starting with ``HIL_``, ``LC_``, ``PYTHON``, ``PYTEST_``, ``CAN_`` or ``GITHUB_``
  (python-can reads ``CAN_*``), plus ``PWD`` and ``HIL_UML=1``. A given ``env`` mapping is
  passed whole. When the host's stdout is not a terminal, ``TERM=dumb`` so tools do not
  colour a CI log just because the UML console is a terminal.
* Terminal line discipline: the script turns ``onlcr`` off on both terminals, so ``\\n``
  arrives as ``\\n``, not ``\\r\\n``.
* Files the command creates on the host belong to the user who ran ``linux.uml``.
* Standard input is always ``/dev/null`` inside: interactive commands do not work.
* Host files are reached with the host permissions of the user who ran ``hil uml``, even
  though the command is root inside UML.
* Clean-up: ``linux.uml`` runs under a guard shell that kills UML's whole process group when
  the run times out, is interrupted, or the caller dies (even by SIGKILL). The control folder
  is removed afterwards unless ``HIL_UML_KEEP=1``.
* UML does not nest: ``run_in_uml`` refuses to run inside UML.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import secrets
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from hil.argtypes import number
from hil.errors import HilError, UsageError
from hil.uml_fpu import (
    SSE_ONLY_ENV,
    host_needs_legacy_fpu,
    install_xstate_refusal,
    kernel_env_args,
)

UML_MODULES_ROOT = Path("/usr/lib/uml/modules")
INSTALL_HINT = "install the Debian package user-mode-linux (the test script does this)"

# Load order matters: can-raw needs can, vcan needs can-dev (modinfo "depends").
CAN_MODULES_REQUIRED = ("can", "can-raw", "can-dev", "vcan")
CAN_MODULES_OPTIONAL = ("can-bcm", "can-gw")

# Variables passed into UML when the caller gives no ``env`` (exact names, then prefixes).
ENV_NAMES = (
    "PATH", "HOME", "USER", "LOGNAME", "SHELL", "LANG", "TZ", "TMPDIR", "VIRTUAL_ENV",
    "PYTHONPATH", "CI", "TERM", "NO_COLOR", "FORCE_COLOR",
)
ENV_PREFIXES = ("HIL_", "LC_", "PYTHON", "PYTEST_", "CAN_", "GITHUB_")

# Host folders the run hides with UML's own mounts; the control folder must not be under them.
_SHADOWED = ("/proc", "/sys", "/dev")
_MEM_RE = re.compile(r"^[1-9][0-9]*[KMG]?$")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_CHANNEL_RE = re.compile(r"^[A-Za-z0-9_.-]{1,15}$")
_TAIL_LINES = 40


class UmlError(HilError):
    """user-mode Linux is missing, did not boot, failed set-up, or timed out."""


@dataclass(frozen=True)
class UmlKernel:
    """Where the user-mode Linux kernel and its modules are."""

    binary: Path  # linux.uml
    version: str  # e.g. "6.1.176"
    modules_dir: Path  # /usr/lib/uml/modules/<version>


@dataclass(frozen=True)
class UmlStatus:
    """What the init script wrote into the status file.

    ``kind`` is ``"exit"`` (the command ran; ``code`` is its exit status) or
    ``"setup-failed"`` (``detail`` says which step; the command never ran).
    """

    kind: str
    code: int | None = None
    detail: str = ""


# --------------------------------------------------------------------------- pure parts


def parse_status(text: str) -> UmlStatus:
    """Parse the status file: ``exit <N>`` or ``setup-failed <what>``.

    Raises ``ValueError`` on anything else (an empty file means the run was cut short).
    """
    line = text.strip().splitlines()[0].strip() if text.strip() else ""
    word, _, rest = line.partition(" ")
    if word == "exit":
        try:
            code = int(rest.strip())
        except ValueError:
            raise ValueError(f"status file: expected 'exit <integer>', got {line!r}") from None
        if not 0 <= code <= 255:
            raise ValueError(f"status file: expected an exit status in 0..255, got {code}")
        return UmlStatus("exit", code)
    if word == "setup-failed":
        return UmlStatus("setup-failed", None, rest.strip())
    raise ValueError(f"status file: expected 'exit <N>' or 'setup-failed <what>', got {line!r}")


def select_env(environ: Mapping[str, str]) -> dict[str, str]:
    """The variables of ``environ`` that the command inside UML gets (see the module doc)."""
    return {
        k: v
        for k, v in environ.items()
        if (k in ENV_NAMES or k.startswith(ENV_PREFIXES)) and _NAME_RE.match(k)
    }


def module_paths(modules_dir: Path) -> dict[str, Path]:
    """Map module name (``can-raw``) to its ``.ko`` file under ``modules_dir/kernel``.

    Names are as modinfo prints them: ``_`` and ``-`` are the same, so both spellings map.
    Compressed modules (``.ko.xz``, ``.ko.zst``, ``.ko.gz``) are found too.
    """
    found: dict[str, Path] = {}
    for path in sorted((modules_dir / "kernel").rglob("*.ko*")):
        name = path.name.split(".ko")[0]
        for key in (name, name.replace("_", "-"), name.replace("-", "_")):
            found.setdefault(key, path)
    return found


def build_kernel_args(
    *, init_path: str, mem: str, umid: str, uml_dir: str
) -> list[str]:
    """Arguments of ``linux.uml``: host root via hostfs, our init, quiet console on fd 1 and 2."""
    if not _MEM_RE.match(mem):
        raise UsageError(f"--mem: expected a size such as 512M or 1G, got {mem!r}")
    for what, value in (("init script path", init_path), ("uml_dir", uml_dir), ("umid", umid)):
        if not value or any(c.isspace() for c in value):
            raise UmlError(f"{what}: expected a path without blanks, got {value!r}")
    return [
        f"mem={mem}",
        "root=/dev/root",
        "rootfstype=hostfs",
        "rootflags=/",
        "rw",
        f"init={init_path}",
        # con0 is the kernel console and the command's stdout (host fd 1); con1 (/dev/tty1)
        # carries the command's stderr to host fd 2. Input is null on both: the run must not
        # depend on (or hang up on) the host's stdin, which CI closes.
        "con=null",
        "con0=null,fd:1",
        "con1=null,fd:2",
        f"umid={umid}",
        f"uml_dir={uml_dir}",
        "quiet",
        "loglevel=3",
    ]


def build_init_script(
    *,
    argv: Sequence[str],
    cwd: str,
    env: Mapping[str, str],
    status_path: str,
    modules: Sequence[tuple[str, str, bool]],
    channels: Sequence[str] = ("vcan0",),
    start_marker: str,
    end_marker: str,
    busybox: str = "/usr/bin/busybox",
    ip: str | None = None,
    env_tool: str = "/usr/bin/env",
) -> str:
    """Text of the init script (PID 1 inside UML).

    ``modules`` is ``(name, path, required)`` in load order. A required module that fails to
    load, or any other set-up failure, writes ``setup-failed <what>`` and powers off; the
    command runs only when the whole set-up succeeded. ``ip`` is iproute2's ``ip`` (busybox's
    cannot create a vcan link); ``None`` uses busybox's as a last resort. ``env_tool`` starts
    the command with exactly ``env``: the host's ``env``, not busybox's, which would run its
    own applets (``ip``, ``sh``...) instead of the host programs found on PATH.
    """
    if not argv:
        raise UsageError("no command given")
    q = shlex.quote
    bb = q(busybox)
    ipc = q(ip) if ip else f"{bb} ip"
    status = q(status_path)
    dmesg = q(str(Path(status_path).with_name("dmesg")))
    lines = [
        "#!" + busybox + " sh",
        "# Generated by hil.uml: PID 1 of one user-mode Linux run. Set up, run, report, power off.",
        f"BB={bb}",
        "fail() {",
        f'  echo "setup-failed $*" > {status}',
        f"  $BB dmesg > {dmesg} 2>&1",
        "  $BB sync",
        "  $BB poweroff -f",
        "  exit 1",
        "}",
        "$BB mount -t proc proc /proc || fail 'mount /proc'",
        "$BB mount -t sysfs sysfs /sys || fail 'mount /sys'",
        # The kernel mounts devtmpfs on /dev itself (DEVTMPFS_MOUNT); mount it if not.
        "$BB grep -q ' /dev ' /proc/mounts || $BB mount -t devtmpfs devtmpfs /dev"
        " || fail 'mount /dev'",
        "$BB mkdir -p /dev/pts /dev/shm",
        "$BB mount -t devpts -o mode=620,ptmxmode=666 devpts /dev/pts || fail 'mount /dev/pts'",
        "$BB mount -t tmpfs -o mode=1777 tmpfs /dev/shm || fail 'mount /dev/shm'",
    ]
    for name, path, required in modules:
        if required:
            lines.append(f"$BB insmod {q(path)} || fail {q('insmod ' + name)}")
        else:
            lines.append(f"$BB insmod {q(path)} 2>/dev/null || true")
    lines.append(f"{ipc} link set dev lo up || fail 'ip link set lo up'")
    for ch in channels:
        if not _CHANNEL_RE.match(ch):
            raise UsageError(f"--channel: expected an interface name, got {ch!r}")
        lines += [
            f"{ipc} link add dev {ch} type vcan || fail {q('ip link add ' + ch)}",
            f"{ipc} link set dev {ch} mtu 72 || fail {q('ip link set ' + ch + ' mtu 72')}",
            f"{ipc} link set dev {ch} up || fail {q('ip link set ' + ch + ' up')}",
        ]
    envs = " ".join(q(f"{k}={v}") for k, v in env.items())
    lines += [
        f"cd {q(cwd)} || fail {q('cd ' + cwd)}",
        "$BB stty -onlcr < /dev/console",
        "$BB stty -onlcr < /dev/tty1",
        f"echo {q(start_marker)} > /dev/console",
        f"{q(env_tool)} -i {envs} {shlex.join(argv)} < /dev/null > /dev/console 2> /dev/tty1",
        f'echo "exit $?" > {status}',
        f"echo {q(end_marker)} > /dev/console",
        "$BB sync",
        "$BB poweroff -f",
        "",
    ]
    return "\n".join(lines)


class MarkerFilter:
    """Pass through the console bytes between two marker lines; keep the rest as a log tail.

    Fed chunk by chunk (a marker may be split between chunks). Output between the markers is
    returned at once, except for the shortest trailing piece that could begin the end marker.
    """

    def __init__(self, start_marker: str, end_marker: str, tail_lines: int = _TAIL_LINES):
        self._start = start_marker.encode() + b"\n"
        self._end = end_marker.encode() + b"\n"
        self._state = "before"  # before -> during -> after
        self._pending = b""
        self._held = b""  # console bytes not shown (boot and shutdown), for error messages
        self._tail_lines = tail_lines
        self.started = False

    def feed(self, chunk: bytes) -> bytes:
        """Bytes of ``chunk`` to show now."""
        data = self._pending + chunk
        self._pending = b""
        out = b""
        if self._state == "before":
            i = data.find(self._start)
            if i < 0:
                keep = _partial_suffix(data, self._start)
                self._hold(data[: len(data) - keep])
                self._pending = data[len(data) - keep:]
                return b""
            self._hold(data[:i])
            data = data[i + len(self._start):]
            self._state = "during"
            self.started = True
        if self._state == "during":
            i = data.find(self._end)
            if i < 0:
                keep = _partial_suffix(data, self._end)
                self._pending = data[len(data) - keep:]
                return out + data[: len(data) - keep]
            out += data[:i]
            data = data[i + len(self._end):]
            self._state = "after"
        self._hold(data)
        return out

    def flush(self) -> bytes:
        """At end of stream: what is still held back (shown only while the command ran)."""
        data, self._pending = self._pending, b""
        if self._state == "during":
            return data
        self._hold(data)
        return b""

    def _hold(self, data: bytes) -> None:
        if data:
            self._held = b"\n".join((self._held + data).split(b"\n")[-self._tail_lines - 1:])

    def tail(self) -> str:
        """Last lines of the console that were not shown."""
        text = self._held.decode("utf-8", "replace").replace("\r", "")
        return "\n".join(ln for ln in text.splitlines() if ln.strip())


def _partial_suffix(data: bytes, marker: bytes) -> int:
    """Length of the longest suffix of ``data`` that is a proper prefix of ``marker``."""
    for n in range(min(len(marker) - 1, len(data)), 0, -1):
        if data.endswith(marker[:n]):
            return n
    return 0


# --------------------------------------------------------------------------- host side


def find_uml_kernel() -> UmlKernel:
    """Locate ``linux.uml`` and its module folder (any version)."""
    binary = shutil.which("linux.uml") or shutil.which("linux.uml", path="/usr/bin:/usr/local/bin")
    versions = sorted(
        (p for p in UML_MODULES_ROOT.glob("*") if (p / "kernel").is_dir()),
        key=lambda p: [int(x) if x.isdigit() else x for x in re.split(r"[.-]", p.name)],
    )
    if not binary or not versions:
        missing = "linux.uml" if not binary else f"{UML_MODULES_ROOT}/<version>/kernel"
        raise UmlError(f"hil uml: {missing} not found; {INSTALL_HINT}")
    newest = versions[-1]
    return UmlKernel(Path(binary), newest.name, newest)


def in_uml() -> bool:
    """True when this process runs inside user-mode Linux."""
    if os.environ.get("HIL_UML") == "1":
        return True
    try:
        return "User Mode Linux" in Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return False


def _module_plan(kernel: UmlKernel) -> list[tuple[str, str, bool]]:
    paths = module_paths(kernel.modules_dir)
    plan = []
    for name in CAN_MODULES_REQUIRED:
        if name not in paths:
            raise UmlError(
                f"hil uml: module {name} not found under {kernel.modules_dir}/kernel; "
                f"{INSTALL_HINT}"
            )
        plan.append((name, str(paths[name]), True))
    plan += [(n, str(paths[n]), False) for n in CAN_MODULES_OPTIONAL if n in paths]
    return plan


def _control_parent() -> str:
    """A host folder for the control folder: visible inside UML, no blanks in its path."""
    for cand in (tempfile.gettempdir(), "/tmp", "/var/tmp"):
        real = os.path.realpath(cand)
        shadowed = any(real == s or real.startswith(s + "/") for s in _SHADOWED)
        if os.path.isdir(real) and os.access(real, os.W_OK) and not shadowed \
                and not any(c.isspace() for c in real):
            return real
    raise UmlError("hil uml: no writable temp folder outside /proc, /sys and /dev")


def _pump(src: BinaryIO, dst: BinaryIO | None, filt: MarkerFilter | None,
          tail: collections.deque[str]) -> None:
    """Copy ``src`` to ``dst`` live, through ``filt`` when given; remember a tail of it."""
    while True:
        chunk = src.read1(65536) if hasattr(src, "read1") else src.read(65536)
        if not chunk:
            break
        out = filt.feed(chunk) if filt else chunk
        if not filt:
            tail.extend(chunk.decode("utf-8", "replace").splitlines()[-_TAIL_LINES:])
        if out and dst is not None:
            try:
                dst.write(out)
                dst.flush()
            except (OSError, ValueError):
                dst = None  # the reader went away; keep draining so UML never blocks
    if filt:
        rest = filt.flush()
        if rest and dst is not None:
            try:
                dst.write(rest)
                dst.flush()
            except (OSError, ValueError):
                pass


def _binary_stream(stream) -> BinaryIO | None:
    return getattr(stream, "buffer", None) or (stream if stream is not None else None)


# linux.uml makes itself a session leader (setsid), so it and the helper processes it forks
# form their own process group. A small guard shell starts it and, on SIGTERM, kills that
# whole group; after a normal end it sweeps any helper left behind. If we die without
# cleaning up (SIGKILL, OOM killer) the kernel sends the guard SIGTERM (PR_SET_PDEATHSIG), so
# no UML process is left sleeping forever while holding its memory. Its first argument is the
# control folder to remove on that path (empty: keep it), since our own clean-up cannot run.
# The guard's wait discards the shell's own job report ("Aborted" when linux.uml dies by
# SIGABRT while powering off, seen under load after the status was written): it is not the
# command's output, and the status file says how the command ended (UmlError without one).
_GUARD = """ctl=$1; shift; p=
trap 'if [ -n "$p" ]; then kill -s KILL -- -"$p" "$p" 2>/dev/null; fi
[ -n "$ctl" ] && rm -rf -- "$ctl"; exit 143' TERM
"$@" & p=$!
wait "$p" 2>/dev/null; rc=$?
kill -s KILL -- -"$p" 2>/dev/null
exit "$rc"
"""


def _die_with_parent() -> None:
    """In the guard before exec: get SIGTERM when the parent (this process) dies."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _guard_preexec_legacy_fpu() -> None:
    """``_die_with_parent``, then the XSTATE refusal of ``hil.uml_fpu`` for UML's tree."""
    _die_with_parent()
    install_xstate_refusal()


def _kill_group(proc: subprocess.Popen) -> None:
    """Stop the guard, which stops linux.uml and every host process it made."""
    if proc.poll() is not None:
        return  # the guard has ended, after sweeping UML's process group
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=5)
    except ProcessLookupError:
        pass
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def run_in_uml(
    argv: Sequence[str],
    *,
    mem: str = "1G",
    timeout_s: float | None = None,
    env: Mapping[str, str] | None = None,
    cwd: str | os.PathLike[str] | None = None,
    channels: Sequence[str] = ("vcan0",),
    stdout: BinaryIO | None = None,
    stderr: BinaryIO | None = None,
    on_interrupt: Callable[[str], None] | None = None,
    interrupt_grace_s: float = 30.0,
) -> int:
    """Run ``argv`` inside user-mode Linux with a real ``vcan0``; return its exit status.

    ``cwd`` defaults to the current folder (the same path inside, through hostfs). ``env=None``
    passes the variables listed in the module doc; a mapping is passed whole. ``stdout`` and
    ``stderr`` (binary streams) default to this process's. Raises ``UmlError`` when UML is
    not installed, the kernel did not boot, set-up failed or ``timeout_s`` ran out (the
    message ends with the tail of the console), ``UsageError`` on a bad argument.

    ``on_interrupt``: on a ``KeyboardInterrupt`` (Ctrl-C, or a signal the caller turns into
    one) it is called with the interruption's text and UML gets ``interrupt_grace_s`` to end
    by itself (the command inside was asked to stop some other way, e.g. through a file);
    its exit status is then returned as usual. A second interruption, or the grace running
    out, stops UML at once and re-raises. Without it UML is stopped at once.
    """
    argv = [str(a) for a in argv]
    if not argv:
        raise UsageError("hil uml: no command given (usage: hil uml -- COMMAND...)")
    if in_uml():
        # Checked: a UML kernel booted inside UML hangs instead of failing.
        raise UmlError("hil uml: already inside user-mode Linux, which does not nest; "
                       "run the command directly")
    kernel = find_uml_kernel()
    modules = _module_plan(kernel)
    busybox = shutil.which("busybox") or "/usr/bin/busybox"
    if not os.path.exists(busybox):
        raise UmlError("hil uml: busybox not found; install the Debian package busybox-static")
    sys_path = os.pathsep.join(
        [os.environ.get("PATH", ""), "/usr/sbin", "/sbin", "/usr/bin", "/bin"])
    ip = shutil.which("ip", path=sys_path)
    env_tool = shutil.which("env", path=sys_path)
    if not env_tool:
        raise UmlError("hil uml: env (coreutils) not found on this host")
    cwd = os.path.abspath(cwd if cwd is not None else os.getcwd())
    if env is None:
        env = select_env(os.environ)
        if not _isatty(stdout if stdout is not None else sys.stdout):
            env["TERM"] = "dumb"
    env = {k: str(v) for k, v in env.items() if _NAME_RE.match(k)}
    legacy_fpu = host_needs_legacy_fpu()
    if legacy_fpu:  # an AMX host: UML on the legacy FPU regset, SSE code paths inside
        env = {**env, **SSE_ONLY_ENV}
    env.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin:/usr/sbin:/sbin")
    env["PWD"] = cwd
    env["HIL_UML"] = "1"

    token = secrets.token_hex(8)
    ctl = tempfile.mkdtemp(prefix="hil-uml-", dir=_control_parent())
    try:
        os.chmod(ctl, 0o755)
        init_path = os.path.join(ctl, "init")
        status_path = os.path.join(ctl, "status")
        uml_dir = os.path.join(ctl, "uml")
        os.mkdir(uml_dir)
        script = build_init_script(
            argv=argv, cwd=cwd, env=env, status_path=status_path, modules=modules,
            channels=channels, start_marker=f"@@hil-uml-{token}-start@@",
            end_marker=f"@@hil-uml-{token}-end@@", busybox=busybox, ip=ip,
            env_tool=env_tool,
        )
        Path(init_path).write_text(script)
        os.chmod(init_path, 0o755)
        keep = os.environ.get("HIL_UML_KEEP") == "1"
        args = ["/bin/sh", "-c", _GUARD, "hil-uml-guard", "" if keep else ctl,
                str(kernel.binary)] + build_kernel_args(
            init_path=init_path, mem=mem, umid=f"hil-{os.getpid()}-{token}", uml_dir=uml_dir)
        if legacy_fpu:
            args += kernel_env_args()
        filt = MarkerFilter(f"@@hil-uml-{token}-start@@", f"@@hil-uml-{token}-end@@")
        err_tail: collections.deque[str] = collections.deque(maxlen=_TAIL_LINES)
        # Own session: a terminal's Ctrl-C reaches only us, and we stop UML through the guard.
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()  # what the caller printed comes before the command's output
        proc = subprocess.Popen(
            args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            start_new_session=True, cwd=ctl,
            preexec_fn=_guard_preexec_legacy_fpu if legacy_fpu else _die_with_parent,
        )
        pumps = [
            threading.Thread(target=_pump, daemon=True, args=(
                proc.stdout, stdout if stdout is not None else _binary_stream(sys.stdout),
                filt, collections.deque())),
            threading.Thread(target=_pump, daemon=True, args=(
                proc.stderr, stderr if stderr is not None else _binary_stream(sys.stderr),
                None, err_tail)),
        ]
        for t in pumps:
            t.start()
        t0 = time.monotonic()
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            for t in pumps:
                t.join(timeout=2)
            raise UmlError(
                f"hil uml: timed out after {timeout_s:g} s "
                f"({'the command was still running' if filt.started else 'during boot'})"
                + _tail_text(filt, err_tail)
            ) from None
        except KeyboardInterrupt as exc:
            if on_interrupt is None:
                _kill_group(proc)
                raise
            try:
                on_interrupt(str(exc) or "interrupted (SIGINT)")
                proc.wait(timeout=interrupt_grace_s)
            except subprocess.TimeoutExpired:
                _kill_group(proc)
                raise exc from None
            except BaseException:
                _kill_group(proc)
                raise
        except BaseException:
            _kill_group(proc)
            raise
        for t in pumps:
            t.join(timeout=5)
        elapsed = time.monotonic() - t0
        try:
            status = parse_status(Path(status_path).read_text())
        except (OSError, ValueError) as exc:
            where = "the command was running" if filt.started else "before the command started"
            raise UmlError(
                f"hil uml: user-mode Linux stopped {where} without an exit status "
                f"(linux.uml exit {proc.returncode}, {elapsed:.1f} s; {exc})"
                + _tail_text(filt, err_tail)
            ) from None
        if status.kind == "setup-failed":
            dmesg = _read_tail(os.path.join(ctl, "dmesg"))
            raise UmlError(
                f"hil uml: set-up inside user-mode Linux failed: {status.detail}"
                + _tail_text(filt, err_tail) + (f"\nkernel log (tail):\n{dmesg}" if dmesg else "")
            )
        return int(status.code)
    finally:
        if os.environ.get("HIL_UML_KEEP") != "1":
            shutil.rmtree(ctl, ignore_errors=True)


def _isatty(stream) -> bool:
    try:
        return bool(stream is not None and stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def _read_tail(path: str, n: int = 15) -> str:
    try:
        return "\n".join(Path(path).read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


def _tail_text(filt: MarkerFilter, err_tail: collections.deque[str]) -> str:
    parts = []
    console = filt.tail()
    if console:
        parts.append("console (tail):\n" + console)
    if err_tail:
        parts.append("stderr (tail):\n" + "\n".join(list(err_tail)[-15:]))
    return ("\n" + "\n".join(parts)) if parts else ""


# --------------------------------------------------------------------------- CLI


def command_argv(rest: Sequence[str]) -> list[str]:
    """The command after ``--`` (argparse.REMAINDER keeps the ``--``)."""
    rest = list(rest)
    if rest and rest[0] == "--":
        rest = rest[1:]
    return rest


def _cmd_uml(args: argparse.Namespace) -> int:
    argv = command_argv(args.command_argv)
    if not argv:
        raise UsageError("hil uml: no command given (usage: hil uml [options] -- COMMAND...)")
    if args.timeout is not None and args.timeout <= 0:
        raise UsageError(f"hil uml: --timeout: expected > 0 seconds, got {args.timeout}")
    return run_in_uml(argv, mem=args.mem, timeout_s=args.timeout,
                      channels=args.channel or ("vcan0",))


def register(sub) -> None:
    """Add ``hil uml`` to ``sub``."""
    p = sub.add_parser(
        "uml",
        help="run a command inside user-mode Linux, with a real vcan0",
        description=(
            "Boot user-mode Linux (Debian package user-mode-linux) with the host's files as "
            "its root, create vcan0 (up, MTU 72), and run COMMAND in the current folder with "
            "the current environment. Exits with COMMAND's exit status. COMMAND's stdout and "
            "stderr arrive live; its stdin is /dev/null."
        ),
    )
    p.add_argument("--mem", default="1G", help="memory of the UML kernel (default 1G)")
    p.add_argument("--timeout", type=number(gt=0), default=None, metavar="S",
                   help="stop the run after S seconds (error, exit 2)")
    p.add_argument("--channel", action="append", metavar="NAME",
                   help="vcan interface to create (repeatable; default vcan0)")
    p.add_argument("command_argv", nargs=argparse.REMAINDER, metavar="-- COMMAND...")
    p.set_defaults(func=_cmd_uml)
