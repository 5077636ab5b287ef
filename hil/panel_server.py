"""The panel bridge process that ``hil up`` starts beside the plant (``hil.panel_bridge``).

``python -m hil.panel_server --run DIR --interface I --channel C``: serves ``DIR/control``
with the panel's own ``send_and_wait`` until SIGTERM or SIGINT.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

from hil.node_shell import Stop
from hil.panel import send_and_wait
from hil.panel_bridge import serve
from hil.secoc_key import KEY_FILE, read_key


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.panel_server")
    p.add_argument("--run", required=True)
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    a = p.parse_args(argv)
    run = Path(a.run)
    # The run's SecOC key (hil run / hil up write it before the nodes start): the bridge signs
    # FAULT_CMD as the panel on the host would.
    key = read_key(run / KEY_FILE) if (run / KEY_FILE).exists() else None
    return serve(run, a.interface, a.channel, Stop(), partial(send_and_wait, key=key),
                 log=lambda text: print(text, flush=True))


if __name__ == "__main__":
    sys.exit(main())
