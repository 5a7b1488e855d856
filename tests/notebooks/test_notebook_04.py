"""Notebook 04 (differentiable adjustment): the statements of its text, checked on the numbers
it prints (``NOTEBOOK_RESULTS``), on a quick run (see conftest.py) and on the committed full
run.

Quick mode draws 20 random GCP layouts instead of 200 and runs 100 Monte-Carlo draws instead
of 1000; the gradient check and the gradient descent are the same. The Monte-Carlo bounds
follow from the number of runs N: an empirical standard deviation from N draws is uncertain by
sigma_N = 1 / sqrt(2 (N - 1)) (relative; 7.1 % for 100 runs, 2.2 % for 1000), so the mean ratio
empirical / predicted over the check points must lie within 3 sigma_N of 1, and every single
point's within 5 sigma_N (the largest of 180 such deviations is ~3 sigma_N)."""

import math

NAME = "04_differentiable"


def check(r: dict) -> None:
    """The text's statements, on a quick or a full run's results."""
    assert r["adjusted"]["converged"], r["adjusted"]

    # the gradient through the solve against central differences: the difference is O(h^2),
    # so it shrinks 100x from h = 0.5 m to 0.05 m (within 20 %), and is below 1e-4 at 0.05 m
    g = r["gradient_check"]
    for axis in ("height", "east"):
        small, large = g[f"{axis} h=0.05"], g[f"{axis} h=0.5"]
        assert small < 1e-4, g
        assert 80 < large / small < 125, g

    # GCP placement: from a start bunched in the middle (every corner more than half the
    # overlap's side from its nearest GCP), the gradient spreads the GCPs to the corners: three
    # end about a tenth of the side from one (here: at most 0.12), the fourth about a third
    # (here: at most 0.4; on an edge, still moving); the result is within 2 % of the regular
    # corner layout and better than the best random one
    p = r["placement"]
    assert min(p["corner_gap_start"]) > 0.5, p
    gaps = sorted(p["corner_gap_optimised"])
    assert max(gaps[:3]) < 0.12 and gaps[3] < 0.4, p
    assert p["optimised_m"] < p["regular_m"] * 1.02, p
    assert p["optimised_m"] < p["random_best_m"] <= p["random_median_m"], p
    assert p["optimised_m"] < p["start_m"] / 4, p

    # the covariance of the adjustment predicts the Monte-Carlo accuracy (bounds: docstring)
    mc = r["monte_carlo"]
    assert mc["converged"] == mc["runs"], mc
    sigma_n = 1 / math.sqrt(2 * (mc["runs"] - 1))
    for i in range(3):  # east, north, height
        assert abs(mc["ratio_mean"][i] - 1) < 3 * sigma_n, mc
        assert 1 - 5 * sigma_n < mc["ratio_min"][i] <= mc["ratio_max"][i] < 1 + 5 * sigma_n, mc
        ratio_rms = mc["empirical_rms_m"][i] / mc["predicted_rms_m"][i]
        assert abs(ratio_rms - 1) < 3 * sigma_n, mc


def test_notebook_04_runs(run_notebook):
    run = run_notebook("04_differentiable")
    check(run.results)


def test_notebook_04_committed_outputs(committed_results):
    r = committed_results(NAME)
    assert r["quick"] is False  # the documentation shows the full run
    assert r["placement"]["n_random"] == 200 and r["monte_carlo"]["runs"] == 1000, r
    check(r)
    # the numbers quoted in the text (as it rounds them)
    mc = r["monte_carlo"]
    assert all(0.985 <= v < 1.005 for v in mc["ratio_mean"]), mc  # 0.99-1.00
    assert 0.945 <= min(mc["ratio_min"]) and max(mc["ratio_max"]) < 1.075, mc  # 0.95-1.07
