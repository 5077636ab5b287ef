"""Save docs/console.svg (and .png): `hil console` at 80x24 on a real S000-stuck run, shown
as it was two ticks after the detection.

It runs S000-stuck in lockstep between real processes (udp_multicast: no CAN needed), copies
the run's per-tick records up to that tick into a scratch folder, attaches the console to it
in Textual's headless pilot and saves the screen. The PNG needs ``rsvg-convert``
(Debian ``librsvg2-bin``); without it only the SVG is written.

    .venv/bin/python scripts/console_screenshot.py
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
DOCS = REPO / "docs"


def cut(run: Path, dest: Path, last_tick: int) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    for name in ("plant.jsonl", "flight.jsonl"):
        keep = [x for x in (run / name).read_text().splitlines()
                if json.loads(x).get("tick", 0) <= last_tick and not json.loads(x).get("final")]
        (dest / name).write_text("\n".join(keep) + "\n")


async def shoot(run: Path, svg: Path) -> None:
    from hil.console import _app_classes

    app_cls, _ = _app_classes()
    app = app_cls(run)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause(0.5)
        app.title = "hil console runs/up"
        await pilot.pause(0.1)
        app.save_screenshot(svg.name, str(svg.parent))


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        subprocess.run([sys.executable, "-m", "hil.cli", "run", "S000-stuck", "--out", str(run),
                        "--interface", "udp_multicast", "--channel", "239.74.200.17"],
                       check=False, cwd=REPO, env=dict(os.environ, RERUN_ANALYTICS="0"),
                       stdout=subprocess.DEVNULL)
        det = next(json.loads(x)["detection"] for x in (run / "flight.jsonl").read_text()
                   .splitlines() if json.loads(x).get("detection"))
        view = Path(tmp) / "view"
        cut(run, view, det["tick"] + 2)
        svg = DOCS / "console.svg"
        asyncio.run(shoot(view, svg))
    # Browsers keep the leading spaces of the text rows; librsvg needs to be told.
    text = svg.read_text().replace("<svg ", '<svg xml:space="preserve" ', 1)
    svg.write_text(text)
    if shutil.which("rsvg-convert"):
        subprocess.run(["rsvg-convert", "-w", "1100", str(svg), "-o",
                        str(svg.with_suffix(".png"))], check=True)
    print(f"wrote {svg}" + (" and .png" if shutil.which("rsvg-convert") else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
