"""Errors as data: ``solve`` returns a ``RESULTS`` per problem, raises only with ``throw=True``."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.bundle import with_bias
from jaxgeo.bundle._prepare import prepare
from jaxgeo.lsq import RESULTS, SolverConfig, solve
from jaxgeo.lsq.internal import describe
from tests.bundle.conftest import make_block


@pytest.fixture(scope="module")
def problems(ventoux_pair):
    """A shift-bias pair with GCPs, and the same problem with the GCP weights zeroed: a common
    shift of both images is then not determined (same structure, so the two stack)."""
    small = make_block(*ventoux_pair, n=8, n_gcp=4, seed=5)
    good = prepare(with_bias(small.models, "shift"), small.obs, small.ground).problem
    bad = eqx.tree_at(lambda p: p.ground.weight, good, jnp.zeros_like(good.ground.weight))
    return good, bad


_solve = eqx.filter_jit(lambda p: solve(p, SolverConfig()))
"""One jitted solve for the module: compiled once, for every problem of one structure."""


def test_singular_problem_is_a_result_or_raises_with_throw(problems):
    good, bad = problems  # one structure: each jitted solve compiles once for both
    plain = _solve
    throwing = eqx.filter_jit(lambda p: solve(p, SolverConfig(), throw=True))
    ok = plain(good)
    assert bool(ok.result == RESULTS.successful)
    sol = plain(bad)
    assert bool(sol.result == RESULTS.undetermined)
    assert describe(sol.result) == (False, "singular normal equations")
    with pytest.raises(eqx.EquinoxRuntimeError, match="parameters or ground points are not"):
        jax.block_until_ready(throwing(bad))
    # a successful solve does not raise with throw=True
    thrown = throwing(good)
    np.testing.assert_allclose(thrown.theta[0], ok.theta[0], rtol=1e-12, atol=1e-12)


def test_vmap_gives_each_problem_its_own_result(problems):
    good, bad = problems
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b]), good, bad)
    sols = eqx.filter_jit(eqx.filter_vmap(lambda p: solve(p, SolverConfig())))(batch)
    flags = np.asarray(sols.result == RESULTS.successful)
    singular = np.asarray(sols.result == RESULTS.undetermined)
    assert flags.tolist() == [True, False] and singular.tolist() == [False, True]
    single = _solve(good)
    np.testing.assert_allclose(sols.theta[0][0], single.theta[0], rtol=1e-8, atol=1e-9)


def test_solver_config_validates():
    with pytest.raises(ValueError, match="method must be one of"):
        SolverConfig(method="newton")
    with pytest.raises(ValueError, match="loss must be one of"):
        SolverConfig(loss="l1")
    with pytest.raises(ValueError, match="max_steps must be >= 1, got 0"):
        SolverConfig(max_steps=0)
    with pytest.raises(ValueError, match="loss_scale must be a positive"):
        SolverConfig(loss_scale=-1.0)
    with pytest.raises(ValueError, match="tol must be"):
        SolverConfig(tol=float("nan"))
    assert SolverConfig() == SolverConfig() and hash(SolverConfig()) == hash(SolverConfig())
