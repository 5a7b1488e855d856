"""Notebook 03 (full strip, paper 003_): the statements of its text, checked on the numbers it
prints (``NOTEBOOK_RESULTS``), on the run of the test and on the committed run. It has no quick
mode (see conftest.py): both are the same 44-scene strip, so the numbers the text quotes are
checked on both, to the text's rounding."""

import numpy as np

NAME = "03_full_strip"


def check(r: dict) -> None:
    """The text's statements."""
    assert r["n_scenes"] == 44
    # the rule's check, before solving: silent for the respecting layout, warns for the other
    assert r["warnings_respecting"] == 0 and r["warnings_violating"] >= 1, r
    # the vendor RPCs are off by ~15 m (check RMS in planimetry; here within 10-25 m)
    assert 10 < r["direct"]["check_plan_m"] < 25, r["direct"]
    # one by one, the sub-scenes leave gaps of metres at the seams: 1.5 m RMS, 7.6 m at worst
    one = r["one_by_one"]
    assert (round(one["gap_rms_m"], 1), round(one["gap_max_m"], 1)) == (1.5, 7.6), one
    # the two-level adjustment closes them to a fraction of a millimetre ...
    for key in ("respecting", "violating"):
        assert r[key]["gap_max_m"] < 1e-3, (key, r[key])
    # ... at better check-point accuracy than one by one (GCPs respecting the rule)
    assert r["respecting"]["check_plan_m"] < one["check_plan_m"], (r["respecting"], one)
    # violating the rule costs accuracy, over the whole strip and in the bare last third,
    # where the error grows towards the end of the strip (the "curved effect")
    assert r["violating"]["check_plan_m"] > r["respecting"]["check_plan_m"], r
    last = r["after_last_gcp"]
    assert last["violating_m"] > last["respecting_m"], last
    per_scene = np.array(last["violating_per_scene_m"])
    assert np.polyfit(np.arange(len(per_scene)), per_scene, 1)[0] > 0, per_scene
    assert per_scene[-1] == per_scene.max(), per_scene


def test_notebook_03_runs(run_notebook):
    run = run_notebook("03_full_strip")
    check(run.results)


def test_notebook_03_committed_outputs(committed_results):
    check(committed_results(NAME))
