"""The Jacobian blocks of the residuals formed a chunk of observations at a time
(``_residuals.jacobians``, the solve's) equal those of one linearisation of the whole objective
(``_schur.split_jacobians``): observations sorted by block (evaluated block by block) or not
(one model copy per observation, as the strip's), in one chunk or several with padding, with
least squares and a robust loss; both layouts give the same residuals."""

import dataclasses

import equinox as eqx
import jax
import numpy as np
import pytest

from jaxgeo.lsq import _residuals, _schur
from jaxgeo.lsq._residuals import jacobians, residuals
from jaxgeo.lsq._solve import unit_scales


def _unsorted(problem):
    """The same problem evaluated observation by observation (no ``block_start``)."""
    images = tuple(dataclasses.replace(ob, block_start=()) for ob in problem.images)
    return dataclasses.replace(problem, images=images)


def _point(problem, seed=0):
    """Unknowns off the start: parameters and points moved (residuals of a few px)."""
    rng = np.random.default_rng(seed)
    z = tuple(
        jax.numpy.asarray(rng.normal(scale=[1.0, 1.0, 1e-4, 1e-4, 1e-4, 1e-4][: g.n_params],
                                     size=g.theta0.shape))
        for g in problem.groups
    )  # fmt: skip
    u = jax.numpy.asarray(rng.normal(scale=3.0, size=problem.origin.shape))
    return z, u


@pytest.mark.parametrize("loss", ["l2", "cauchy"])
@pytest.mark.parametrize("sorted_", [True, False])
@pytest.mark.parametrize("chunk", [7, 1 << 13])
def test_chunked_jacobians_equal_one_linearisation(
    block_problem, monkeypatch, sorted_, chunk, loss
):
    problem = block_problem if sorted_ else _unsorted(block_problem)
    counts = np.diff(np.asarray(block_problem.images[0].block_start))
    assert counts.max() > 7 and counts.max() % 7  # several chunks, the last one padded
    monkeypatch.setattr(_residuals, "CHUNK", chunk)
    y, sc = _point(problem), unit_scales(problem)
    want = _schur.split_jacobians(residuals, (problem, sc, loss, 3.0), y, problem.structure.width)
    got = eqx.filter_jit(jacobians)(problem, sc, y, loss, 3.0)
    assert float(np.abs(np.asarray(want.r)).max()) > 1.0  # a point off the solution
    for name in ("r", "jc", "jp", "rg", "jg"):
        a, b = np.asarray(getattr(got, name)), np.asarray(getattr(want, name))
        assert a.shape == b.shape, name
        # the ground residuals (not chunked) are differences of earth-centred metres (~6e6 m):
        # two compilations round them differently by ~1e-9 m, which a robust loss carries into
        # their Jacobian
        atol = {"rg": 1e-8, "jg": 1e-9 * np.abs(b).max()}.get(name, 1e-11 * np.abs(b).max())
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=atol, err_msg=name)
    for a, b in zip(got.jpr + got.rpr, want.jpr + want.rpr, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-15)


def test_both_layouts_give_the_same_residuals(block_problem):
    y, sc = _point(block_problem, seed=1), unit_scales(block_problem)
    a = residuals(y, (block_problem, sc, "l2", 3.0))
    b = residuals(y, (_unsorted(block_problem), sc, "l2", 3.0))
    for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(u), np.asarray(v), rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("loss", ["l2", "cauchy"])
def test_solution_weights_are_not_weakly_typed(block_problem, loss):
    # data snooping re-solves from the last solution's weights: weakly typed ones gave the
    # re-solve another compilation key than the cold start's (a second compilation per run)
    from jaxgeo.lsq import SolverConfig, solve

    sol = eqx.filter_jit(solve)(block_problem, SolverConfig(loss=loss))
    assert not sol.weight_image.weak_type and not sol.weight_ground.weak_type
