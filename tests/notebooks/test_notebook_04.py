"""Notebook 04 (differentiable adjustment) runs top to bottom, in quick mode
(see conftest.py); one file per notebook, so that xdist's --dist loadfile spreads them over
the workers."""


def test_notebook_04_runs(run_notebook):
    run_notebook("04_differentiable")
