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
