"""Each research notebook ``notebooks/NN_*.ipynb`` is what ``notebooks/make_notebooks.py`` builds
from its source in ``notebooks/src/`` (its code and markdown cells), executed in full: the
documentation site renders the committed notebooks as they are, so each must carry the outputs,
tables and figures of one run. Each also has a test that runs it top to bottom and checks the
statements of its text against the numbers it prints (``tests/notebooks/test_notebook_NN.py``,
one file per notebook so that ``--dist loadfile`` spreads them over the xdist workers; quick
mode, see ``tests/notebooks/conftest.py``), so they cannot rot."""

import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = REPO / "notebooks"
NAMES = sorted(p.stem for p in (NOTEBOOKS / "src").glob("[0-9][0-9]_*.py"))
REBUILD = "run python notebooks/make_notebooks.py"

nbformat = pytest.importorskip("nbformat")


@pytest.fixture(scope="module")
def make_notebooks():
    sys.path.insert(0, str(NOTEBOOKS))
    try:
        import make_notebooks
    finally:
        sys.path.remove(str(NOTEBOOKS))
    return make_notebooks


def committed(name):
    return nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)


def test_six_notebooks():
    assert NAMES == [
        "01_cartosat1_sensor_models",
        "02_kepler_rotation_orders",
        "03_full_strip",
        "04_differentiable",
        "05_what_no_peer_has",
        "06_ventoux_real_images",
    ]


@pytest.mark.parametrize("name", NAMES)
def test_notebook_has_a_run_test(name):
    test = REPO / "tests" / "notebooks" / f"test_notebook_{name[:2]}.py"
    assert test.is_file(), f"no test runs notebooks/{name}.ipynb"
    text = test.read_text()
    assert f'run_notebook("{name}")' in text
    assert "committed_results(NAME)" in text and f'NAME = "{name}"' in text


@pytest.mark.parametrize("name", NAMES)
def test_notebook_is_built_from_its_source(name, make_notebooks):
    """The cells (type, id, source) are the source's; outputs are not compared."""
    built = make_notebooks.notebook(NOTEBOOKS / "src" / f"{name}.py")
    assert make_notebooks.cell_sources(committed(name)) == make_notebooks.cell_sources(built), (
        f"notebooks/{name}.ipynb is out of date: {REBUILD} (or, for a change of the prose "
        f"only, python notebooks/make_notebooks.py --keep-outputs)"
    )


def test_render_is_deterministic(make_notebooks):
    source = NOTEBOOKS / "src" / f"{NAMES[0]}.py"
    assert make_notebooks.render(source) == make_notebooks.render(source)
    nb = nbformat.reads(make_notebooks.render(source), as_version=4)
    assert not any(c.get("outputs") for c in nb.cells)  # render() gives no outputs


@pytest.mark.parametrize("name", NAMES)
def test_notebook_is_executed_with_a_figure(name, make_notebooks):
    """Executed top to bottom in one kernel (execution counts 1, 2, ...), no error, something
    printed, at least one figure (PNG), and its results line from the full run (quick mode is
    for the tests only)."""
    nb = committed(name)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    counts = [c.execution_count for c in code]
    assert counts == list(range(1, len(code) + 1)), f"notebooks/{name}.ipynb: not run: {REBUILD}"
    outputs = [o for c in code for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"], name
    assert make_notebooks.printed(nb).strip(), f"notebooks/{name}.ipynb: no output"
    assert make_notebooks.figures(nb) >= 1, f"notebooks/{name}.ipynb: no figure"
    assert make_notebooks.results(nb).get("quick", False) is False, (
        f"notebooks/{name}.ipynb was run in quick mode: {REBUILD}"
    )
    assert nb.metadata["kernelspec"]["name"] == "python3", nb.metadata["kernelspec"]
