"""Pure parts of hil.uml and hil.vcan: no kernel is booted, no interface is touched."""

from __future__ import annotations

import ast
import io
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil import cli, uml, vcan
from hil.errors import UsageError

START, END = "@@hil-uml-feed-start@@", "@@hil-uml-feed-end@@"
MODULES = [
    ("can", "/m/net/can/can.ko", True),
    ("can-raw", "/m/net/can/can-raw.ko", True),
    ("can-dev", "/m/drivers/net/can/dev/can-dev.ko", True),
    ("vcan", "/m/drivers/net/can/vcan.ko", True),
    ("can-bcm", "/m/net/can/can-bcm.ko", False),
]


def script(argv=("true",), env=None, cwd="/srv/project", **kw) -> str:
    return uml.build_init_script(
        argv=list(argv), cwd=cwd, env=env if env is not None else {"PATH": "/usr/bin"},
        status_path="/tmp/hil-uml-abc/status", modules=kw.pop("modules", MODULES),
        start_marker=START, end_marker=END, busybox="/usr/bin/busybox", ip="/usr/sbin/ip",
        env_tool="/usr/bin/env", **kw)


def command_line(text: str) -> str:
    """The command's line (quoted arguments may span lines: a newline is a valid argument)."""
    start = text.index("\n/usr/bin/env -i ") + 1
    tail = "< /dev/null > /dev/console 2> /dev/tty1"
    return text[start:text.index(tail, start) + len(tail)]


# --------------------------------------------------------------------------- init script


def test_init_script_loads_modules_in_dependency_order_before_creating_vcan():
    lines = script().splitlines()
    insmods = [i for i, ln in enumerate(lines) if "insmod" in ln]
    loaded = [Path(shlex.split(lines[i])[2]).name for i in insmods]
    assert loaded == ["can.ko", "can-raw.ko", "can-dev.ko", "vcan.ko", "can-bcm.ko"]
    add = next(i for i, ln in enumerate(lines) if "link add dev vcan0 type vcan" in ln)
    mtu = next(i for i, ln in enumerate(lines) if "link set dev vcan0 mtu 72" in ln)
    up = next(i for i, ln in enumerate(lines) if "link set dev vcan0 up" in ln)
    run = next(i for i, ln in enumerate(lines) if ln.startswith("/usr/bin/env -i"))
    assert max(insmods) < add < mtu < up < run


def test_required_modules_fail_the_setup_optional_ones_do_not():
    lines = script().splitlines()
    assert "fail 'insmod vcan'" in next(ln for ln in lines if "vcan.ko" in ln)
    bcm = next(ln for ln in lines if "can-bcm.ko" in ln)
    assert "fail" not in bcm and bcm.endswith("|| true")


def test_init_script_mounts_proc_sys_and_shm_but_nothing_over_tmp():
    text = script()
    for mount in ("proc proc /proc", "sysfs sysfs /sys", "tmpfs /dev/shm", "devpts /dev/pts"):
        assert mount in text
    assert " /tmp" not in text.replace("/tmp/hil-uml-abc/", "")
    assert "link set dev lo up" in text


def test_init_script_reports_status_then_powers_off():
    lines = script().splitlines()
    run = next(i for i, ln in enumerate(lines) if ln.startswith("/usr/bin/env -i"))
    assert lines[run + 1] == "echo \"exit $?\" > /tmp/hil-uml-abc/status"
    assert lines[-1] == "$BB poweroff -f"
    assert lines[0] == "#!/usr/bin/busybox sh"


def test_command_runs_in_cwd_with_stdin_null_stdout_console_stderr_tty1():
    text = script(cwd="/a dir/with 'quote'")
    assert "cd '/a dir/with '\"'\"'quote'\"'\"'' || fail" in text
    line = command_line(text)
    assert line.endswith("< /dev/null > /dev/console 2> /dev/tty1")


def test_extra_channels_are_created():
    text = script(channels=("vcan0", "vcan1"))
    assert "link add dev vcan1 type vcan" in text


def test_bad_channel_name_is_a_usage_error():
    with pytest.raises(UsageError, match="--channel"):
        script(channels=("vcan0; reboot",))


ARG_TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
                   max_size=20)


