"""The documentation site builds without a warning (``mkdocs build --strict``): every API page
resolves, every link and notebook in the navigation exists, the CLI reference names every
command, option and exit code. Skipped where the ``docs`` extra is not installed."""

import argparse
import os
import pathlib
import re
import subprocess
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]

# API page -> names its rendered HTML must show (one per package at least: the page resolved)
API_NAMES = {
    "jaxgeo": ("adjust", "read_rpc", "RPC"),
    "models": ("AbstractSensorModel", "Biased", "AffineBias", "localize_on_dem"),
    "lsq": ("solve", "solve_batch", "Problem", "SolverConfig", "Solution", "RESULTS"),
    "intersect": ("intersect", "IntersectResult"),
    "io": ("read_rpc", "read_dem", "read_observations"),
    "bundle": ("adjust", "AdjustResult", "prepare", "adjust_files", "AdjustSettings"),
    "strip": ("adjust_strip", "StripConfig"),
    "ortho": ("orthorectify", "OrthoReport"),
    "stereo": ("dsm_from_images", "stereo_pair", "DSMGrid"),
    "simulate": ("cartosat1_stereo", "demo_dir"),
    "tiles": ("run_tiles", "plan_tiles", "TilePlan"),
}
# the public packages with a "::: public" page (intersect is a module: plain ":::")
PUBLIC_PAGES = (
    "models",
    "lsq",
    "io",
    "bundle",
    "strip",
    "ortho",
    "stereo",
    "coreg",
    "simulate",
    "tiles",
    "report",
)


def _hooks():
    sys.path.insert(0, str(REPO / "docs"))
    try:
        import hooks
    finally:
        sys.path.remove(str(REPO / "docs"))
    return hooks


def test_mkdocs_build_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    pytest.importorskip("mkdocs_jupyter")
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        env={"NO_MKDOCS_2_WARNING": "1", **os.environ},
    )
    assert out.returncode == 0, out.stderr[-4000:]
    for page, names in API_NAMES.items():
        html = (tmp_path / "site" / "api" / page / "index.html").read_text()
        missing = [n for n in names if f'id="{_anchor(page, n)}"' not in html]
        assert not missing, f"api/{page}.md does not render {missing}"
    for name in ("01_cartosat1_sensor_models", "04_differentiable"):
        assert (tmp_path / "site" / "notebooks" / name / "index.html").exists()
    check_cli_reference((tmp_path / "site" / "cli" / "index.html").read_text())


def cli_parsers():
    """``(command line, parser)`` of every command and sub-command, walked from the parsers
    here (not by the docs hook)."""
    from jaxgeo.cli import COMMANDS, build_parser

    out = []

    def walk(path, parser):
        out.append((path, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(f"{path} {name}", sub)

    for name in COMMANDS:
        top = build_parser(name)
        walk(f"jaxgeo {name}", top._subparsers._group_actions[0].choices[name])
    return out


def check_cli_reference(html: str) -> None:
    """The built CLI reference names every command and sub-command (a heading), every option
    and positional of every parser with its help, every non-trivial default, and every exit
    code of each command."""
    import html as html_

    # sections: from one heading <h2|h3 id=...>TITLE<a class="headerlink" ...></h.> to the next
    parts = re.split(r"<h[23] id=\"[^\"]*\">(.*?)</h[23]>", html)
    by_path = {
        html_.unescape(re.sub(r"<a class=\"headerlink\".*?</a>|<[^>]+>", "", title)).strip(): body
        for title, body in zip(parts[1::2], parts[2::2], strict=True)
    }
    parsers = cli_parsers()
    assert len(parsers) > len(__import__("jaxgeo.cli").cli.COMMANDS)  # simulate's kinds too
    for path, parser in parsers:
        assert path in by_path, f"the CLI reference has no section {path!r}"
        section = by_path[path]
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            names = action.option_strings or [action.metavar or action.dest]
            for name in names:
                assert f"<code>{name}" in section, f"{path}: {name} missing"
            words = " ".join(action.help.split()).split(" (default")[0][:30]
            assert html_.escape(words, quote=False) in section.replace("\\", ""), (path, words)
            default = action.default
            if isinstance(default, (int, float, str)) and not isinstance(default, bool):
                assert f"<code>{html_.escape(str(default))}</code>" in section, (path, names)
        status = (parser.epilog or "").partition("exit status:")[2].split("\n\n")[0]
        codes = re.findall(r"^\s+(\d+)\s", status, re.M)
        assert codes or path.count(" ") == 2, f"{path}: no exit codes"
        for code in codes:
            assert f"<td>{code}</td>" in section, f"{path}: exit code {code} missing"


def _anchor(page: str, name: str) -> str:
    """The HTML id mkdocstrings gives a documented name: its qualified path as rendered. The
    hook documents a re-exported name under its defining private module, so look the target
    up there."""
    module = "jaxgeo" if page == "jaxgeo" else f"jaxgeo.{page}"
    if page == "intersect":
        return f"jaxgeo.intersect.{name}"
    targets = dict((n, t) for t, n in _hooks().public_names(module))
    return targets[name]


def test_api_pages_cover_the_public_namespaces():
    hooks = _hooks()
    names = {n for _, n in hooks.public_names("jaxgeo")}
    assert {"adjust", "RPC", "read_rpc", "KeplerSequence", "SolverConfig"} <= names
    for module in PUBLIC_PAGES:
        page = (REPO / "docs" / "api" / f"{module}.md").read_text()
        assert f"::: public jaxgeo.{module}" in page
        assert hooks.public_names(f"jaxgeo.{module}"), module
    assert "::: jaxgeo.intersect" in (REPO / "docs" / "api" / "intersect.md").read_text()
    # every public package of jaxgeo has a page, and every page is in the navigation
    packages = {p.parent.name for p in (REPO / "jaxgeo").glob("[!_]*/__init__.py")} - {"cli"}
    assert packages <= set(PUBLIC_PAGES), packages - set(PUBLIC_PAGES)
    nav = (REPO / "mkdocs.yml").read_text()
    for page in (*PUBLIC_PAGES, "jaxgeo", "intersect"):
        assert f"api/{page}.md" in nav, page
    for name, page in (("solve", "lsq"), ("orthorectify", "ortho"), ("dsm_from_images", "stereo")):
        assert name in {n for _, n in hooks.public_names(f"jaxgeo.{page}")}
