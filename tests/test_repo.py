"""The fresh-machine contract: README's two commands, CI runs the test one, the CLI dispatches."""

import re
import subprocess
import sys

from tests.conftest import REPO


def _readme_commands():
    text = (REPO / "README.md").read_text()
    return re.findall(r"```bash\n(.+?)\n```", text)[:2]


def test_readme_opens_with_demo_and_test_commands():
    demo, tests = _readme_commands()
    assert demo.endswith("jaxgeo demo") and "pip install" in demo
    assert "pytest" in tests and '".[test]"' in tests


def test_ci_runs_exactly_the_readme_test_command():
    _, tests = _readme_commands()
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    assert tests in ci
    assert "set -euo pipefail" in ci


def test_cli_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "jaxgeo.cli", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "COMMAND" in out
    for name in ("demo",):
        assert name in out


def _readme_blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.+?)```", (REPO / "README.md").read_text(), re.S)


def test_readme_is_short_with_python_example_and_cli_chain():
    text = (REPO / "README.md").read_text()
    assert len(text.splitlines()) <= 200, "README.md is for users: 200 lines at most"
    assert any("jaxgeo.adjust(" in block for block in _readme_blocks("python"))
    # the image chain, in one shell block, in the order a user runs it
    chains = [b for b in _readme_blocks("bash") if "jaxgeo match" in b]
    assert chains, "README.md has no shell block with `jaxgeo match`"
    order = [chains[0].index(f"jaxgeo {cmd} ") for cmd in ("match", "adjust", "ortho", "dsm")]
    assert order == sorted(order)
    # the generated results table: two marker lines, and where the rest of the measurements are
    assert text.count("<!-- results table -->") == 2
    assert "benchmarks/README.md" in text


def test_readme_python_example_names_exist():
    """Every ``jaxgeo.NAME`` and ``from jaxgeo.X import NAME`` of README's Python example is
    public API (the example itself ran when it was written; this keeps its names current)."""
    import importlib

    import jaxgeo

    code = next(b for b in _readme_blocks("python") if "jaxgeo.adjust(" in b)
    for name in re.findall(r"\bjaxgeo\.(\w+)\(", code):
        assert hasattr(jaxgeo, name), f"jaxgeo.{name}"
    for module, names in re.findall(r"from (jaxgeo[\w.]*) import ([\w, ]+)", code):
        mod = importlib.import_module(module)
        for name in names.split(","):
            assert hasattr(mod, name.strip()), f"{module}.{name.strip()}"