@settings(max_examples=200, deadline=None)
@given(argv=st.lists(ARG_TEXT, min_size=1, max_size=5), value=ARG_TEXT)
def test_command_and_env_quoting_round_trips(argv, value):
    words = shlex.split(command_line(script(argv=argv, env={"PATH": "/bin", "HIL_V": value})))
    assert words[:4] == ["/usr/bin/env", "-i", "PATH=/bin", f"HIL_V={value}"]
    assert words[4:-6] == argv
    assert words[-6:] == ["<", "/dev/null", ">", "/dev/console", "2>", "/dev/tty1"]


SHELLS = [s for s in ("/bin/sh", shutil.which("busybox")) if s and Path(s).exists()]


@pytest.mark.parametrize("shell", SHELLS)
def test_quoting_survives_a_real_shell(shell):
    """The generated command line, run by a real shell, gives the program exactly argv."""
    argv = [sys.executable, "-c", "import os,sys; print(repr((sys.argv[1:], os.environ['HIL_Q'])))",
            "a b", "it's", '"dq"', "$HOME", "`id`", "back\\slash", "new\nline", "", "*"]
    env = {"PATH": "/usr/bin:/bin", "HIL_Q": "x y 'z' \"w\" $PATH"}
    line = command_line(script(argv=argv, env=env))
    line = line.replace("< /dev/null > /dev/console 2> /dev/tty1", "< /dev/null")
    cmd = [shell, "sh", "-c", line] if shell.endswith("busybox") else [shell, "-c", line]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    assert ast.literal_eval(out.strip()) == (argv[3:], env["HIL_Q"])


def test_empty_command_is_a_usage_error():
    with pytest.raises(UsageError):
        script(argv=())


# --------------------------------------------------------------------------- kernel args


def test_kernel_args_boot_hostfs_root_with_our_init_and_quiet_console():
    args = uml.build_kernel_args(init_path="/tmp/c/init", mem="512M", umid="hil-1-ab",
                                 uml_dir="/tmp/c/uml")
    for want in ("mem=512M", "root=/dev/root", "rootfstype=hostfs", "rootflags=/", "rw",
                 "init=/tmp/c/init", "con=null", "con0=null,fd:1", "con1=null,fd:2",
                 "umid=hil-1-ab", "uml_dir=/tmp/c/uml", "quiet"):
        assert want in args
    assert args.index("con=null") < args.index("con0=null,fd:1")


@pytest.mark.parametrize("mem", ["", "1T", "-1G", "1.5G", "G", "0"])
def test_bad_mem_is_a_usage_error(mem):
    with pytest.raises(UsageError, match="--mem: expected a size such as 512M or 1G"):
        uml.build_kernel_args(init_path="/i", mem=mem, umid="u", uml_dir="/d")


def test_path_with_blank_cannot_go_on_the_kernel_command_line():
    with pytest.raises(uml.UmlError, match="without blanks"):
        uml.build_kernel_args(init_path="/a b/init", mem="1G", umid="u", uml_dir="/d")


# --------------------------------------------------------------------------- status file


@pytest.mark.parametrize(("text", "want"), [
    ("exit 0\n", uml.UmlStatus("exit", 0)),
    ("exit 7", uml.UmlStatus("exit", 7)),
    ("  exit 255  \n\n", uml.UmlStatus("exit", 255)),
    ("setup-failed insmod vcan\n", uml.UmlStatus("setup-failed", None, "insmod vcan")),
])
def test_parse_status(text, want):
    assert uml.parse_status(text) == want


@pytest.mark.parametrize("text", ["", "\n", "exit", "exit x", "exit 256", "exit -1", "done 0"])
def test_parse_status_rejects_junk(text):
    with pytest.raises(ValueError, match="status file"):
        uml.parse_status(text)


# --------------------------------------------------------------------------- console filter


def test_marker_filter_shows_only_the_command_output():
    f = uml.MarkerFilter(START, END)
    out = f.feed(b"SELinux: noise\r\nmore noise\n" + START.encode() + b"\nhello\nworld")
    out += f.feed(b"\n" + END.encode() + b"\nreboot: System halted\n")
    out += f.flush()
    assert out == b"hello\nworld\n"
    assert f.started
    assert f.tail() == "SELinux: noise\nmore noise\nreboot: System halted"


def test_marker_filter_passes_partial_lines_at_once():
    f = uml.MarkerFilter(START, END)
    f.feed(START.encode() + b"\n")
    assert f.feed(b"....") == b"...."  # progress dots without a newline are shown live
    assert f.feed(b"@@hil") == b""  # could be the end marker: held back
    assert f.feed(b"-not-a-marker\n") == b"@@hil-not-a-marker\n"


