"""Notebook 04 (differentiable adjustment) runs top to bottom, in quick mode
(see conftest.py); one file per notebook, so that xdist's --dist loadfile spreads them over
the workers."""

import re


def test_notebook_04_runs(run_notebook):
    text = run_notebook("04_differentiable")
    # the gradient of the check RMS w.r.t. a GCP's position against central finite differences:
    # at the small step (0.05 m) within 1e-4 relative (issue 14), for height and east
    small = re.findall(r"\(h = 0\.05 m\).*relative difference ([0-9.e+-]+)", text)
    assert len(small) == 2, text[-2000:]
    assert all(float(r) < 1e-4 for r in small), small
