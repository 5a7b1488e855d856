"""The adjustment core as a pure function: gradients (implicit function theorem) and vmap."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgeo.bundle import with_bias
from jaxgeo.bundle._prepare import prepare
from jaxgeo.lsq import RESULTS, SolverConfig, solve
from jaxgeo.lsq._solve import solve_jit
from tests.bundle.conftest import NOISE_PX, make_block


@pytest.fixture(scope="module")
def block(ventoux_pair):
    # GCPs nearly exact, so that image noise alone explains the scatter of the solutions
    return make_block(*ventoux_pair, n=10, n_gcp=4, seed=3, gcp_sigma_m=0.01)


@pytest.fixture(scope="module")
def problem(block):
    return prepare(with_bias(block.models, "shift-drift"), block.obs, block.ground).problem


def _xy(problem):
    return jnp.concatenate([ob.xy for ob in problem.images])


@pytest.mark.parametrize(("loss", "rtol"), [("l2", 1e-4), ("cauchy", 4e-3)])
def test_gradient_of_the_adjustment_wrt_observations(problem, loss, rtol):
    """Reverse and forward derivatives through the solve equal finite differences: least squares,
    and the default robust loss (its IRLS loop is cut from the graph, the final robust solve
    carries the implicit derivative; the finite differences of the Cauchy objective at
    eps = 1e-2 px are good to ~1e-3 only)."""
    xy0 = _xy(problem)

    @jax.jit
    def params_and_height(xy):
        sol = solve(problem.with_xy(xy), SolverConfig(tol=1e-10, loss=loss))
        # parameters (px, px/px scaled to px over the image) and a tie point's height (m)
        theta = sol.theta[0] * jnp.array([1.0, 1.0, 2e4, 2e4])
        return theta, sol.ground[-1, 2]

    check_grads(
        params_and_height, (xy0,), order=1, modes=("fwd", "rev"), eps=1e-2, atol=1e-6, rtol=rtol
    )
    jac_theta, jac_h = jax.jacrev(params_and_height)(xy0)
    # moving every left measurement by +1 px in x is absorbed by the left shift alone (B0 -> B0
    # - 1, eq. 2): the derivatives over the left observations sum to -1, 0 for the right image,
    # and no ground point moves
    left = slice(0, 10)
    np.testing.assert_allclose(jac_theta[0, 0, left, 0].sum(), -1.0, atol=1e-6)
    np.testing.assert_allclose(jac_theta[1, 0, left, 0].sum(), 0.0, atol=1e-6)
    np.testing.assert_allclose(jac_h[left, 0].sum(), 0.0, atol=1e-5)
    # a check point's height depends on its own y parallax (~1.5 m / px, B/H ~ 0.34)
    assert 0.5 < abs(float(jac_h[9, 1])) < 3.0


def test_monte_carlo_runs_are_one_vmapped_call(problem, block):
    xy0 = jnp.asarray(block.exact_xy)  # same order as the problem (one group, one slot)
    n = 64
    draws = xy0 + NOISE_PX * jax.random.normal(jax.random.key(0), (n, *xy0.shape))

    @eqx.filter_jit
    def batch(problem, xys):
        sols = jax.vmap(lambda xy: solve(problem.with_xy(xy)))(xys)
        return sols.theta[0], sols.ground, sols.result, sols.s0, sols.q_params

    theta, ground, result, s0, q = batch(problem, draws)
    assert theta.shape == (n, 2, 4) and ground.shape == (n, 10, 3)
    assert np.all(np.asarray(result == RESULTS.successful))
    for i in (0, n - 1):  # members equal independent solves
        single = solve_jit(problem.with_xy(draws[i]), SolverConfig())
        np.testing.assert_allclose(theta[i], single.theta[0], rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(s0[i], single.s0, rtol=1e-8)
    # the scatter of the parameters over the noise draws is their predicted sigma
    # (sigma_px = noise: a priori sigmas; 64 draws: sample std within ~27 % at 3 sigma)
    empirical = np.std(np.asarray(theta).reshape(n, -1), axis=0)
    predicted = np.sqrt(np.diag(np.asarray(q).mean(axis=0)))
    np.testing.assert_allclose(empirical, predicted, rtol=0.3)
