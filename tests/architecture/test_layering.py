"""The dependency direction, enforced by scanning imports (house style, habits 1 and 13).

``flight/``, ``plant/`` and ``bus/`` import nothing of the shell ``hil/``; ``flight/`` and
``plant/`` never import each other; ``common/`` (the ground floor) imports no other package of
the project; no circle of imports among the modules (lazy imports inside functions included).
The allowed edges are ``layering.ALLOWED``; run ``layering.py`` to print them.
The scanner itself is checked on synthetic trees: an upward import, a lazy one inside a
function, one in a sub-package, a core-to-core one and one from the ground floor up are each
reported.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from layering import ALLOWED, PACKAGES, edges, module_cycles, violations


def test_the_repository_keeps_the_direction() -> None:
    found = sorted(edges())
    print("allowed:", {k: sorted(v) for k, v in ALLOWED.items()})
    print("found:", found)
    assert violations() == []


def test_no_import_cycle_even_through_lazy_imports() -> None:
    assert module_cycles() == []


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    return tmp_path


@pytest.mark.parametrize(("files", "expected"), [
    ({"flight/x.py": "from hil.config import load_vehicle\n"},
     "flight/x.py:1: flight imports hil (allowed: ['common'])"),
    ({"plant/x.py": "import numpy\n\ndef f():\n    import hil.errors\n"},
     "plant/x.py:4: plant imports hil (allowed: ['common'])"),
    ({"bus/sub/__init__.py": "", "bus/sub/x.py": "import can\nimport hil.errors as e\n"},
     "bus/sub/x.py:2: bus imports hil (allowed: ['common'])"),
    ({"plant/x.py": "from flight.detector import Detection\n"},
     "plant/x.py:1: plant imports flight (allowed: ['common'])"),
    ({"common/x.py": "from bus.catalog import HEARTBEAT_PERIOD_S\n"},
     "common/x.py:1: common imports bus (allowed: [])"),
])
def test_a_reintroduced_forbidden_import_is_reported(tmp_path, files, expected) -> None:
    root = _tree(tmp_path, files)
    assert violations(root) == [expected]


def test_allowed_imports_pass_and_a_module_cycle_is_found(tmp_path) -> None:
    root = _tree(tmp_path, {
        "flight/x.py": "from common.units import DEG\nimport numpy\n",
        "hil/a.py": "from hil.b import g\nfrom flight.x import DEG\n",
        "hil/b.py": "def g():\n    from hil.a import f\n",
    })
    assert violations(root) == []
    assert module_cycles(root) == [["hil.a", "hil.b"]]
    assert module_cycles(root, lazy=False) == []


def test_importing_the_cores_loads_no_yaml_no_bus_and_no_shell() -> None:
    # A fresh interpreter: what `import flight.software, plant.core` really loads.
    import subprocess
    import sys

    code = ("import sys, flight.software, plant.core; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'yaml', 'hil', 'bus', 'can'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
