"""The import direction of the project's packages, read from the source by ``ast``.

Every ``import`` and ``from ... import`` statement is counted, at module level and inside
functions alike (a lazy import is still a dependency). ``ALLOWED`` is the whole list of edges
between the project's top-level packages; ``docs/architecture.md`` draws it. Run as a script to
print the allowed edges, the edges found (with how many imports make each) and any violation::

    .venv/bin/python tests/architecture/layering.py
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("common", "bus", "flight", "plant", "hil")

# package -> the project packages it may import. The cores (flight, plant) and the bus stand on
# the ground floor only; flight and plant never import each other; only the shell sees all.
ALLOWED: dict[str, frozenset[str]] = {
    "common": frozenset(),
    "bus": frozenset({"common"}),
    "flight": frozenset({"common"}),
    "plant": frozenset({"common"}),
    "hil": frozenset({"common", "bus", "flight", "plant"}),
}


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(root: Path, path: Path) -> list[tuple[str, int]]:
    """(imported module, line) for every import statement in ``path`` (relative ones resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = module_name(root, path).split(".")
    is_pkg = path.name == "__init__.py"
    out: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here if is_pkg else here[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((mod, node.lineno))
    return out


def edges(root: Path = REPO) -> dict[tuple[str, str], list[str]]:
    """(from package, to package) -> the ``file:line`` of each import making that edge."""
    found: dict[tuple[str, str], list[str]] = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            for mod, line in imports_of(root, path):
                top = mod.split(".")[0]
                if top in PACKAGES and top != pkg:
                    rel = path.relative_to(root).as_posix()
                    found.setdefault((pkg, top), []).append(f"{rel}:{line}")
    return found


def violations(root: Path = REPO) -> list[str]:
    """One line per import that goes against ``ALLOWED``."""
    out = []
    for (src, dst), where in sorted(edges(root).items()):
        if dst not in ALLOWED.get(src, frozenset()):
            out += [f"{w}: {src} imports {dst} (allowed: {sorted(ALLOWED.get(src, ()))})"
                    for w in where]
    return out


def module_cycles(root: Path = REPO, *, lazy: bool = True) -> list[list[str]]:
    """Cycles among the project's modules (Tarjan's strongly connected components), through
    every import, or through module-level imports only when ``lazy`` is False."""
    graph: dict[str, set[str]] = {}
    mods = {module_name(root, p): p for pkg in PACKAGES for p in (root / pkg).rglob("*.py")}
    for name, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        deps: set[str] = set()
        for node in ast.walk(tree) if lazy else tree.body:
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            deps |= {t for t in targets if t in mods and t != name}
        graph[name] = deps
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    sccs: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    sys.setrecursionlimit(max(1000, 4 * len(graph)))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sccs


def main() -> int:
    print("allowed edges:")
    for src in PACKAGES:
        print(f"  {src} -> {', '.join(sorted(ALLOWED[src])) or '(nothing of the project)'}")
    print("edges found (imports):")
    for (src, dst), where in sorted(edges().items()):
        print(f"  {src} -> {dst}: {len(where)}")
    bad = violations()
    for line in bad:
        print(f"violation: {line}")
    for comp in module_cycles():
        print(f"cycle: {' <-> '.join(comp)}")
    print(f"direction: {len(bad)} violation(s)" if bad else "direction: ok")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
