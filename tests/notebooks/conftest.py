"""Running the research notebooks top to bottom with nbclient, one test file per notebook
(``test_notebook_NN.py``), so that ``--dist loadfile`` can send them to different xdist workers;
``tests/test_notebooks.py`` checks that each committed ``.ipynb`` is built from its source and
was executed in full.

Each notebook ends by printing its key numbers as one JSON line (``NOTEBOOK_RESULTS {...}``);
each test file checks the statements of the notebook's text against them twice: on the run of
the test (quick mode, below) and on the committed notebook's own outputs (the full run that the
documentation shows, where the numbers quoted in the text are checked too).

The kernel runs in quick mode (``JAXGEO_NOTEBOOK_QUICK=1``): notebooks 01, 02 and 04 run every
cell, every check, on smaller workloads (fewer variants, GCP counts, layouts, Monte-Carlo runs),
as the ``QUICK`` line near the top of each says. ``JAXGEO_NOTEBOOK_QUICK=0 python -m pytest
tests/notebooks`` runs them in full, as ``python notebooks/make_notebooks.py`` does.
Notebook 03 has no quick mode: its time is compilation, which a shorter strip does not shorten.

Almost all of a notebook's time is XLA compilation (one compiled solve per problem structure:
model, bias, number of GCPs), so quick mode leaves out variants, each of which is one more
compiled solve, rather than shrinking problems, which reuse the compiled programs anyway.
"""

import os
import pathlib
import sys
import time
from types import SimpleNamespace

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
NOTEBOOKS = REPO / "notebooks"
QUICK = os.environ.get("JAXGEO_NOTEBOOK_QUICK", "1") != "0"


@pytest.fixture(scope="session")
def make_notebooks():
    """The builder ``notebooks/make_notebooks.py`` (a script, not a package module)."""
    pytest.importorskip("nbformat")
    sys.path.insert(0, str(NOTEBOOKS))
    try:
        import make_notebooks
    finally:
        sys.path.remove(str(NOTEBOOKS))
    return make_notebooks


@pytest.fixture
def run_notebook(make_notebooks, tmp_path):
    """``run_notebook(name)`` builds ``notebooks/{name}.ipynb`` from its source and executes it
    in a fresh kernel as ``make_notebooks`` does (quick mode unless the environment says
    ``JAXGEO_NOTEBOOK_QUICK=0``; an error in any cell fails the test), writes the executed copy
    to ``tmp_path`` for a look, checks that every code cell ran, that the last one printed the
    run time and that a figure came out, and returns ``text`` (all that was printed),
    ``results`` (the ``NOTEBOOK_RESULTS`` line) and ``seconds``."""
    pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    pytest.importorskip("matplotlib")
    import nbformat

    def run(name: str) -> SimpleNamespace:
        nb = make_notebooks.notebook(NOTEBOOKS / "src" / f"{name}.py")
        t = time.perf_counter()
        try:
            make_notebooks.execute(nb, quick=QUICK, cwd=tmp_path, timeout=600)
        finally:
            print(f"{name}: {time.perf_counter() - t:.0f} s")
        nbformat.write(nb, tmp_path / f"{name}.ipynb")  # executed copy
        code = [c for c in nb.cells if c.cell_type == "code"]
        assert code and all(c.execution_count for c in code), f"{name}: a cell did not run"
        text = make_notebooks.printed(nb)
        assert "notebook run time" in text, f"{name}: the last cell printed no run time"
        assert make_notebooks.figures(nb) >= 1, f"{name}: no figure"
        return SimpleNamespace(
            text=text, results=make_notebooks.results(nb), seconds=time.perf_counter() - t
        )

    return run


@pytest.fixture
def committed_results(make_notebooks):
    """``committed_results(name)``: the ``NOTEBOOK_RESULTS`` of the committed (executed)
    ``notebooks/{name}.ipynb``, the run the documentation shows."""
    import nbformat

    def read(name: str) -> dict:
        nb = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
        try:
            return make_notebooks.results(nb)
        except ValueError as e:
            pytest.fail(f"notebooks/{name}.ipynb: {e}: run python notebooks/make_notebooks.py")

    return read
