"""Each research notebook ``notebooks/NN_*.ipynb`` is what ``notebooks/make_notebooks.py`` builds
from its source in ``notebooks/src/``, and each has a test that runs it top to bottom
(``tests/notebooks/test_notebook_NN.py``, one file per notebook so that ``--dist loadfile``
spreads them over the xdist workers; quick mode, see ``tests/notebooks/conftest.py``), so they
cannot rot."""

import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = REPO / "notebooks"
NAMES = sorted(p.stem for p in (NOTEBOOKS / "src").glob("[0-9][0-9]_*.py"))

nbformat = pytest.importorskip("nbformat")


def test_four_notebooks():
    assert NAMES == [
        "01_cartosat1_sensor_models",
        "02_kepler_rotation_orders",
        "03_full_strip",
        "04_differentiable",
    ]


@pytest.mark.parametrize("name", NAMES)
def test_notebook_has_a_run_test(name):
    test = REPO / "tests" / "notebooks" / f"test_notebook_{name[:2]}.py"
    assert test.is_file(), f"no test runs notebooks/{name}.ipynb"
    assert f'run_notebook("{name}")' in test.read_text()


@pytest.mark.parametrize("name", NAMES)
def test_notebook_is_built_from_its_source(name):
    sys.path.insert(0, str(NOTEBOOKS))
    try:
        import make_notebooks
    finally:
        sys.path.remove(str(NOTEBOOKS))
    ipynb = (NOTEBOOKS / f"{name}.ipynb").read_text()
    assert ipynb == make_notebooks.render(NOTEBOOKS / "src" / f"{name}.py"), (
        f"notebooks/{name}.ipynb is out of date: run python notebooks/make_notebooks.py"
    )
