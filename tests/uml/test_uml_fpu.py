"""``hil.uml_fpu``: the seccomp program that makes UML use the legacy FPU regset on AMX hosts.

The BPF program is checked by interpreting it (an independent reading of the instruction
encoding: classic BPF ``ld [k]``, ``jeq #k, jt, jf``, ``ret #k``) on the system calls it must
refuse and the ones it must allow; the AMX detection on ``/proc/cpuinfo`` texts.
"""

from __future__ import annotations

import struct

import pytest

from hil.uml_fpu import (
    NT_X86_XSTATE,
    PTRACE_GETREGSET,
    PTRACE_NR_X86_64,
    PTRACE_SETREGSET,
    host_needs_legacy_fpu,
    kernel_env_args,
    refusal_program,
)

ALLOW, EIO = 0x7FFF0000, 0x00050005


def _run_bpf(prog: bytes, nr: int, args: tuple[int, ...]) -> int:
    data = struct.pack("iIQ6Q", nr, 0xC000003E, 0, *(list(args) + [0] * (6 - len(args))))
    pc, acc = 0, 0
    insns = [struct.unpack("HBBI", prog[i:i + 8]) for i in range(0, len(prog), 8)]
    while True:
        code, jt, jf, k = insns[pc]
        if code == 0x20:
            acc = struct.unpack_from("I", data, k)[0]
            pc += 1
        elif code == 0x15:
            pc += 1 + (jt if acc == k else jf)
        elif code == 0x06:
            return k
        else:
            raise AssertionError(f"unexpected BPF code {code:#x}")


@pytest.mark.parametrize(("nr", "args", "want"), [
    (PTRACE_NR_X86_64, (PTRACE_GETREGSET, 123, NT_X86_XSTATE), EIO),
    (PTRACE_NR_X86_64, (PTRACE_SETREGSET, 123, NT_X86_XSTATE), EIO),
    (PTRACE_NR_X86_64, (PTRACE_GETREGSET, 123, 1), ALLOW),      # NT_PRSTATUS
    (PTRACE_NR_X86_64, (PTRACE_SETREGSET, 123, 2), ALLOW),      # NT_PRFPREG
    (PTRACE_NR_X86_64, (14, 123, 0), ALLOW),                    # PTRACE_GETFPREGS
    (PTRACE_NR_X86_64, (0x4206, 123, NT_X86_XSTATE), ALLOW),    # PTRACE_SEIZE
    (0, (PTRACE_GETREGSET, 0, NT_X86_XSTATE), ALLOW),           # read(2), same arguments
    (1, (), ALLOW),
])
def test_only_the_xstate_regset_is_refused(nr, args, want) -> None:
    assert _run_bpf(refusal_program(), nr, args) == want


def test_amx_hosts_are_detected_from_their_cpu_flags(monkeypatch) -> None:
    monkeypatch.delenv("HIL_UML_LEGACY_FPU", raising=False)
    assert host_needs_legacy_fpu("flags\t\t: fpu sse avx avx512f amx_bf16 amx_tile amx_int8\n")
    assert not host_needs_legacy_fpu("flags\t\t: fpu sse avx avx2 avx512f avx512bw\n")
    monkeypatch.setenv("HIL_UML_LEGACY_FPU", "0")
    assert not host_needs_legacy_fpu("flags : amx_tile\n")
    monkeypatch.setenv("HIL_UML_LEGACY_FPU", "1")
    assert host_needs_legacy_fpu("flags : sse\n")


def test_the_glibc_tunable_goes_to_init_as_one_kernel_word() -> None:
    (word,) = kernel_env_args()
    assert word.startswith("GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX,") and " " not in word
