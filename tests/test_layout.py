"""The package layout is the architecture: every module imports, imports point down only and
private modules stay in their package (import-linter contracts in pyproject.toml), one name means
one thing, and no module grows past 500 lines silently."""

import ast
import collections
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
    assert "Contracts: 2 kept, 0 broken" in run.stdout


# the sub-commands' protocol: every jaxgeo.cli._<command> module has its register and run
PROTOCOL = {"register", "run"}


def test_one_name_for_one_thing():
    """No two public functions or classes of the package share a name (private helpers, ``_x``,
    are their module's own)."""
    where = collections.defaultdict(list)
    for path in sorted((REPO / "jaxgeo").rglob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef | ast.ClassDef) and not node.name.startswith("_"):
                where[node.name].append(str(path.relative_to(REPO)))
    twice = {k: v for k, v in where.items() if len(v) > 1 and k not in PROTOCOL}
    assert not twice, f"names defined more than once: {twice}"


def test_public_packages():
    """The engine and the image products are first-class: attributes of the package, with
    their entry points public."""
    from jaxgeo.lsq import solve, solve_batch  # noqa: F401

    for name in (
        "lsq",
        "bundle",
        "strip",
        "tiles",
        "ortho",
        "stereo",
        "coreg",
        "models",
        "io",
        "simulate",
    ):
        assert isinstance(getattr(jaxgeo, name), types.ModuleType)
    assert callable(jaxgeo.ortho.orthorectify) and callable(jaxgeo.stereo.dsm_from_images)
    assert jaxgeo.SolverConfig is jaxgeo.lsq.SolverConfig


def test_no_module_probes_a_model_with_hasattr():
    """What is asked of a model is declared by its interface (``base_rpc``, ``exact_rpc``...)."""
    found = []
    for path in sorted((REPO / "jaxgeo").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "hasattr":
                found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not found, f"hasattr in the library: {found}"


def test_no_module_over_500_lines_without_a_reason():
    too_long = []
    for path in sorted((REPO / "jaxgeo").rglob("*.py")):
        text = path.read_text()
        n = text.count("\n")
        if n > MAX_LINES and REASON_MARK not in text[:2000]:
            too_long.append(f"{path.relative_to(REPO)} ({n} lines)")
    assert not too_long, f"modules over {MAX_LINES} lines without a reason at the top: {too_long}"


PACKAGES = sorted(
    p.parent.name for p in (REPO / "jaxgeo").glob("[!_]*/__init__.py") if p.parent.name != "cli"
)


def _reexports(path: pathlib.Path) -> set[str]:
    """The names a module re-exports one by one (``from ._x import y as y``)."""
    return {
        alias.asname
        for node in ast.parse(path.read_text()).body
        if isinstance(node, ast.ImportFrom) and node.level == 1
        for alias in node.names
        if alias.asname == alias.name
    }


@pytest.mark.parametrize("package", PACKAGES)
def test_public_api_is_what_the_init_reexports(package):
    """A package's public names are exactly the names its ``__init__`` re-exports from its
    private modules (nothing leaks from an import), and none is also in its ``internal`` module."""
    module = importlib.import_module(f"jaxgeo.{package}")
    public = {
        n
        for n in vars(module)
        if not n.startswith("_") and not isinstance(getattr(module, n), types.ModuleType)
    }
    assert public == _reexports(REPO / "jaxgeo" / package / "__init__.py")
    internal = REPO / "jaxgeo" / package / "internal.py"
    if internal.exists():
        assert not public & _reexports(internal), public & _reexports(internal)


@pytest.mark.parametrize(
    "package", [p for p in PACKAGES if (REPO / "jaxgeo" / p / "internal.py").exists()]
)
def test_internal_names_serve_other_packages(package):
    """``jaxgeo.<package>.internal`` holds the stages other jaxgeo packages use, not the user API:
    each of its names is imported by another package of jaxgeo (else it is private to its module,
    or public)."""
    names = _reexports(REPO / "jaxgeo" / package / "internal.py")
    used = set()
    for path in (REPO / "jaxgeo").rglob("*.py"):
        if path.is_relative_to(REPO / "jaxgeo" / package):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").endswith(
                f"{package}.internal"
            ):
                used |= {a.name for a in node.names}
    assert names <= used, f"jaxgeo.{package}.internal: not used by another package: {names - used}"


def test_raster_io_goes_through_io():
    """Every raster jaxgeo opens or writes is opened by :mod:`jaxgeo.io` (one place for GDAL's
    options): no ``rasterio.open`` outside it."""
    found = []
    for path in sorted((REPO / "jaxgeo").rglob("*.py")):
        if path.is_relative_to(REPO / "jaxgeo" / "io"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and ast.unparse(node.func) == "rasterio.open":
                found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not found, f"rasterio.open outside jaxgeo.io: {found}"
