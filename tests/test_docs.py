"""The documentation site builds without a warning (``mkdocs build --strict``): every API page
resolves, every link and notebook in the navigation exists. Skipped where the ``docs`` extra is
not installed."""

import pathlib
import subprocess
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]


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
        env={"NO_MKDOCS_2_WARNING": "1", **__import__("os").environ},
    )
    assert out.returncode == 0, out.stderr[-4000:]
    api = (tmp_path / "site" / "api" / "bundle" / "index.html").read_text()
    assert "AdjustResult" in api and "SolverConfig" in api  # the re-exported names are rendered
    for name in ("01_cartosat1_sensor_models", "04_differentiable"):
        assert (tmp_path / "site" / "notebooks" / name / "index.html").exists()


def test_api_pages_cover_the_public_namespaces():
    sys.path.insert(0, str(REPO / "docs"))
    try:
        import hooks
    finally:
        sys.path.remove(str(REPO / "docs"))
    names = {n for _, n in hooks.public_names("jaxgeo")}
    assert {"adjust", "RPC", "read_rpc", "KeplerSequence"} <= names
    for module in ("models", "io", "bundle", "strip", "simulate"):
        page = (REPO / "docs" / "api" / f"{module}.md").read_text()
        assert f"::: public jaxgeo.{module}" in page
        assert hooks.public_names(f"jaxgeo.{module}"), module
    assert "::: jaxgeo.intersect" in (REPO / "docs" / "api" / "intersect.md").read_text()
