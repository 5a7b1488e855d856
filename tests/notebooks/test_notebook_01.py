"""Notebook 01 (Cartosat-1 sensor models) runs top to bottom, in quick mode
(see conftest.py); one file per notebook, so that xdist's --dist loadfile spreads them over
the workers."""


def test_notebook_01_runs(run_notebook):
    run_notebook("01_cartosat1_sensor_models")
