"""benchmarks/speed/strip.py: the peers' problem dict is jaxgeo's level-1 problem (same cost at the
start and at jaxgeo's solution), and the peers reach jaxgeo's solution to 1e-6 px.

(Not named test_strip.py: tests/cli/test_strip.py has that basename, and the test directories
are not packages.)"""

import warnings

import numpy as np
import pytest

from benchmarks.peers import strip as sp
from benchmarks.speed import strip as sb


@pytest.fixture(scope="module")
def case():
    from jaxgeo.simulate import carto2s_strip
    from jaxgeo.strip import Strip, StripConfig, TieConfig, adjust_strip

    strip = Strip.from_simulation(carto2s_strip(4, seed=1))
    with warnings.catch_warnings():  # level 2 (not compared here) on 2 GCP scenes
        warnings.filterwarnings("ignore", message=".*universal correction")
        config = StripConfig(ties=TieConfig(per_pair=10), solver=sb.least_squares_solver())
        res = adjust_strip(strip, config)
    return res, sb.problem_dict(res)


def test_problem_dict_is_the_level1_problem(case):
    res, problem = case
    setup = res.setup
    assert [setup.image_index[n][1] for n in problem["names"]] == [0, 1, 2, 3]
    assert len(problem["points0"]) == len(setup.point_ids)
    assert len(problem["obs_scene"]) == len(res.inputs.observations.point_ids)
    assert np.all(problem["bias0"] == 0.0)
    # every level-1 ground observation has an observed axis: GCPs and tie height priors
    n_gcp = len(res.inputs.ground.ids) - len(res.inputs.tie_ids)
    assert len(problem["gcp_point"]) == n_gcp + len(res.inputs.tie_ids)
    assert np.isfinite(problem["gcp_sigma_m"]).sum() == 3 * n_gcp + len(res.inputs.tie_ids)
    costs = sb.check_costs(res, problem)
    assert abs(costs["cost_rel_diff_initial"]) < 1e-9
    # at the solution the residuals are ~s0: exact ENU (jaxgeo) vs ENU linearised at each
    # observed point (peers) differ at second order (measured ~1e-9)
    assert abs(costs["cost_rel_diff_solution"]) < 1e-7
    assert abs(costs["jaxgeo_reported_cost_rel"]) < 1e-7


def test_ground_residuals_match_jaxgeo_row_by_row(case):
    res, problem = case
    bias, points = sb.jaxgeo_solution(res)
    r = sp.residuals(problem, bias, points)[2 * len(problem["obs_scene"]) :]
    mine = np.asarray(res.solution.level1.residuals_ground)
    weight = np.asarray(res.setup.problem.ground.weight)
    want = mine[(weight > 0).any(axis=1)][np.isfinite(problem["gcp_sigma_m"])]
    # exact ENU about the observed point vs its linearisation: the up axis of a tie moved
    # ~20 m horizontally differs by the Earth's curvature, d^2 / 2R ~ 3e-5 m (6e-8 sigma)
    np.testing.assert_allclose(r, want, rtol=0, atol=1e-6)
    # one ENU linearisation for the whole strip (no gcp_scale) is a different problem
    one_origin = {k: v for k, v in problem.items() if k != "gcp_scale"}
    r1 = sp.residuals(one_origin, bias, points)[2 * len(problem["obs_scene"]) :]
    assert np.abs(r1 - want).max() > 1e-3 * np.abs(want).max()


def test_scipy_reaches_jaxgeo_solution(case):
    res, problem = case
    out = sb.compare_peers(res, problem, ["scipy-analytic"], max_nfev=200, jaxgeo_s=1.0)
    assert out["scipy_analytic_status"] > 0
    assert out["scipy_analytic_vs_jaxgeo_px_max"] < 1e-6
    assert abs(out["scipy_analytic_cost_rel_to_jaxgeo"]) < 1e-7


def test_ceres_reaches_jaxgeo_solution(case):
    pytest.importorskip("pyceres")  # optional peer (`bench` extra)
    res, problem = case
    out = sb.compare_peers(res, problem, ["ceres"], max_nfev=200, jaxgeo_s=1.0)
    assert out["ceres_status"] == "CONVERGENCE"
    assert out["ceres_vs_jaxgeo_px_max"] < 1e-6
