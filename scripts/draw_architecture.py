"""Draw docs/architecture.svg (and .png): the processes of a run, the messages between them,
the run folder, and the packages with their allowed imports.

The drawing is made from the code, not by hand: the messages, their senders, receivers and
periods from ``bus.catalog.CATALOG``; the package edges from
``tests/architecture/layering.ALLOWED``. Beside the picture it writes
``docs/architecture.txt``, the same facts as text; ``tests/test_docs.py`` rebuilds that text
from the code and compares it with the committed one, so a message or a package edge added
without drawing it again fails the test.

    .venv/bin/python scripts/draw_architecture.py
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests" / "architecture"))

DOCS = REPO / "docs"

# Processes of `hil up` (and `hil run`, without the panel bridge) and the host-side tools.
PROCESSES = {
    "PLANT": "plant process\npython -m hil.nodes plant\n(time master in lockstep)",
    "FLIGHT": "flight process\npython -m hil.nodes flight\n(200 ms tick)",
    "PANEL": ("fault panel\nhil fault / hil console\n(or the panel bridge,\n"
              "python -m hil.panel_server)"),
}
FILES = ("plant.jsonl, flight.jsonl (one line per tick)", "bus.log (candump), run.rrd, "
         "summary.json", "control/ (fault requests, stop)")


def messages() -> list[tuple[str, str, tuple[str, ...], float | None]]:
    """(message, sender, receivers, period s) of every message set in the catalog."""
    from bus.catalog import CATALOG
    from bus.codec import set_name_of

    out, seen = [], set()
    for f in CATALOG.frames:
        name = set_name_of(f)
        if name in seen:
            continue
        seen.add(name)
        out.append((name, f.sender.name, tuple(r.name for r in f.receivers), f.cycle_s))
    return out


def package_edges() -> list[tuple[str, str]]:
    from layering import ALLOWED, PACKAGES

    return [(p, q) for p in PACKAGES for q in sorted(ALLOWED[p])]


def model_text() -> str:
    """The facts the picture shows, one per line (what the test compares)."""
    lines = ["# docs/architecture.svg shows (written by scripts/draw_architecture.py)",
             "processes: " + ", ".join(PROCESSES)]
    for name, snd, rcv, cyc in messages():
        period = f"every {cyc * 1000:g} ms" if cyc else "on request"
        lines.append(f"message {name}: {snd} -> {', '.join(rcv)} ({period})")
    for p, q in package_edges():
        lines.append(f"package {p} imports {q}")
    return "\n".join(lines) + "\n"


def draw(out_svg: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["svg.hashsalt"] = "thruster-hil"
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    fig, ax = plt.subplots(figsize=(12, 7.4))
    ax.set_xlim(0, 12)
    ax.set_ylim(0, 7.4)
    ax.axis("off")
    ax.set_title("thruster-hil: processes, messages (CAN, bus/catalog.py) and packages",
                 fontsize=12)

    def box(x, y, w, h, text, color, size=9):
        ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.05", fc=color,
                                    ec="#333333", lw=1.0))
        ax.text(x + w / 2, y + h / 2, text, ha="center", va="center", fontsize=size)

    pos = {"FLIGHT": (0.3, 4.6), "PLANT": (8.2, 4.6), "PANEL": (4.25, 1.7)}
    w, h = 3.5, 1.6
    colors = {"FLIGHT": "#cfe3ff", "PLANT": "#ffe2c6", "PANEL": "#e3f5d6"}
    for k, (x, y) in pos.items():
        box(x, y, w, h, PROCESSES[k], colors[k])
    centre = {k: (x + w / 2, y + h / 2) for k, (x, y) in pos.items()}

    # One arrow per sender -> receiver pair, labelled with its messages.
    pairs: dict[tuple[str, str], list[str]] = {}
    for name, snd, rcv, cyc in messages():
        for r in rcv:
            per = f" {cyc * 1000:g} ms" if cyc else ""
            pairs.setdefault((snd, r), []).append(name + per)
    offsets = {("FLIGHT", "PLANT"): 0.45, ("PLANT", "FLIGHT"): -0.45}
    for (snd, rcv), names in sorted(pairs.items()):
        (x0, y0), (x1, y1) = centre[snd], centre[rcv]
        off = offsets.get((snd, rcv), 0.0)
        if snd in ("FLIGHT", "PLANT") and rcv in ("FLIGHT", "PLANT"):
            x0 += (w / 2 if x1 > x0 else -w / 2)
            x1 -= (w / 2 if x1 > x0 else -w / 2)
            y0 += off
            y1 += off
        else:
            y0 += -h / 2 if y1 < y0 else h / 2
            y1 += h / 2 if y1 < y0 else -h / 2
            if snd == "PANEL":  # the request goes up beside the answers coming down
                x0, x1 = x0 + 1.3, x1 + 0.9
            elif rcv == "PANEL":
                x1 += 0.35 if snd == "PLANT" else -0.35
        ax.add_patch(FancyArrowPatch((x0, y0), (x1, y1), arrowstyle="-|>", mutation_scale=12,
                                     color="#444444", lw=1.0))
        up = snd == "PANEL"
        ax.text((x0 + x1) / 2 + (0.25 if up else 0.0),
                (y0 + y1) / 2 + (0.12 if off >= 0 else -0.12) - (0.45 if up else 0.0),
                "\n".join(names), ha="left" if up else "center",
                va="bottom" if off >= 0 else "top",
                fontsize=7.5, color="#1f3d7a",
                bbox={"fc": "white", "ec": "none", "alpha": 0.8, "pad": 0.5})

    box(4.25, 6.35, 3.5, 0.8, "supervisor: hil run / hil up\n(starts the processes, "
        "bus monitor -> bus.log)", "#f0f0f0", 8)
    box(8.2, 0.25, 3.5, 1.9, "run folder (shared disk, also with\nuser-mode Linux):\n"
        + "\n".join(FILES), "#fff7c2", 7.5)
    ax.add_patch(FancyArrowPatch((7.75, 2.4), (8.2, 1.6), arrowstyle="<|-|>",
                                 mutation_scale=10, color="#888888", lw=0.8, ls="--"))

    # Packages and their allowed imports (tests/architecture).
    ax.text(0.3, 3.15, "packages (an arrow: may import)", fontsize=9, weight="bold")
    ppos = {"hil": (1.6, 2.5), "bus": (0.3, 1.45), "flight": (1.6, 1.45), "plant": (2.9, 1.45),
            "common": (1.6, 0.35)}
    for p, (x, y) in ppos.items():
        box(x, y, 0.95, 0.45, p, "#eeeeee", 8.5)
    for p, q in package_edges():
        (x0, y0), (x1, y1) = ppos[p], ppos[q]
        ax.add_patch(FancyArrowPatch((x0 + 0.47, y0), (x1 + 0.47, y1 + 0.45),
                                     arrowstyle="-|>", mutation_scale=9, color="#666666",
                                     lw=0.8))
    fig.savefig(out_svg, format="svg", metadata={"Date": None})
    fig.savefig(out_svg.with_suffix(".png"), format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)


def main() -> int:
    DOCS.mkdir(exist_ok=True)
    (DOCS / "architecture.txt").write_text(model_text())
    draw(DOCS / "architecture.svg")
    print(f"wrote {DOCS / 'architecture.svg'}, .png and .txt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
