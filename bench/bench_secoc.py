"""SecOC cost per message (bus.secoc): the HMAC alone, and sign (sender, with the message
already encoded, as ``Port.send`` does) and check (receiver: it encodes the decoded message
again) of THR_CMD, FAULT_CMD and GYRO, microseconds per message, on this machine. Prints figures;
asserts nothing.

    .venv/bin/python bench/bench_secoc.py [--n 20000]
"""

from __future__ import annotations

import argparse
import time

from bus.catalog import FaultAction, FaultKind
from bus.codec import FaultCmd, Gyro, ThrCmd, encode
from bus.secoc import Authenticator, compute_mac


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20000)
    n = ap.parse_args().n
    key = bytes(range(32))
    tx = Authenticator(key)
    for name, make in (("THR_CMD (12 thrusters)",
                        lambda k: ThrCmd(k, (3, 0, 20, 0, 5, 0, 0, 17, 0, 0, 3, 0), 7, k)),
                       ("FAULT_CMD", lambda k: FaultCmd(k % 256, FaultAction.INJECT,
                                                        FaultKind.STUCK_ON, 1, 0.5, 0.0, None)),
                       ("GYRO", lambda k: Gyro(k & 0xFFFF, (1e-3, -2e-3, 3e-4), 1))):
        msgs = [make(k + 1) for k in range(n)]
        plain = [encode(m) for m in msgs]
        t0 = time.perf_counter()
        for k, (m, p) in enumerate(zip(msgs, plain, strict=True)):
            compute_mac(key, m, k, p)
        t_mac = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        macs = [tx.sign(m, 1000.0 + 0.02 * k, p) for k, (m, p) in
                enumerate(zip(msgs, plain, strict=True))]
        t_sign = (time.perf_counter() - t0) / n
        rx = Authenticator(key)
        t0 = time.perf_counter()
        ok = 0
        for k, (m, mac) in enumerate(zip(msgs, macs, strict=True)):
            ok += len(rx.accept([(m, 0.0), (mac, 0.0)], 1000.0 + 0.02 * k))
        t_check = (time.perf_counter() - t0) / n
        print(f"{name}: HMAC-SHA256 over id, payload, freshness {t_mac * 1e6:.1f} us; "
              f"sign {t_sign * 1e6:.1f} us, check (re-encodes) {t_check * 1e6:.1f} us per "
              f"message ({ok}/{n} accepted)")


if __name__ == "__main__":
    main()
