"""The documentation site builds without a warning (``mkdocs build --strict``): every API page
resolves, every link and notebook in the navigation exists. Skipped where the ``docs`` extra is
not installed."""

import os
import pathlib
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
    "bundle": ("adjust", "AdjustResult", "prepare", "snoop", "make_result"),
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