def test_marker_filter_without_end_marker_flushes_what_the_command_wrote():
    f = uml.MarkerFilter(START, END)
    out = f.feed(START.encode() + b"\nabc\n@@")
    assert out + f.flush() == b"abc\n@@"


def test_marker_filter_never_started_keeps_everything_for_the_error():
    f = uml.MarkerFilter(START, END, tail_lines=3)
    f.feed(b"".join(b"line %d\n" % i for i in range(10)))
    f.flush()
    assert not f.started
    assert f.tail() == "line 7\nline 8\nline 9"


@settings(max_examples=200, deadline=None)
@given(payload=st.binary(max_size=200), cuts=st.lists(st.integers(0, 400), max_size=8))
def test_marker_filter_is_independent_of_chunking(payload, cuts):
    stream = b"boot\n" + START.encode() + b"\n" + payload + END.encode() + b"\nbye\n"
    f = uml.MarkerFilter(START, END)
    out, last = b"", 0
    for c in sorted(min(c, len(stream)) for c in cuts) + [len(stream)]:
        out += f.feed(stream[last:c])
        last = c
    out += f.flush()
    # The first complete end marker ends the output.
    assert out == (payload + END.encode() + b"\n").split(END.encode() + b"\n")[0]


# --------------------------------------------------------------------------- locating UML


def fake_modules(root: Path, version: str, names: list[str], suffix: str = ".ko") -> Path:
    d = root / version / "kernel" / "net" / "can"
    d.mkdir(parents=True)
    for n in names:
        (d / f"{n}{suffix}").write_bytes(b"")
    return root / version


def test_module_paths_finds_compressed_modules_and_both_spellings(tmp_path):
    mdir = fake_modules(tmp_path, "6.1.1", ["can", "can-raw", "can_dev"], suffix=".ko.xz")
    paths = uml.module_paths(mdir)
    assert paths["can-raw"].name == "can-raw.ko.xz"
    assert paths["can-dev"] == paths["can_dev"]


def test_module_plan_needs_every_can_module(tmp_path):
    mdir = fake_modules(tmp_path, "6.1.1", ["can", "can-raw", "can-dev"])
    kernel = uml.UmlKernel(Path("/usr/bin/linux.uml"), "6.1.1", mdir)
    with pytest.raises(uml.UmlError, match="module vcan not found.*user-mode-linux"):
        uml._module_plan(kernel)


def test_module_plan_order_and_optional_modules(tmp_path):
    mdir = fake_modules(tmp_path, "6.1.1", ["vcan", "can-gw", "can-dev", "can-raw", "can"])
    plan = uml._module_plan(uml.UmlKernel(Path("/x"), "6.1.1", mdir))
    assert [(n, req) for n, _, req in plan] == [
        ("can", True), ("can-raw", True), ("can-dev", True), ("vcan", True), ("can-gw", False)]


def test_missing_user_mode_linux_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setattr(uml, "UML_MODULES_ROOT", tmp_path)
    monkeypatch.setattr(uml.shutil, "which", lambda *a, **k: None)
    with pytest.raises(uml.UmlError) as err:
        uml.find_uml_kernel()
    assert str(err.value) == (
        "hil uml: linux.uml not found; install the Debian package user-mode-linux "
        "(the test script does this)")


def test_find_uml_kernel_takes_the_newest_module_version(tmp_path, monkeypatch):
    for v in ("6.1.9", "6.1.10", "5.10.2"):
        fake_modules(tmp_path, v, ["can"])
    monkeypatch.setattr(uml, "UML_MODULES_ROOT", tmp_path)
    monkeypatch.setattr(uml.shutil, "which", lambda *a, **k: "/usr/bin/linux.uml")
    assert uml.find_uml_kernel().version == "6.1.10"


# --------------------------------------------------------------------------- environment


def test_select_env_keeps_what_matters_and_drops_the_rest():
    environ = {"PATH": "/p", "HOME": "/h", "VIRTUAL_ENV": "/v", "PYTHONPATH": "/pp", "CI": "1",
               "TERM": "xterm", "HIL_LOG": "x", "LC_ALL": "C", "CAN_INTERFACE": "socketcan",
               "SECRET_TOKEN": "s", "SSH_AUTH_SOCK": "/s", "BASH_FUNC_f%%": "() { :; }"}
    got = uml.select_env(environ)
    assert set(got) == {"PATH", "HOME", "VIRTUAL_ENV", "PYTHONPATH", "CI", "TERM", "HIL_LOG",
                        "LC_ALL", "CAN_INTERFACE"}


