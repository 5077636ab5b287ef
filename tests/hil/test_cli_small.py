"""Small things of the command line: --version, scenarios by name, help texts with examples."""

from __future__ import annotations

import tomllib

import pytest

from hil.cli import main
from hil.config import REPO_ROOT, SCENARIO_DIR
from hil.run import scenario_path


def test_version_is_the_package_version(capsys):
    assert main(["--version"]) == 0
    want = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert capsys.readouterr().out == f"hil {want}\n"


def test_scenarios_are_found_by_name_like_vehicles():
    assert scenario_path("S000-stuck") == SCENARIO_DIR / "S000-stuck.yaml"
    f = SCENARIO_DIR / "REC-stuck.yaml"
    assert scenario_path(str(f)) == f


def test_an_unknown_scenario_name_lists_the_names(capsys):
    assert main(["run", "S999-none"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: hil run: SCENARIO: expected a scenario file or one of [")
    assert "'S000-stuck'" in err and err.endswith("got 'S999-none'\n")


@pytest.mark.parametrize("cmd", ["run", "up", "fault", "bench"])
def test_help_has_a_description_and_examples(cmd, capsys):
    assert main([cmd, "--help"]) == 0
    out = capsys.readouterr().out
    usage, _, rest = out.partition("\n\n")
    assert rest.split("\n")[0].strip(), "a one-line description after the usage"
    assert "\nexamples:\n" in out and f"  hil {cmd} " in out
