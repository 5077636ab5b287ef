"""``hil lcm-types``: write or check the LCM types generated from the catalog (docs/lcm.md).

The ``.lcm`` files (``bus/lcm/``) come from ``bus.lcm_schema``; the Python types
(``bus/hil_lcm/``) from them through LCM's own ``lcm-gen --python`` (the PyPI package ``lcm``,
pinned in pyproject.toml). ``--check`` generates both into a temporary folder and compares
them with the committed ones, file by file.
"""

from __future__ import annotations

import argparse
import filecmp
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from bus.lcm_schema import LCM_DIR, PACKAGE, PY_DIR, lcm_files
from hil.errors import UsageError

# The telemetry types (hil.telemetry) are written by hand in hil/lcm/; their Python too is
# lcm-gen's, in hil/hil_telemetry/.
TELEMETRY_LCM_DIR = Path(__file__).with_name("lcm")
TELEMETRY_PY_DIR = Path(__file__).parent
TELEMETRY_PACKAGE = "hil_telemetry"


def lcm_tool(name: str) -> str:
    """An LCM program (``lcm-gen``, ``lcm-logger``...) beside this Python (the venv's), else
    on PATH."""
    here = Path(sys.executable).parent / name
    found = str(here) if here.exists() else shutil.which(name)
    if not found:
        raise UsageError(f"hil: expected {name} (PyPI package lcm) installed, got none "
                         f"beside python nor on PATH: run `bash scripts/setup.sh`")
    return found


def lcm_gen_path() -> str:
    return lcm_tool("lcm-gen")


def _lcm_gen(files: list[str], py_dir: Path, package: str) -> None:
    pkg = py_dir / package
    if pkg.exists():
        shutil.rmtree(pkg)
    subprocess.run([lcm_gen_path(), "--python", "--ppath", str(py_dir), *sorted(files)],
                   check=True, capture_output=True, text=True)


def generate_telemetry(py_dir: Path) -> None:
    _lcm_gen([str(p) for p in TELEMETRY_LCM_DIR.glob("*.lcm")], py_dir, TELEMETRY_PACKAGE)


def generate(lcm_dir: Path, py_dir: Path) -> None:
    """Write the .lcm files into ``lcm_dir`` and the lcm-gen Python package into ``py_dir``."""
    lcm_dir.mkdir(parents=True, exist_ok=True)
    for old in lcm_dir.glob("*.lcm"):
        old.unlink()
    files = []
    for name, text in lcm_files().items():
        (lcm_dir / name).write_text(text)
        files.append(str(lcm_dir / name))
    _lcm_gen(files, py_dir, PACKAGE)


def differences(lcm_dir: Path, py_dir: Path, telemetry_py_dir: Path = TELEMETRY_PY_DIR
                ) -> list[str]:
    """Files that differ between a fresh generation and ``lcm_dir`` / ``py_dir`` (and the
    telemetry types' Python in ``telemetry_py_dir``)."""
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        generate(t / "lcm", t)
        generate_telemetry(t / "tel")
        out = []
        for fresh, committed in ((t / "lcm", lcm_dir), (t / PACKAGE, py_dir / PACKAGE),
                                 (t / "tel" / TELEMETRY_PACKAGE,
                                  telemetry_py_dir / TELEMETRY_PACKAGE)):
            want = sorted(p.name for p in fresh.iterdir() if p.suffix in (".lcm", ".py"))
            have = sorted(p.name for p in committed.iterdir()
                          if p.suffix in (".lcm", ".py")) if committed.exists() else []
            out += [f"{committed / n}: missing" for n in want if n not in have]
            out += [f"{committed / n}: not generated" for n in have if n not in want]
            out += [f"{committed / n}: differs" for n in want
                    if n in have and not filecmp.cmp(fresh / n, committed / n, shallow=False)]
        return out


def run(args: argparse.Namespace) -> int:
    if args.check:
        diff = differences(LCM_DIR, PY_DIR)
        for d in diff:
            print(f"{d}; run `hil lcm-types`", file=sys.stderr)
        if not diff:
            print(f"bus/lcm and bus/{PACKAGE}: match the catalog; hil/{TELEMETRY_PACKAGE}: "
                  "matches hil/lcm")
        return 1 if diff else 0
    generate(LCM_DIR, PY_DIR)
    generate_telemetry(TELEMETRY_PY_DIR)
    print(f"wrote bus/lcm/*.lcm, bus/{PACKAGE}/ and hil/{TELEMETRY_PACKAGE}/ "
          "(lcm-gen --python)")
    return 0


def register(sub) -> None:
    p = sub.add_parser("lcm-types", help="write or check the LCM types made from the catalog",
                       description=__doc__.split("\n")[0])
    p.add_argument("--check", action="store_true",
                   help="exit 1 if bus/lcm or bus/hil_lcm differ from a fresh generation")
    p.set_defaults(func=run)
