"""Notebook 03 (full strip) runs top to bottom (in full: it has no quick mode, see
conftest.py); one file per notebook, so that xdist's --dist loadfile spreads them over the
workers."""


def test_notebook_03_runs(run_notebook):
    text = run_notebook("03_full_strip")
    assert "paper" in text  # its results are printed against the paper's findings
