"""Notebook 01 (Cartosat-1 sensor models) runs top to bottom, in quick mode
(see conftest.py); one file per notebook, so that xdist's --dist loadfile spreads them over
the workers."""


def test_notebook_01_runs(run_notebook):
    text = run_notebook("01_cartosat1_sensor_models")
    assert "paper" in text  # the tables print the paper's values beside jaxgeo's
