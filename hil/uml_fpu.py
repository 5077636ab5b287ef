"""User-mode Linux on hosts whose XSAVE area it cannot hold (Intel AMX).

``linux.uml`` runs each of its processes as a host process under ``ptrace`` and saves and
restores their floating-point registers with ``PTRACE_GETREGSET`` / ``PTRACE_SETREGSET`` on
``NT_X86_XSTATE``. The host kernel takes a ``SETREGSET`` of that regset only with the whole
XSAVE buffer; on a CPU with AMX tiles that buffer is about 11 kB, more than UML provides
(UML 6.1 and 6.12 alike, checked), so every boot ends in "ptrace set fp regs failed, errno =
14" and a kernel panic as init starts.

UML falls back to the legacy FXSAVE regset (x87 and SSE) when the XSTATE regset is refused at
boot. ``install_xstate_refusal`` makes the host refuse it for the UML process tree only: a
seccomp filter that answers ``EIO`` to ``ptrace(PTRACE_GETREGSET|PTRACE_SETREGSET, pid,
NT_X86_XSTATE, ...)`` and allows every other call. With the legacy regset UML keeps only the
x87 and SSE state of its processes: code that uses AVX or AVX-512 registers inside crashes
(seen: static busybox and libpython segfault at start). ``SSE_ONLY_ENV`` keeps glibc, NumPy
and OpenBLAS on their SSE code paths; the glibc part also goes on the kernel command line
(``kernel_env_args``), which the kernel hands to init as its environment, so init and every
process it starts get it from the first instruction. Checked on such a host: boot, module
loading, vcan0 up, a NumPy matrix product equal to the host's to the last bit.

Code that detects AVX by itself at run time (some Rust crates in rerun-sdk) is not covered;
hosts without AMX keep UML's own XSTATE path, untouched.
"""

from __future__ import annotations

import ctypes
import os
import struct
from pathlib import Path

PTRACE_NR_X86_64 = 101
PTRACE_GETREGSET = 0x4204
PTRACE_SETREGSET = 0x4205
NT_X86_XSTATE = 0x202
_EIO = 5
_SECCOMP_RET_ALLOW = 0x7FFF0000
_SECCOMP_RET_ERRNO = 0x00050000
_PR_SET_NO_NEW_PRIVS = 38
_PR_SET_SECCOMP = 22
_SECCOMP_MODE_FILTER = 2
_BPF_LD_W_ABS, _BPF_JEQ_K, _BPF_RET_K = 0x20, 0x15, 0x06
# struct seccomp_data: int nr; u32 arch; u64 instruction_pointer; u64 args[6]
_OFF_NR, _OFF_ARG0, _OFF_ARG2 = 0, 16, 32

GLIBC_SSE_ONLY = ("glibc.cpu.hwcaps=-AVX,-AVX2,-AVX512F,-AVX512CD,-AVX512BW,-AVX512DQ,"
                  "-AVX512VL,-AVX_Fast_Unaligned_Load,-FMA,-FMA4")
SSE_ONLY_ENV = {
    "GLIBC_TUNABLES": GLIBC_SSE_ONLY,
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Nehalem",
}


def _ins(code: int, jt: int, jf: int, k: int) -> bytes:
    return struct.pack("HBBI", code, jt, jf, k)


def refusal_program() -> bytes:
    """The BPF program of the module doc (9 instructions, 8 bytes each)."""
    return b"".join([
        _ins(_BPF_LD_W_ABS, 0, 0, _OFF_NR),
        _ins(_BPF_JEQ_K, 0, 6, PTRACE_NR_X86_64),       # not ptrace: allow
        _ins(_BPF_LD_W_ABS, 0, 0, _OFF_ARG0),
        _ins(_BPF_JEQ_K, 1, 0, PTRACE_GETREGSET),
        _ins(_BPF_JEQ_K, 0, 3, PTRACE_SETREGSET),       # another request: allow
        _ins(_BPF_LD_W_ABS, 0, 0, _OFF_ARG2),
        _ins(_BPF_JEQ_K, 0, 1, NT_X86_XSTATE),          # another regset: allow
        _ins(_BPF_RET_K, 0, 0, _SECCOMP_RET_ERRNO | _EIO),
        _ins(_BPF_RET_K, 0, 0, _SECCOMP_RET_ALLOW),
    ])


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]


def install_xstate_refusal() -> None:
    """In a child before exec (``preexec_fn``): install the filter for it and its tree."""
    prog = refusal_program()
    buf = ctypes.create_string_buffer(prog, len(prog))
    fprog = _SockFprog(len(prog) // 8, ctypes.cast(buf, ctypes.c_void_p))
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_NO_NEW_PRIVS)")
    if libc.prctl(_PR_SET_SECCOMP, _SECCOMP_MODE_FILTER, ctypes.byref(fprog), 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_SECCOMP)")


def kernel_env_args() -> list[str]:
    """Kernel command-line words that become init's environment (the glibc tunable)."""
    return [f"GLIBC_TUNABLES={GLIBC_SSE_ONLY}"]


def host_needs_legacy_fpu(cpuinfo: str | None = None) -> bool:
    """True on an x86-64 host with AMX tiles (its XSAVE area is too large for UML), or when
    ``HIL_UML_LEGACY_FPU=1``; ``HIL_UML_LEGACY_FPU=0`` keeps UML's own XSTATE path."""
    forced = os.environ.get("HIL_UML_LEGACY_FPU")
    if forced in ("0", "1"):
        return forced == "1"
    if cpuinfo is None:
        if os.uname().machine != "x86_64":
            return False
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return False
    flags = next((ln.split(":", 1)[1].split() for ln in cpuinfo.splitlines()
                  if ln.startswith("flags")), [])
    return "amx_tile" in flags
