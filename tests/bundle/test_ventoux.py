"""Bias-compensated adjustment of the real Pleiades Ventoux pair with injected affine biases.

The true geometry is the vendor RPC composed with a known affine image bias (tens of pixels);
measurements are the true projections plus 0.3 px noise. The adjustment must recover the bias,
bring the check points to the noise level, and agree with a dense solver.
"""

import numpy as np
import pytest

from jaxgeo.bundle import adjust, direct_georeferencing, with_bias
from jaxgeo.bundle._prepare import prepare
from jaxgeo.bundle._report import project
from jaxgeo.lsq import RESULTS, SolverConfig, solve
from jaxgeo.lsq._solve import solve_jit
from tests.bundle.conftest import NOISE_PX, TRUE_BIAS


@pytest.fixture(scope="module")
def result(block):
    return adjust(block.models, block.obs, block.ground, bias="affine")


def _true_params():
    return np.concatenate(
        [
            np.concatenate([np.ravel(TRUE_BIAS[n].shift_px), np.ravel(TRUE_BIAS[n].matrix)])
            for n in ("left", "right")
        ]
    )


def test_bias_is_recovered(block, result):
    # default Cauchy loss: least squares (~5 steps), then a few reweighted solves (24 steps in
    # all), then the final solve of the robust objective that carries the derivatives (~10)
    assert result.converged and result.num_steps <= 40
    assert result.param_names[:2] == ("left.bias.shift_px[0]", "left.bias.shift_px[1]")
    z = (result.params - _true_params()) / result.param_sigma
    assert np.abs(z).max() < 4.0  # every parameter within 4 sigma of the truth
    # at the check points the adjusted geometry departs from the true one by less than the
    # noise of one measurement (6 GCPs determine 6 affine parameters per image), where the
    # vendor geometry was > 5 px off
    check = block.ground.select("check").lonlath
    for name, model in result.models.items():
        truth = np.asarray(project(block.truth[name], check))
        diff = np.asarray(project(model, check)) - truth
        vendor = np.asarray(project(block.models[name], check)) - truth
        assert np.sqrt(np.mean(diff**2)) < NOISE_PX < 5.0 < np.sqrt(np.mean(vendor**2))


def test_check_points_fall_to_the_noise_level(block, result):
    direct = direct_georeferencing(block.models, block.obs, block.ground)
    rep = result.report
    assert rep.n == 24
    for name in ("left", "right"):
        assert max(direct.images[name][:2]) > 5.0  # the injected bias: > 5 px before
        rx, ry, n = rep.images[name]
        assert n == 24 and max(rx, ry) < 1.5 * NOISE_PX  # back-projection RMS ~ the noise
    assert direct.rms_m[2] > 20.0
    # 0.3 px noise on 0.5 m pixels with B/H ~ 0.34: ~0.15 m planimetry, ~0.6 m height
    assert rep.rms_m[0] < 0.3 and rep.rms_m[1] < 0.3 and rep.rms_m[2] < 1.0
    assert 0.75 < result.s0 < 1.25  # sigma_px = noise: s0 ~ 1
    # a posteriori sigmas of the check points describe their actual errors
    sig = np.array([result.point(p)[1] for p in rep.ids])
    chi2 = np.mean((rep.errors_m / sig) ** 2, axis=0)  # errors correlated through the bias:
    assert np.all((chi2 > 0.2) & (chi2 < 3.0))  # a loose band (exact check: test_transforms)


def test_schur_solver_equals_dense_levenberg_marquardt(block, result):
    setup = prepare(with_bias(block.models, "affine"), block.obs, block.ground)
    problem = setup.problem
    # the solvers compared on least squares (IRLS would add its own 1e-3 weight tolerance)
    a = solve_jit(problem, SolverConfig(loss="l2"))
    b = solve(problem, SolverConfig(method="dense", tol=1e-12, max_steps=100, loss="l2"))
    c = solve(problem, SolverConfig(method="gn", tol=1e-9, loss="l2"))  # to the noise floor
    assert all(bool(s.result == RESULTS.successful) for s in (a, b, c))
    sigma = np.sqrt(np.diag(np.asarray(b.q_params))) * float(b.s0)
    for other in (a, c):
        dtheta = (np.asarray(other.theta[0]) - np.asarray(b.theta[0])).ravel()
        assert np.abs(dtheta / sigma).max() < 1e-6
        dground = (np.asarray(other.ground) - np.asarray(b.ground)) * np.asarray(
            problem.metres_per_unit
        )
        assert np.abs(dground).max() < 1e-7  # metres
        dres = (np.asarray(other.residuals_image) - np.asarray(b.residuals_image)) * NOISE_PX
        assert np.abs(dres).max() < 1e-7  # pixels
        np.testing.assert_allclose(other.s0, b.s0, rtol=1e-9)
        q, qb = np.asarray(other.q_params), np.asarray(b.q_params)
        scale = np.sqrt(np.outer(np.diag(qb), np.diag(qb)))
        assert np.abs((q - qb) / scale).max() < 1e-6  # sigmas and correlations
        np.testing.assert_allclose(other.q_points, b.q_points, rtol=1e-6, atol=1e-12)
