"""The package layout is the architecture: every module imports as a module, imports point down
only (import-linter contract in pyproject.toml), and no module grows past 500 lines silently."""

import importlib
import pathlib
import pkgutil
import subprocess
import sys
import types

import pytest

import jaxgeo
from tests.conftest import REPO

MAX_LINES = 500
REASON_MARK = "Longer than 500 lines because"


def _modules() -> list[str]:
    names = ["jaxgeo"]
    for info in pkgutil.walk_packages(jaxgeo.__path__, prefix="jaxgeo."):
        if not info.name.endswith(".__main__"):  # runs the program when imported
            names.append(info.name)
    return names


@pytest.mark.parametrize("name", _modules())
def test_every_module_imports_as_a_module(name):
    module = importlib.import_module(name)
    assert isinstance(module, types.ModuleType)
    # no function or class re-exported under a package's attribute shadows a submodule of it
    parent, _, leaf = name.rpartition(".")
    if parent:
        assert isinstance(getattr(importlib.import_module(parent), leaf), types.ModuleType), (
            f"{parent}.{leaf} is shadowed by a non-module attribute"
        )


def test_imports_point_down_only():
    """``lint-imports`` checks the layers contract of pyproject.toml ([tool.importlinter])."""
    exe = pathlib.Path(sys.executable).parent / "lint-imports"  # installed by the test extra
    run = subprocess.run(
        [str(exe), "--config", str(REPO / "pyproject.toml"), "--no-cache"],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Contracts: 1 kept, 0 broken" in run.stdout or " KEPT" in run.stdout


def test_no_module_over_500_lines_without_a_reason():
    too_long = []
    for path in sorted((REPO / "jaxgeo").rglob("*.py")):
        text = path.read_text()
        n = text.count("\n")
        if n > MAX_LINES and REASON_MARK not in text[:2000]:
            too_long.append(f"{path.relative_to(REPO)} ({n} lines)")
    assert not too_long, f"modules over {MAX_LINES} lines without a reason at the top: {too_long}"