def test_command_argv_strips_the_separator():
    assert uml.command_argv(["--", "a", "--", "b"]) == ["a", "--", "b"]
    assert uml.command_argv(["a"]) == ["a"]
    assert uml.command_argv([]) == []


# --------------------------------------------------------------------------- hil vcan


def test_ensure_vcan_on_a_kernel_without_can(monkeypatch):
    monkeypatch.setattr(vcan, "vcan_present", lambda ch="vcan0": False)
    monkeypatch.setattr(vcan, "native_vcan_supported", lambda: False)
    with pytest.raises(vcan.VcanError) as err:
        vcan.ensure_vcan("vcan0")
    assert str(err.value) == (
        "hil vcan up: this kernel has no CAN support (Unknown device type); use `hil vcan exec` "
        "or `hil uml`, which run inside user-mode Linux")


def test_ensure_vcan_without_root(monkeypatch):
    monkeypatch.setattr(vcan, "vcan_present", lambda ch="vcan0": False)
    monkeypatch.setattr(vcan, "native_vcan_supported", lambda: True)
    monkeypatch.setattr(vcan, "has_net_admin", lambda: False)
    with pytest.raises(vcan.VcanError) as err:
        vcan.ensure_vcan("vcan0")
    assert str(err.value) == (
        "hil vcan up: creating vcan0 needs root (CAP_NET_ADMIN); run as root or with sudo")


@pytest.mark.parametrize(("present", "up", "supported", "admin", "want"), [
    (True, True, True, False, "native"),
    (True, False, True, True, "native"),
    (True, False, True, False, "uml"),
    (False, False, True, True, "native"),
    (False, False, True, False, "uml"),
    (False, False, False, True, "uml"),
])
def test_exec_chooses_native_when_vcan_can_exist_here(monkeypatch, present, up, supported,
                                                      admin, want):
    monkeypatch.setattr(vcan, "vcan_present", lambda ch="vcan0": present)
    monkeypatch.setattr(vcan, "vcan_up", lambda ch="vcan0": up)
    monkeypatch.setattr(vcan, "native_vcan_supported", lambda: supported)
    monkeypatch.setattr(vcan, "has_net_admin", lambda: admin)
    assert vcan.choose_path("vcan0") == want
    assert vcan.choose_path("vcan0", force="uml") == "uml"


def test_exec_native_returns_the_command_status(monkeypatch):
    monkeypatch.setattr(vcan, "ensure_vcan", lambda ch, where: None)
    rc = vcan.exec_with_vcan([sys.executable, "-c", "raise SystemExit(5)"], force="native")
    assert rc == 5
    assert vcan.run_native(["/nonexistent/cmd"]) == 127


def test_exec_inside_uml_runs_run_in_uml_with_the_channel(monkeypatch):
    seen = {}
    monkeypatch.setattr(vcan, "in_uml", lambda: False)

    def fake_run(argv, **kw):
        seen.update(kw, argv=argv)
        return 3

    monkeypatch.setattr(vcan, "run_in_uml", fake_run)
    rc = vcan.exec_with_vcan(["pytest", "-m", "vcan"], channel="vcan1", force="uml", mem="2G")
    assert rc == 3
    assert seen == {"argv": ["pytest", "-m", "vcan"], "mem": "2G", "timeout_s": None,
                    "channels": ("vcan1",)}


@pytest.mark.parametrize("argv", [
    ["vcan", "exec"], ["vcan", "exec", "--"], ["uml"], ["uml", "--"],
    ["vcan", "up", "--channel", "bad name"], ["uml", "--timeout", "0", "--", "true"],
])
def test_cli_usage_errors_exit_2(argv, capsys):
    assert cli.main(argv) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_cli_vcan_status_exit_code(monkeypatch, capsys):
    monkeypatch.setattr(vcan, "vcan_present", lambda ch="vcan0": False)
    monkeypatch.setattr(vcan, "native_vcan_supported", lambda: False)
    assert cli.main(["vcan", "status"]) == 1
    assert "this kernel has no CAN support" in capsys.readouterr().out


def test_uml_streams_to_given_binary_stream_types():
    # run_in_uml writes bytes; a text stream is reached through its .buffer.
    buf = io.BytesIO()
    assert uml._binary_stream(buf) is buf
    assert uml._binary_stream(sys.__stdout__) is sys.__stdout__.buffer
