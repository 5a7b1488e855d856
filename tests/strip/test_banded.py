"""A strip's level 1 solved with the block-banded reduced system equals the dense solve."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.bundle import SingularNormalEquations
from jaxgeo.bundle.internal import make_result
from jaxgeo.lsq import RESULTS
from jaxgeo.lsq import _band as band
from jaxgeo.lsq._solve import solve_jit
from jaxgeo.strip import UniversalCorrectionWarning, adjust_strip
from jaxgeo.strip._config import STRIP_SOLVER
from jaxgeo.strip._export import strip_summary as summary
from tests.strip.conftest import strip_config


@pytest.fixture(scope="module")
def dense(strip_result):
    problem = strip_result.setup.problem
    assert problem.structure.band == 0  # 12 sub-scenes: too few super-blocks, dense
    return problem, solve_jit(problem, STRIP_SOLVER)


@pytest.mark.parametrize("extra", [0, 4])  # super-blocks of the bandwidth; wider, padded
def test_banded_level1_equals_dense(dense, extra):
    problem, want = dense
    s = problem.structure
    width = s.width
    g = band.block_bandwidth(np.asarray(s.pair_blocks)) + extra
    banded = dataclasses.replace(problem, structure=dataclasses.replace(s, band=g))
    got = solve_jit(banded, STRIP_SOLVER)
    assert isinstance(got.q_params, band.Band) and bool(got.result == RESULTS.successful)
    assert bool(want.result == RESULTS.successful)
    # rounding differs, so a step or two near the cost's noise floor may be taken or not (the
    # robust solve's last decrements, 1e-10 to 1e-11, are below the cost's rounding)
    assert abs(int(got.num_steps) - int(want.num_steps)) <= 2
    # equal within the solver's tolerance (1e-6 of each unknown's sigma)
    sigma = np.sqrt(np.diag(np.asarray(want.q_params))).reshape(want.theta[0].shape)
    assert np.max(np.abs(got.theta[0] - want.theta[0]) / sigma) < 1e-6
    sigma_p = np.sqrt(np.diagonal(np.asarray(want.q_points), axis1=1, axis2=2))  # ENU m
    moved = (np.asarray(got.ground) - np.asarray(want.ground)) * problem.metres_per_unit
    assert np.max(np.abs(moved) / sigma_p) < 1e-6
    # s0 to 1e-8: the robust weights move with the unknowns (equal to 1e-6 sigma above), and s0
    # with them (an H200: 1.3e-9 apart)
    np.testing.assert_allclose(got.s0, want.s0, rtol=1e-8)
    np.testing.assert_allclose(got.redundancy_image, want.redundancy_image, atol=1e-9)
    # cofactors compared as correlations (entries over sqrt(q_ii q_jj) of the dense solve)
    d = np.sqrt(np.diagonal(np.asarray(want.q_points), axis1=1, axis2=2))
    norm = d[:, :, None] * d[:, None, :]
    np.testing.assert_allclose(got.q_points / norm, want.q_points / norm, rtol=0, atol=1e-7)
    np.testing.assert_allclose(got.inflation_params, want.inflation_params, rtol=1e-7)
    # the cofactors within the band: a sub-scene with itself and its neighbours
    q, qd = np.asarray(got.q_params.todense()), np.asarray(want.q_params)
    blocks = np.arange(q.shape[0]) // width
    near = np.abs(blocks[:, None] - blocks[None, :]) <= g - extra
    assert near.sum() > 3 * q.shape[0]
    norm = np.sqrt(np.outer(np.diag(qd), np.diag(qd)))[near]
    np.testing.assert_allclose(q[near] / norm, qd[near] / norm, rtol=0, atol=1e-7)
    np.testing.assert_allclose(got.q_params.diagonal(), np.diag(qd), rtol=1e-7)


def test_banded_strip_end_to_end_equals_dense(strip_quarter, strip_result, monkeypatch):
    """The whole two-level adjustment, report and JSON summary with the banded system (forced
    on these 12 sub-scenes: one sub-scene a super-block) equal the dense run's."""
    monkeypatch.setattr(band, "SUPER_PARAMS", 6)
    with pytest.warns(UniversalCorrectionWarning, match="quadratic universal correction"):
        got = adjust_strip(strip_quarter, strip_config())
    assert got.setup.problem.structure.band == 1
    assert strip_result.setup.problem.structure.band == 0
    mine, theirs = summary(got), summary(strip_result)
    for name in strip_quarter.names:
        a, b = mine["models"][name], theirs["models"][name]
        for key, value in b["bias"].items():
            sigma = b["bias_sigma"][key]
            assert abs(a["bias"][key] - value) < 1e-6 * sigma, (name, key)
            assert a["bias_sigma"][key] == pytest.approx(sigma, rel=1e-6), (name, key)
    for a, b in zip(got.report.scenes, strip_result.report.scenes, strict=True):
        for level in ("level1", "level2"):
            assert a[level]["plan"] == pytest.approx(b[level]["plan"], rel=1e-6, abs=1e-6)
    cov = got.level1.param_cov
    assert cov.shape == (got.level1.params.size,) * 2 and cov.nnz < cov.shape[0] ** 2
    np.testing.assert_allclose(np.sqrt(cov.diagonal()), got.level1.param_sigma, rtol=1e-12)


def test_banded_singular_sub_scene_is_named(dense, strip_result):
    """A sub-scene that no observation sees: the banded factor's NaN becomes the same named
    error as the dense solve's (``SingularNormalEquations`` naming its parameters)."""
    problem, _ = dense
    s = problem.structure
    (img,) = problem.images
    gone = jnp.asarray(np.asarray(s.obs_block) == 5)
    blind = eqx.tree_at(lambda q: q.images[0].weight, problem, jnp.where(gone, 0.0, img.weight))
    g = band.block_bandwidth(np.asarray(s.pair_blocks))
    blind = dataclasses.replace(blind, structure=dataclasses.replace(s, band=g))
    sol = solve_jit(blind, STRIP_SOLVER)
    assert bool(sol.result == RESULTS.undetermined)
    setup = dataclasses.replace(strip_result.setup, problem=blind)
    strip = strip_result.strip
    name = strip.names[5]
    with pytest.raises(SingularNormalEquations, match=rf"{name}\.bias\.shift_px\[0\]"):
        make_result(setup, sol, strip.observations, strip.ground, STRIP_SOLVER)
