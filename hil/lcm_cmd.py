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


def lcm_gen_path() -> str:
    """``lcm-gen`` beside this Python (the venv's), else on PATH."""
    here = Path(sys.executable).parent / "lcm-gen"
    found = str(here) if here.exists() else shutil.which("lcm-gen")
    if not found:
        raise UsageError("hil lcm-types: expected lcm-gen (PyPI package lcm) installed, got "
                         "none beside python nor on PATH: run `bash scripts/setup.sh`")
    return found


def generate(lcm_dir: Path, py_dir: Path) -> None:
    """Write the .lcm files into ``lcm_dir`` and the lcm-gen Python package into ``py_dir``."""
    lcm_dir.mkdir(parents=True, exist_ok=True)
    for old in lcm_dir.glob("*.lcm"):
        old.unlink()
    files = []
    for name, text in lcm_files().items():
        (lcm_dir / name).write_text(text)
        files.append(str(lcm_dir / name))
    pkg = py_dir / PACKAGE
    if pkg.exists():
        shutil.rmtree(pkg)
    subprocess.run([lcm_gen_path(), "--python", "--ppath", str(py_dir), *sorted(files)],
                   check=True, capture_output=True, text=True)


def differences(lcm_dir: Path, py_dir: Path) -> list[str]:
    """Files that differ between a fresh generation and ``lcm_dir`` / ``py_dir``."""
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        generate(t / "lcm", t)
        out = []
        for fresh, committed in ((t / "lcm", lcm_dir), (t / PACKAGE, py_dir / PACKAGE)):
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
            print(f"bus/lcm and bus/{PACKAGE}: match the catalog")
        return 1 if diff else 0
    generate(LCM_DIR, PY_DIR)
    print(f"wrote bus/lcm/*.lcm and bus/{PACKAGE}/ (lcm-gen --python)")
    return 0


def register(sub) -> None:
    p = sub.add_parser("lcm-types", help="write or check the LCM types made from the catalog",
                       description=__doc__.split("\n")[0])
    p.add_argument("--check", action="store_true",
                   help="exit 1 if bus/lcm or bus/hil_lcm differ from a fresh generation")
    p.set_defaults(func=run)
