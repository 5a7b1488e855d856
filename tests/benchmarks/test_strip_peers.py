"""The strip-benchmark peers (benchmarks/peers/strip.py): model checked against jaxgeo, and
scipy and Ceres converging to the same minimum, which recovers the injected biases."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from benchmarks.peers import strip as sp
from benchmarks.peers.strip_synth import make_problem
from jaxgeo import RPC, AffineBias, Biased
from jaxgeo.geodesy import geodetic_to_enu

GEOM = "phr_ventoux__left_image.geom"


@pytest.fixture(scope="module")
def problem(real_data):
    return sp.validate(make_problem(4, 10, seed=1, rpc_path=real_data / GEOM))


def _biased_model(problem, s, bias6):
    rpc = RPC(*(problem[k][s] for k in ("num", "den", "ground_offset", "ground_scale",
                                        "image_offset", "image_scale")))  # fmt: skip
    return Biased(rpc, AffineBias(shift_px=bias6[:2], matrix=jnp.reshape(bias6[2:], (2, 2))))


def test_projection_matches_jaxgeo(problem):
    bias = problem["bias_true"] * 50.0  # shifts ~150 px, matrix ~1e-3: far from identity
    for s in range(len(problem["num"])):
        ground = problem["points_true"][problem["obs_point"][problem["obs_scene"] == s]]
        want = np.asarray(_biased_model(problem, s, jnp.asarray(bias[s])).project(ground))
        got = sp.project_biased(problem, s, ground, bias)
        assert np.abs(got - want).max() < 1e-9
        got_rpc = sp.rpc_project(problem, s, ground)
        want_rpc = np.asarray(_biased_model(problem, s, jnp.zeros(6)).model.project(ground))
        assert np.abs(got_rpc - want_rpc).max() < 1e-9


def test_jacobian_matches_autodiff(problem):
    bias, points = problem["bias_true"] * 50.0, problem["points_true"]
    jac = sp.jacobian(problem, bias, points).toarray()
    n_bias = bias.size
    for m in (0, 7, len(problem["obs_scene"]) - 1):
        s, i = problem["obs_scene"][m], problem["obs_point"][m]

        def f(b6, g, s=s, sigma=problem["obs_sigma"][m]):
            return _biased_model(problem, s, b6).project(g) / sigma

        d_bias, d_ground = jax.jacfwd(f, argnums=(0, 1))(
            jnp.asarray(bias[s]), jnp.asarray(points[i])
        )
        rows = jac[2 * m : 2 * m + 2]
        np.testing.assert_allclose(rows[:, 6 * s : 6 * s + 6], d_bias, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(
            rows[:, n_bias + 3 * i : n_bias + 3 * i + 3], d_ground, rtol=1e-9, atol=1e-9
        )
        assert np.count_nonzero(rows) <= 18  # nothing outside the two blocks
    # the analytic Jacobian's pattern is exactly the declared sparsity
    pattern = sp.jac_sparsity(problem).toarray() != 0
    assert np.all(pattern[jac != 0])
    n_img = 2 * len(problem["obs_scene"])
    assert pattern.sum() == 9 * n_img + (jac.shape[0] - n_img)  # 9 per image row, 1 per ground row


def test_ceres_cost_functions_match_vectorised(problem):
    pytest.importorskip(
        "pyceres"
    )  # optional peer (`bench` extra), the vectorised model is tested above
    from benchmarks.peers.strip_ceres import ImageCost as image_cost

    bias, points = problem["bias_true"] * 50.0, problem["points_true"]
    r_all = sp.residuals(problem, bias, points)
    jac = sp.jacobian(problem, bias, points).toarray()
    n_bias = bias.size
    for m in (0, 5, len(problem["obs_scene"]) - 1):
        s, i = problem["obs_scene"][m], problem["obs_point"][m]
        cost = image_cost(problem, s, m)
        r, j = np.zeros(2), [np.zeros(12), np.zeros(6)]
        assert cost.Evaluate([bias[s].copy(), points[i].copy()], r, j)
        np.testing.assert_allclose(r, r_all[2 * m : 2 * m + 2], rtol=1e-12, atol=1e-9)
        rows = jac[2 * m : 2 * m + 2]
        np.testing.assert_allclose(j[0].reshape(2, 6), rows[:, 6 * s : 6 * s + 6], rtol=1e-12)
        np.testing.assert_allclose(
            j[1].reshape(2, 3), rows[:, n_bias + 3 * i : n_bias + 3 * i + 3], rtol=1e-10
        )
        r_only = np.zeros(2)
        assert cost.Evaluate([bias[s].copy(), points[i].copy()], r_only, None)
        np.testing.assert_allclose(r_only, r, rtol=1e-13)  # other summation order


def test_enu_scale_is_the_enu_jacobian(problem):
    origin = problem["origin"]
    d = np.asarray(jax.jacfwd(geodetic_to_enu)(jnp.asarray(origin), jnp.asarray(origin)))
    np.testing.assert_allclose(np.diag(d), sp.enu_scale(origin), rtol=1e-12)
    assert np.abs(d - np.diag(np.diag(d))).max() < 1e-9 * np.abs(d).max()


def test_ground_residuals_drop_infinite_sigmas(problem):
    p = dict(problem)
    finite = np.isfinite(p["gcp_sigma_m"])
    p["gcp_lonlath"] = np.where(finite, p["gcp_lonlath"], np.nan)  # unused values may be NaN
    r = sp.residuals(p, p["bias_true"], p["points_true"])
    assert r.shape == (2 * len(p["obs_scene"]) + finite.sum(),)
    assert np.all(np.isfinite(r))
    # GCP residuals at the truth are the injected noise: whitened, so of unit size
    gcp = r[2 * len(p["obs_scene"]) :]
    assert 0.5 < np.sqrt(np.mean(gcp**2)) < 1.5


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda p: p.pop("origin"), "missing key 'origin'"),
        (lambda p: p.__setitem__("obs_point", p["obs_point"] + 1000), "obs_point[0]"),
        (lambda p: p.__setitem__("num", p["num"][:, :1]), "'num' must have shape"),
        (lambda p: p.__setitem__("bias0", p["bias0"][:2]), "'bias0' has S=2"),
        (lambda p: p.__setitem__("obs_sigma", 0.0 * p["obs_sigma"]), "obs_sigma[0] is not > 0"),
    ],
)
def test_validate_names_the_fault(problem, edit, message):
    p = dict(problem)
    edit(p)
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        sp.validate(p)


@pytest.fixture(scope="module")
def solutions(problem):
    pytest.importorskip("pyceres")  # optional peer (`bench` extra)
    return {
        "ceres": sp.solve_ceres(problem),
        "scipy": sp.solve_scipy(problem, jac="analytic", lsmr_tol=1e-12),
        "scipy_fd": sp.solve_scipy(problem),
    }


def test_peers_reach_the_same_minimum(problem, solutions):
    ceres, scipy_, scipy_fd = solutions["ceres"], solutions["scipy"], solutions["scipy_fd"]
    assert ceres["status"] == "CONVERGENCE"
    assert ceres["eliminated_blocks"] == len(problem["points0"])  # Schur on the points
    assert scipy_["status"] > 0
    assert ceres["cost"] < 1e-2 * ceres["initial_cost"]
    for res in solutions.values():  # reported cost is the cost of the reported solution
        assert abs(sp.cost(problem, res["bias"], res["points"]) - res["cost"]) < 1e-9 * res["cost"]
    assert abs(scipy_["cost"] - ceres["cost"]) < 1e-8 * ceres["cost"]
    assert sp.bias_effect_px(problem, scipy_["bias"], ceres["bias"]).max() < 1e-6
    # finite differences (scipy's usual sparse mode) stop short of the minimum: measured ~1e-7
    assert 0.0 <= (scipy_fd["cost"] - ceres["cost"]) / ceres["cost"] < 1e-5
    assert sp.bias_effect_px(problem, scipy_fd["bias"], ceres["bias"]).max() < 0.05


def test_biases_recovered_to_the_noise_level(problem, solutions):
    """The bias error is consistent with the formal covariance (J^T J)^-1 of the adjustment.

    With GCPs in one scene of three and ties from one viewing geometry in narrow overlaps, the
    drift terms of the other scenes are weakly determined: corner errors of 3-5 px are within
    the formal precision (measured chi2 17 for 24 parameters).
    """
    ceres = solutions["ceres"]
    jac = sp.jacobian(problem, ceres["bias"], ceres["points"]).toarray()
    n_bias = problem["bias0"].size
    cov = np.linalg.inv(jac.T @ jac)[:n_bias, :n_bias]
    err = (ceres["bias"] - problem["bias_true"]).ravel()
    chi2 = err @ np.linalg.solve(cov, err)
    assert chi2 < scipy.stats.chi2.ppf(0.999, n_bias)
    # and the estimate is far better than the starting point (zero bias)
    start = problem["bias_true"].ravel()
    assert chi2 < 1e-2 * (start @ np.linalg.solve(cov, start))
    # a posteriori s0 ~ 1: the residuals are at the injected noise level
    redundancy = jac.shape[0] - jac.shape[1]
    assert 0.6 < np.sqrt(2 * ceres["cost"] / redundancy) < 1.4


def test_biases_recovered_in_pixels_with_gcps_everywhere(real_data):
    """With accurate GCPs in every scene the affine biases are fixed to ~noise at the corners
    (measured max 0.5 px for 0.3 px image noise; the injected biases reach 4-9 px there)."""
    pytest.importorskip("pyceres")  # optional peer (`bench` extra)
    p = make_problem(4, 10, seed=2, gcp_every=1, gcps_per_scene=12, gcp_sigma_m=0.05,
                     rpc_path=real_data / GEOM)  # fmt: skip
    res = sp.solve_ceres(p)
    assert sp.bias_effect_px(p, p["bias0"], p["bias_true"]).min() > 3.0
    assert sp.bias_effect_px(p, res["bias"], p["bias_true"]).max() < 1.0
