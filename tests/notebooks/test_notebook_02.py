"""Notebook 02 (Kepler rotation orders) runs top to bottom, in quick mode
(see conftest.py); one file per notebook, so that xdist's --dist loadfile spreads them over
the workers."""


def test_notebook_02_runs(run_notebook):
    text = run_notebook("02_kepler_rotation_orders")
    assert "paper" in text  # the tables print the paper's values beside jaxgeo's
