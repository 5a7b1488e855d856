"""The ``jaxgeo`` entry point: ``--version`` from the package metadata, and a lazy CLI
(``--help`` and ``--version`` import no sub-command and not jax)."""

import importlib.metadata
import subprocess
import sys

import pytest

from jaxgeo.cli import COMMANDS, main

LAZY = """
import contextlib, io, sys
from jaxgeo.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        main([{flag!r}])
    except SystemExit as e:
        assert e.code == 0, e.code
heavy = sorted(m for m in sys.modules if m == "jax" or m.startswith(("jax.", "jaxgeo.strip",
               "jaxgeo.bundle", "jaxgeo.models", "jaxgeo.cli."))
               and m != "jaxgeo.cli._common")  # the shared option helpers: no sub-command
print(out.getvalue())
print("HEAVY", heavy)
"""


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_and_version_do_not_import_jax(flag):
    run = subprocess.run(
        [sys.executable, "-c", LAZY.format(flag=flag)], capture_output=True, text=True, check=True
    )
    assert run.stdout.rstrip().splitlines()[-1] == "HEAVY []", run.stdout
    if flag == "--help":
        assert all(name in run.stdout for name in COMMANDS)


def test_version_from_package_metadata(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"jaxgeo {importlib.metadata.version('jaxgeo')}"


def test_subcommand_help_names_its_options(capsys):
    with pytest.raises(SystemExit):
        main(["strip", "--help"])
    out = capsys.readouterr().out
    assert "--ties-per-pair" in out and "shift-drift" in out and "--degree" in out


UNINSTALLED = """
import importlib.metadata as md
real = md.version
def version(name):  # a source tree on sys.path: no jaxgeo metadata
    if name == "jaxgeo":
        raise md.PackageNotFoundError(name)
    return real(name)
md.version = version
import jaxgeo
from jaxgeo.cli import main
print(jaxgeo.__version__)
main(["--version"])
"""


def test_a_source_tree_without_metadata_imports_and_says_so():
    run = subprocess.run([sys.executable, "-c", UNINSTALLED], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.splitlines() == ["unknown (not installed)", "jaxgeo unknown (not installed)"]


def test_entry_exits_with_the_status_the_collector_tuned_and_objects_frozen(monkeypatch):
    """``jaxgeo`` (:func:`jaxgeo.cli.entry`): exits with the command's status; the command ran
    under ``GC_THRESHOLD`` and its objects are frozen before the interpreter's teardown."""
    import gc

    import jaxgeo.cli as cli

    seen = []
    monkeypatch.setattr(
        cli, "_main", lambda argv, restore_handlers: seen.append(gc.get_threshold()) or 3
    )
    before = gc.get_threshold()
    try:
        with pytest.raises(SystemExit) as exc:
            cli.entry()
        assert exc.value.code == 3 and seen == [cli.GC_THRESHOLD]
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)


def test_help_names_every_command_simulates_kinds_and_the_conventions_page(capsys):
    """``jaxgeo --help``: one line per command; ``simulate``'s line names its kinds (the
    stereo scene was missing); the epilog points to the conventions and exit codes."""
    import argparse
    import re

    from jaxgeo.cli import build_parser
    from jaxgeo.cli._common import CONVENTIONS_PAGE

    with pytest.raises(SystemExit):
        main(["--help"])
    out = re.sub(r"-\s*\n\s*", "-", capsys.readouterr().out)  # (argparse wraps at hyphens)
    out = " ".join(out.split())
    simulate = build_parser("simulate")._subparsers._group_actions[0].choices["simulate"]
    kinds = next(a for a in simulate._actions if isinstance(a, argparse._SubParsersAction))
    assert set(kinds.choices) == {"cartosat1", "carto2s-strip", "stereo-scene"}
    for name in (*COMMANDS, *kinds.choices):
        assert name in out, name
    assert f"conventions and exit codes: {CONVENTIONS_PAGE}" in out and "docs/cli.md" in out
