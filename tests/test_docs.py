"""The documents stay true to the code: the architecture picture's facts (messages, senders,
receivers, periods, package edges) are rebuilt from the catalog and the layering rules and
compared with the committed ones; the pictures the README shows exist; every seed the code
cites has its full reference in docs/design.md; the code cites documents that exist."""

from __future__ import annotations

import importlib.util
import re

from hil.config import REPO_ROOT

DOCS = REPO_ROOT / "docs"


def _draw_module():
    spec = importlib.util.spec_from_file_location("draw_architecture",
                                                  REPO_ROOT / "scripts" / "draw_architecture.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_architecture_picture_shows_what_the_code_has():
    draw = _draw_module()
    committed = (DOCS / "architecture.txt").read_text()
    assert draw.model_text() == committed, (
        "the catalog or the package rules changed: run scripts/draw_architecture.py")
    svg = (DOCS / "architecture.svg").read_text()
    for name, *_ in draw.messages():
        # matplotlib writes text as glyph paths; each label's text is kept in a comment.
        assert name in svg, name


def test_the_readme_shows_the_pictures_and_points_at_the_docs():
    readme = (REPO_ROOT / "README.md").read_text()
    for path in ("docs/architecture.png", "docs/console.png", "docs/tutorial.md",
                 "docs/glossary.md"):
        assert path in readme, path
        assert (REPO_ROOT / path).exists(), path


def test_every_cited_seed_has_its_reference_in_the_design():
    design = (DOCS / "design.md").read_text()
    table = {m.group(1): m.group(2) for m in re.finditer(r"^\| (00\d) \| (.+?) \|", design, re.M)}
    cited = set()
    for path in list(REPO_ROOT.glob("*/**/*.py")) + list(REPO_ROOT.glob("configs/**/*.yaml")):
        if ".venv" in path.parts:
            continue
        cited.update(re.findall(r"seeds? (00\d)", path.read_text(encoding="utf-8")))
    assert cited and cited <= set(table), cited - set(table)
    for seed in ("000", "003"):  # the two with a venue: authors, journal, year, pages
        assert re.search(r"\d{4}, (vol\. \d+, )?no\. \d+, pp\. \d+-\d+", table[seed]), seed


def test_the_code_cites_documents_that_exist():
    missing = set()
    for path in REPO_ROOT.glob("*/**/*.py"):
        if ".venv" in path.parts:
            continue
        text = path.read_text(encoding="utf-8")
        for doc in re.findall(r"\b(docs/[A-Za-z_]+\.md|[A-Z][A-Z_]+\.md)\b", text):
            if not (REPO_ROOT / doc).exists():
                missing.add((str(path.relative_to(REPO_ROOT)), doc))
    assert not missing, sorted(missing)
